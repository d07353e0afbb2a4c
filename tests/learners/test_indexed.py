"""indexed(learner, T): one independent learner per time step."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sklearn.linear_model import Ridge

from loopid.learners import ftrl_least_squares, indexed, ogd, touched_weights


def _batches(rng, T, n_batches=12, b=40, f=5, t=3):
    W = rng.normal(size=(T, f, t))
    out = []
    for _ in range(n_batches):
        X = rng.normal(size=(b, f))
        idx = rng.integers(0, T - 1, size=b)  # step T-1 never gets a row
        Y = np.einsum("bf,bft->bt", X, W[idx]) + 0.1 * rng.normal(size=(b, t))
        keep = rng.random(b) < 0.8
        out.append((X, Y, keep, idx))
    return out


@pytest.mark.parametrize("fast_path", [True, False])
def test_indexed_ftrl_equals_independent_per_step_fits(rng, fast_path):
    T, lam = 6, 0.3
    base = ftrl_least_squares(lam)
    if not fast_path:
        base = base._replace(update_indexed=None)  # the generic vmap route
    learner = indexed(base, T)
    batches = _batches(rng, T)
    state = learner.init(5, 3)
    for X, Y, keep, idx in batches:
        state = learner.update(state, X, Y, keep, index=idx)
    W = np.asarray(learner.weights(state))
    assert W.shape == (T, 5, 3)
    X = np.concatenate([b[0] for b in batches])
    Y = np.concatenate([b[1] for b in batches])
    keep = np.concatenate([b[2] for b in batches])
    idx = np.concatenate([b[3] for b in batches])
    for t in range(T):
        rows = keep & (idx == t)
        n = rows.sum()
        assert float(state.n[t]) == n
        if n == 0:
            assert np.all(W[t] == 0.0)
            continue
        ridge = Ridge(alpha=lam * np.sqrt(n), fit_intercept=False, solver="cholesky")
        ridge.fit(X[rows], Y[rows])
        np.testing.assert_allclose(W[t], ridge.coef_.T, rtol=0, atol=1e-9)


def test_indexed_ogd_equals_independent_per_step_runs(rng):
    T = 4
    base = ogd(0.1, radius=3.0)
    learner = indexed(base, T)
    batches = _batches(rng, T, n_batches=6)
    state = learner.init(5, 3)
    singles = [base.init(5, 3) for _ in range(T)]
    for X, Y, keep, idx in batches:
        state = learner.update(state, X, Y, keep, index=idx)
        for t in range(T):
            singles[t] = base.update(singles[t], X, Y, keep & (idx == t))
    W = np.asarray(learner.weights(state))
    for t in range(T):
        np.testing.assert_allclose(W[t], np.asarray(singles[t].W), atol=1e-13)
        assert int(state.t[t]) == int(singles[t].t)
    assert int(state.t[T - 1]) == 0 and np.all(W[T - 1] == 0.0)  # never saw a row


def test_indexed_under_scan_and_vmap(rng):
    S, N, b, T = 2, 5, 8, 3
    X = jnp.asarray(rng.normal(size=(S, N, b, 4)))
    Y = jnp.asarray(rng.normal(size=(S, N, b, 2)))
    idx = jnp.asarray(rng.integers(0, T, size=(S, N, b)))
    learner = indexed(ftrl_least_squares(1e-3), T)

    def run(Xs, Ys, Is):
        def step(s, a):
            return learner.update(s, a[0], a[1], None, index=a[2]), None

        return learner.weights(jax.lax.scan(step, learner.init(4, 2), (Xs, Ys, Is))[0])

    W = np.asarray(jax.jit(jax.vmap(run))(X, Y, idx))
    for s in range(S):
        state = learner.init(4, 2)
        for k in range(N):
            state = learner.update(state, X[s, k], Y[s, k], index=idx[s, k])
        np.testing.assert_allclose(W[s], np.asarray(learner.weights(state)), atol=1e-12)


@pytest.mark.parametrize(
    "base", [ftrl_least_squares(0.3), ogd(0.1, radius=3.0)], ids=["ftrl", "ogd"]
)
def test_touched_weights_equal_the_full_solve_bit_for_bit(rng, base):
    """Re-solving only the steps a batch reached (repeated steps, dropped rows, a step never
    reached) gives every step's weights exactly as solving all steps does, batch after batch,
    jitted and vmapped over seeds as the loop runs it."""
    T = 7
    learner = indexed(base, T)
    batches = _batches(rng, T)

    @jax.jit
    @jax.vmap
    def update(state, W, X, Y, keep, idx):
        new = learner.update(state, X, Y, keep, index=idx)
        return new, touched_weights(base, new, W, idx, keep)

    S = 3
    state = jax.tree_util.tree_map(lambda a: jnp.stack([a] * S), learner.init(5, 3))
    W = jax.vmap(learner.weights)(state)
    for X, Y, keep, idx in batches:
        seeds = [rng.permutation(len(keep)) for _ in range(S)]  # each seed its own rows
        state, W = update(
            state, W, *(jnp.asarray(np.stack([a[p] for p in seeds])) for a in (X, Y, keep, idx))
        )
        np.testing.assert_array_equal(np.asarray(W), np.asarray(jax.vmap(learner.weights)(state)))
    assert np.all(np.asarray(W)[:, T - 1] == 0.0)  # step T-1 never got a row


def test_touched_weights_leave_every_other_step_alone():
    """A stale step that no row reached keeps the W it was given (what makes the solve cheap),
    and a dropped row's step is not solved."""
    base = ftrl_least_squares(1e-3)
    learner = indexed(base, 4)
    state = learner.update(
        learner.init(2, 1), np.ones((2, 2)), np.ones((2, 1)), np.array([True, False]),
        index=np.array([1, 2]),
    )  # fmt: skip
    stale = jnp.full((4, 2, 1), 7.0)
    W = np.asarray(touched_weights(base, state, stale, jnp.array([1, 2]), jnp.array([True, False])))
    np.testing.assert_array_equal(W[1], np.asarray(learner.weights(state))[1])
    assert np.all(W[[0, 2, 3]] == 7.0)
