"""Rollouts against plain NumPy loops."""

import jax.numpy as jnp
import numpy as np
import pytest

from loopid.control import linear_rollout, rollout, tracking_rollout


def test_linear_rollout_matches_numpy_loop(rng):
    n, m, T = 3, 2, 12
    A = rng.standard_normal((T, n, n)) / 2
    B = rng.standard_normal((n, m))  # time-invariant: broadcast
    K = rng.standard_normal((T, m, n)) / 3
    k = rng.standard_normal(m)
    c = rng.standard_normal((T, n))
    W = rng.standard_normal((T, n))
    x0 = rng.standard_normal(n)
    out = linear_rollout(A, B, K, x0, k=k, c=c, W=W)
    x, X, U = x0, [x0], []
    for t in range(T):
        u = -K[t] @ x - k
        x = A[t] @ x + B @ u + c[t] + W[t]
        X.append(x)
        U.append(u)
    np.testing.assert_allclose(out.X, np.stack(X), rtol=1e-12)
    np.testing.assert_allclose(out.U, np.stack(U), rtol=1e-12)


def test_static_gain_needs_T_and_tracking_with_zero_gain_is_open_loop(rng):
    A, B, K = np.eye(2) * 0.9, np.ones((2, 1)), np.ones((1, 2))
    with pytest.raises(ValueError, match="T is required"):
        linear_rollout(A, B, K, np.zeros(2))
    out = linear_rollout(A, B, K, np.ones(2), T=4)
    assert out.X.shape == (5, 2) and out.U.shape == (4, 1)

    def dynamics(x, u, t):
        return jnp.sin(x) + u[0] * jnp.asarray(t, jnp.float64)

    U = jnp.asarray(rng.standard_normal((6, 1)))
    X = rollout(dynamics, jnp.ones(2), U)
    tr = tracking_rollout(dynamics, jnp.ones(2), X, U, jnp.zeros((6, 1, 2)))
    np.testing.assert_allclose(tr.X, X, rtol=1e-14)
    np.testing.assert_allclose(tr.U, U, rtol=1e-14)


def test_linear_rollout_checks():
    with pytest.raises(ValueError, match=r"x0 must have shape"):
        linear_rollout(np.eye(2), np.ones((2, 1)), np.ones((1, 2)), np.zeros(3), T=2)
    with pytest.raises(ValueError, match=r"W must have shape"):
        linear_rollout(np.eye(2), np.ones((2, 1)), np.ones((1, 2)), np.zeros(2), W=np.zeros(2))
    with pytest.raises(ValueError, match=r"time axes differ"):
        linear_rollout(np.zeros((3, 2, 2)), np.ones((2, 1)), np.ones((4, 1, 2)), np.zeros(2))
