"""FTRL least squares against its closed form and scikit-learn's Ridge."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sklearn.linear_model import Ridge

from loopid.learners import FTRLState, ftrl_least_squares


def _stream(rng, n_batches=40, f=6, t=4, noise=0.3):
    """Batches of varying size from a fixed linear model with noise and uneven feature scales."""
    W = rng.normal(size=(f, t))
    scales = np.geomspace(0.2, 5.0, f)
    batches = []
    for _ in range(n_batches):
        b = int(rng.choice([1, 11, 29]))  # a few sizes: fewer compilations
        X = rng.normal(size=(b, f)) * scales
        batches.append((X, X @ W + noise * rng.normal(size=(b, t))))
    return batches


def _closed_form(X, Y, lam):
    n = X.shape[0]
    return np.linalg.solve(X.T @ X / n + lam / np.sqrt(n) * np.eye(X.shape[1]), X.T @ Y / n)


@pytest.mark.parametrize("lam", [1e-3, 0.7])
def test_streamed_equals_closed_form_ridge_and_one_shot_fit(rng, lam):
    batches = _stream(rng)
    learner = ftrl_least_squares(lam)
    for order_seed in range(3):
        order = np.random.default_rng(order_seed).permutation(len(batches))
        state = learner.init(6, 4)
        for i in order:
            state = learner.update(state, *batches[i])
        X = np.concatenate([batches[i][0] for i in order])
        Y = np.concatenate([batches[i][1] for i in order])
        n = X.shape[0]
        W = np.asarray(learner.weights(state))
        assert float(state.n) == n
        np.testing.assert_allclose(W, _closed_form(X, Y, lam), rtol=0, atol=1e-9)
        ridge = Ridge(alpha=lam * np.sqrt(n), fit_intercept=False, solver="cholesky").fit(X, Y)
        np.testing.assert_allclose(W, ridge.coef_.T, rtol=0, atol=1e-9)
        one_shot = learner.weights(learner.update(learner.init(6, 4), X, Y))
        np.testing.assert_allclose(W, np.asarray(one_shot), rtol=0, atol=1e-9)


def test_every_prefix_uses_lambda_over_sqrt_n(rng):
    """After each batch the weights are the ridge fit with alpha = λ√n for that prefix's n."""
    lam = 0.5
    batches = _stream(rng, n_batches=8)
    learner = ftrl_least_squares(lam)
    state = learner.init(6, 4)
    for k, (Xb, Yb) in enumerate(batches):
        state = learner.update(state, Xb, Yb)
        X = np.concatenate([b[0] for b in batches[: k + 1]])
        Y = np.concatenate([b[1] for b in batches[: k + 1]])
        W = np.asarray(learner.weights(state))
        np.testing.assert_allclose(W, _closed_form(X, Y, lam), rtol=0, atol=1e-9)


def test_no_data_gives_exact_zero_weights():
    for lam in (1e-3, 0.0):
        learner = ftrl_least_squares(lam)
        W = np.asarray(learner.weights(learner.init(25, 21)))
        assert W.shape == (25, 21)
        assert np.all(W == 0.0)


def test_lambda_zero_is_minimum_norm_least_squares(rng):
    """λ = 0 with fewer rows than features: the minimum-norm fit, no NaN."""
    X, Y = rng.normal(size=(3, 6)), rng.normal(size=(3, 2))
    learner = ftrl_least_squares(0.0)
    W = np.asarray(learner.weights(learner.update(learner.init(6, 2), X, Y)))
    np.testing.assert_allclose(W, np.linalg.lstsq(X, Y, rcond=None)[0], atol=1e-10)


def test_masked_rows_change_nothing(rng):
    X, Y = rng.normal(size=(20, 5)), rng.normal(size=(20, 3))
    keep = rng.random(20) < 0.6
    Xp, Yp = X.copy(), Y.copy()
    Xp[~keep] = np.nan  # padding may hold anything
    Yp[~keep] = np.inf
    learner = ftrl_least_squares(1e-3)
    s0 = learner.init(5, 3)
    ref = learner.update(s0, X[keep], Y[keep])
    for mask in (keep, keep.astype(np.float64)):
        got = learner.update(s0, Xp, Yp, mask)
        for a, b in zip(got, ref, strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-14, atol=1e-14)


def test_scan_and_vmap_over_seeds_match_python_loop(rng):
    S, N, b, f, t = 3, 7, 10, 4, 2
    X = rng.normal(size=(S, N, b, f))
    Y = rng.normal(size=(S, N, b, t))
    mask = rng.random((S, N, b)) < 0.8
    learner = ftrl_least_squares(1e-2)

    def run(Xs, Ys, Ms):
        def step(state, xym):
            return learner.update(state, *xym), None

        state, _ = jax.lax.scan(step, learner.init(f, t), (Xs, Ys, Ms))
        return learner.weights(state)

    W = np.asarray(jax.jit(jax.vmap(run))(jnp.asarray(X), jnp.asarray(Y), jnp.asarray(mask)))
    for s in range(S):
        keep = mask[s].reshape(-1)
        Xs, Ys = X[s].reshape(-1, f)[keep], Y[s].reshape(-1, t)[keep]
        np.testing.assert_allclose(W[s], _closed_form(Xs, Ys, 1e-2), rtol=0, atol=1e-10)


def test_state_is_named_and_float64():
    state = ftrl_least_squares().init(3, 2)
    assert isinstance(state, FTRLState)
    assert state.ZZ.shape == (3, 3) and state.ZY.shape == (3, 2) and state.n.shape == ()
    assert all(leaf.dtype == jnp.float64 for leaf in state)
