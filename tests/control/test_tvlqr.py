"""tvlqr: long-horizon limit, a shifted optimum, a brute-force QP oracle, robustness, checks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.control import dlqr, linear_rollout, tvlqr


def random_problem(rng, n, m, T, *, full=True):
    A = rng.standard_normal((T, n, n)) / np.sqrt(n)
    B = rng.standard_normal((T, n, m))
    Mq = rng.standard_normal((T, n, n))
    Q = Mq @ np.swapaxes(Mq, 1, 2) / n + 0.1 * np.eye(n)
    Mr = rng.standard_normal((T, m, m))
    R = Mr @ np.swapaxes(Mr, 1, 2) / m + 0.5 * np.eye(m)
    kw = {}
    if full:
        kw = {
            "c": rng.standard_normal((T, n)),
            "q": rng.standard_normal((T, n)),
            "r": rng.standard_normal((T, m)),
            "M": 0.05 * rng.standard_normal((T, n, m)),
            "Q_T": np.eye(n) * 2.0,
            "q_T": rng.standard_normal(n),
        }
    return A, B, Q, R, kw


def test_long_horizon_first_gain_converges_to_dlqr(rng):
    n, m = 21, 4
    A = rng.standard_normal((n, n)) / np.sqrt(n) * 1.1
    B = rng.standard_normal((n, m))
    Q, R = np.eye(n), np.eye(m)
    inf = dlqr(A, B, Q, R)
    sol = tvlqr(A, B, Q, R, T=2000)
    assert sol.K.shape == (2000, m, n) and sol.P.shape == (2001, n, n)
    np.testing.assert_allclose(sol.K[0], inf.K, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(sol.P[0], inf.P, rtol=1e-9, atol=1e-11)
    # and near the end of the horizon the gains differ (terminal cost 0 -> last gain 0)
    np.testing.assert_allclose(sol.K[-1], 0.0, atol=1e-14)


def test_shifted_optimum(rng):
    # (x - x*)ᵀQ(x - x*) + (u - u*)ᵀR(u - u*) with x* = A x* + B u* + c a fixed point:
    # the optimum is u = u* - K_t (x - x*), i.e. k_t = -(u* + K_t x*), and x* stays put.
    n, m, T = 4, 2, 50
    A = rng.standard_normal((n, n)) / np.sqrt(n)
    B = rng.standard_normal((n, m))
    x_star = rng.standard_normal(n)
    u_star = rng.standard_normal(m)
    c = x_star - A @ x_star - B @ u_star
    Q, R = np.diag([1.0, 2.0, 0.5, 1.0]), np.diag([0.3, 0.7])
    sol = tvlqr(A, B, Q, R, c=c, q=-Q @ x_star, r=-R @ u_star, Q_T=Q, q_T=-Q @ x_star, T=T)
    plain = tvlqr(A, B, Q, R, Q_T=Q, T=T)
    np.testing.assert_allclose(sol.K, plain.K, rtol=1e-12, atol=1e-14)
    expected_k = -(u_star + np.einsum("tmn,n->tm", plain.K, x_star))
    np.testing.assert_allclose(sol.k, expected_k, rtol=1e-10, atol=1e-12)
    roll = linear_rollout(A, B, sol.K, x_star, k=sol.k, c=c)
    np.testing.assert_allclose(roll.X, np.broadcast_to(x_star, (T + 1, n)), atol=1e-10)
    np.testing.assert_allclose(roll.U, np.broadcast_to(u_star, (T, m)), atol=1e-10)


def _stacked_cost(A, B, Q, R, kw):
    """J(x0, U) of the module docstring, written directly (no recursion)."""
    T = A.shape[0]

    def J(x0, U):
        x, total = x0, 0.0
        for t in range(T):
            u = U[t]
            total += x @ Q[t] @ x + 2 * kw["q"][t] @ x + u @ R[t] @ u + 2 * kw["r"][t] @ u
            total += 2 * x @ kw["M"][t] @ u
            x = A[t] @ x + B[t] @ u + kw["c"][t]
        return total + x @ kw["Q_T"] @ x + 2 * kw["q_T"] @ x

    return J


def test_equals_brute_force_quadratic_program(rng):
    n, m, T = 3, 2, 5
    A, B, Q, R, kw = random_problem(rng, n, m, T)
    sol = tvlqr(A, B, Q, R, **kw)
    J = _stacked_cost(A, B, Q, R, kw)
    # J is quadratic in z = [x0; vec U]: its Hessian and gradient at 0 are exact
    f = lambda z: J(z[:n], z[n:].reshape(T, m))  # noqa: E731
    z0 = jnp.zeros(n + T * m)
    H = np.asarray(jax.jit(jax.hessian(f))(z0))
    g = np.asarray(jax.jit(jax.grad(f))(z0))
    Hxx, HxU, HUU = H[:n, :n], H[:n, n:], H[n:, n:]
    gx, gU = g[:n], g[n:]
    # minimising over U: value Hessian 2P_0 and gradient 2p_0 at x0 = 0
    np.testing.assert_allclose(2 * sol.P[0], Hxx - HxU @ np.linalg.solve(HUU, HxU.T), rtol=1e-9)
    np.testing.assert_allclose(2 * sol.p[0], gx - HxU @ np.linalg.solve(HUU, gU), rtol=1e-9)
    # and the optimal actions from a random start
    x0 = rng.standard_normal(n)
    U_star = -np.linalg.solve(HUU, HxU.T @ x0 + gU).reshape(T, m)
    roll = linear_rollout(A, B, sol.K, x0, k=sol.k, c=kw["c"])
    np.testing.assert_allclose(roll.U, U_star, rtol=1e-9, atol=1e-11)


def test_time_invariant_arguments_broadcast(rng):
    n, m, T = 3, 2, 7
    A, B, Q, R, _ = random_problem(rng, n, m, 1, full=False)
    a = tvlqr(A[0], B[0], Q[0], R[0], T=T)
    b = tvlqr(np.repeat(A, T, 0), B[0], Q[0], np.repeat(R, T, 0))
    np.testing.assert_allclose(a.K, b.K, rtol=1e-13)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-13)


def test_vmap_over_problems_equals_loop(rng):
    n, m, T = 4, 2, 20
    probs = [random_problem(rng, n, m, T) for _ in range(3)]
    stack = lambda i: np.stack([p[i] for p in probs])  # noqa: E731
    c = np.stack([p[4]["c"] for p in probs])
    sol = jax.vmap(lambda A, B, Q, R, c: tvlqr(A, B, Q, R, c=c))(
        stack(0), stack(1), stack(2), stack(3), c
    )
    for i, (A, B, Q, R, kw) in enumerate(probs):
        one = tvlqr(A, B, Q, R, c=kw["c"])
        np.testing.assert_allclose(sol.K[i], one.K, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(sol.k[i], one.k, rtol=1e-12, atol=1e-14)


def test_singular_input_weight_gives_finite_gains():
    # R = 0 and B with a zero column: H_uu singular; the solve falls back, never NaN
    A = np.eye(2)
    B = np.array([[1.0, 0.0], [0.0, 0.0]])
    sol = tvlqr(A, B, np.eye(2), np.zeros((2, 2)), Q_T=np.eye(2), T=5)
    assert np.all(np.isfinite(sol.K)) and np.all(np.isfinite(sol.P))
    np.testing.assert_allclose(sol.K[:, 0, 0], 1.0, rtol=1e-6)  # dead-beat on the first state


def test_input_checks_name_the_argument():
    A, B, Q, R = np.eye(2), np.ones((2, 1)), np.eye(2), np.eye(1)
    with pytest.raises(ValueError, match=r"time axes differ"):
        tvlqr(np.zeros((5, 2, 2)), np.zeros((4, 2, 1)), Q, R)
    with pytest.raises(ValueError, match=r"T is required"):
        tvlqr(A, B, Q, R)
    with pytest.raises(ValueError, match=r"c must have shape"):
        tvlqr(A, B, Q, R, c=np.zeros(3), T=4)
    with pytest.raises(ValueError, match=r"Q must be symmetric"):
        tvlqr(A, B, np.array([[1.0, 1.0], [0.0, 1.0]]), R, T=4)
    with pytest.raises(ValueError, match=r"R must be positive semidefinite"):
        tvlqr(A, B, Q, -R, T=4)
    with pytest.raises(ValueError, match=r"Q_T must be positive semidefinite"):
        tvlqr(A, B, Q, R, Q_T=-np.eye(2), T=4)
    with pytest.raises(ValueError, match=r"B must have shape"):
        tvlqr(A, np.ones((3, 1)), Q, R, T=4)
