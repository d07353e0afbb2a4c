"""Online gradient descent: its update rule, projection, empty batches and its regret rate."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.learners import OGDState, ogd, online_loss, regret_curve


def test_first_two_steps_by_hand(rng):
    eta = 0.3
    X1, Y1 = rng.normal(size=(8, 4)), rng.normal(size=(8, 2))
    X2, Y2 = rng.normal(size=(5, 4)), rng.normal(size=(5, 2))
    learner = ogd(eta)
    s = learner.update(learner.init(4, 2), X1, Y1)
    W1 = eta * (2 / 8) * X1.T @ Y1  # from W = 0
    np.testing.assert_allclose(np.asarray(s.W), W1, atol=1e-14)
    s = learner.update(s, X2, Y2)
    W2 = W1 - eta / np.sqrt(2) * (2 / 5) * X2.T @ (X2 @ W1 - Y2)
    np.testing.assert_allclose(np.asarray(learner.weights(s)), W2, atol=1e-14)
    assert int(s.t) == 2 and isinstance(s, OGDState)


def test_projection_onto_frobenius_ball(rng):
    radius = 0.5
    learner, free = ogd(0.2, radius=radius), ogd(0.2)
    s = learner.init(3, 2)
    for _ in range(10):
        X, Y = rng.normal(size=(6, 3)), 10 * rng.normal(size=(6, 2))
        unprojected = free.update(s._replace(), X, Y)  # same state, no projection
        s = learner.update(s, X, Y)
        norm = np.linalg.norm(np.asarray(unprojected.W))
        expected = np.asarray(unprojected.W) * min(1.0, radius / norm)
        np.testing.assert_allclose(np.asarray(s.W), expected, atol=1e-13)
        assert np.linalg.norm(np.asarray(s.W)) <= radius * (1 + 1e-12)


def test_all_masked_batch_is_not_a_round(rng):
    learner = ogd(0.1)
    s = learner.update(learner.init(3, 2), rng.normal(size=(4, 3)), rng.normal(size=(4, 2)))
    X = np.full((4, 3), np.nan)
    s2 = learner.update(s, X, X[:, :2], np.zeros(4, dtype=bool))
    np.testing.assert_array_equal(np.asarray(s2.W), np.asarray(s.W))
    assert int(s2.t) == int(s.t) == 1


def test_masked_rows_change_nothing(rng):
    X, Y = rng.normal(size=(12, 3)), rng.normal(size=(12, 2))
    keep = np.arange(12) % 3 != 0
    Xp = np.where(keep[:, None], X, np.nan)
    learner = ogd(0.1)
    s0 = learner.update(learner.init(3, 2), X, Y)
    a = learner.update(s0, Xp, Y, keep)
    b = learner.update(s0, X[keep], Y[keep])
    np.testing.assert_allclose(np.asarray(a.W), np.asarray(b.W), atol=1e-14)


def test_converges_to_the_true_model_on_realisable_data(rng):
    W_true = rng.normal(size=(4, 3))
    X = rng.normal(size=(3000, 10, 4))
    learner = ogd(0.2)

    def step(s, x):
        return learner.update(s, x, x @ W_true), None

    s, _ = jax.lax.scan(step, learner.init(4, 3), jnp.asarray(X))
    np.testing.assert_allclose(np.asarray(s.W), W_true, atol=1e-6)


@pytest.mark.slow
def test_average_regret_falls_like_one_over_sqrt_n():
    """Regress log average regret on log N over noisy random least-squares streams: slope ≈ −1/2."""
    N, b, f, t, seeds = 2048, 10, 5, 3, 4
    learner = ogd(0.25)

    def run(key):
        k1, k2, k3 = jax.random.split(key, 3)
        W_true = 0.1 * jax.random.normal(k1, (f, t))
        X = jax.random.normal(k2, (N, b, f))
        Y = X @ W_true + jax.random.normal(k3, (N, b, t))

        def step(s, xy):
            loss = online_loss(learner.weights(s), *xy)  # before the update
            return learner.update(s, *xy), loss

        _, losses = jax.lax.scan(step, learner.init(f, t), (X, Y))
        return regret_curve(losses, X, Y).average_regret

    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    regret = np.asarray(jax.jit(jax.vmap(run))(keys)).mean(axis=0)
    Ns = 2 ** np.arange(5, 12)
    slope = np.polyfit(np.log(Ns), np.log(regret[Ns - 1]), 1)[0]
    assert np.all(regret[Ns - 1] > 0)
    assert -0.7 <= slope <= -0.3, slope
