"""ilqr: equals tvlqr on LQ problems, monotone cost, autodiff vs finite differences, funnel."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.control import ilqr, linear_rollout, quadratize, tvlqr
from loopid.systems import helicopter
from loopid.systems.helicopter import tasks


def lq_problem(rng, n=4, m=2, T=30):
    A = jnp.asarray(rng.standard_normal((T, n, n)) / 2)
    B = jnp.asarray(rng.standard_normal((T, n, m)))
    c = jnp.asarray(rng.standard_normal((T, n)))
    x_ref = jnp.asarray(rng.standard_normal((T + 1, n)))
    Q, R = jnp.eye(n), 0.1 * jnp.eye(m)

    def dynamics(x, u, t):
        return A[t] @ x + B[t] @ u + c[t]

    def cost(x, u, t):
        d = x - x_ref[t]
        return d @ Q @ d + u @ R @ u

    ref = tvlqr(A, B, Q, R, c=c, q=-(x_ref[:-1] @ Q), Q_T=Q, q_T=-Q @ x_ref[-1])
    return dynamics, cost, (A, B, c), ref


@pytest.fixture(scope="module")
def lq():
    """One LQ problem shared by the tests (same functions: the compiled iLQR is reused)."""
    return lq_problem(np.random.default_rng(7))


def test_one_iteration_equals_tvlqr_on_lq_problem(rng, lq):
    dynamics, cost, (A, B, c), ref = lq
    x0 = jnp.asarray(rng.standard_normal(4))
    U0 = jnp.asarray(rng.standard_normal((30, 2)))
    one = ilqr(dynamics, cost, x0, U0, max_iter=1)
    roll = linear_rollout(A, B, ref.K, x0, k=ref.k, c=c)
    np.testing.assert_allclose(one.U, roll.U, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(one.X, roll.X, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(one.K, ref.K, rtol=1e-10, atol=1e-12)
    full = ilqr(dynamics, cost, x0, U0)
    assert bool(full.converged) and int(full.iterations) == 2  # the 2nd only confirms
    np.testing.assert_allclose(full.cost, one.cost, rtol=1e-12)
    np.testing.assert_allclose(full.k, 0.0, atol=1e-9)


def pendulum_cart():
    """A small nonlinear problem: damped pendulum on a cart, swing towards upright."""
    dt = 0.05

    def dynamics(x, u, t):
        _, vel, th, om = x
        acc = u[0] - 0.1 * vel
        alpha = -9.81 * jnp.sin(th) - acc * jnp.cos(th) - 0.2 * om
        return x + dt * jnp.stack([vel, acc, om, alpha])

    def cost(x, u, t):
        target = jnp.array([0.0, 0.0, jnp.pi, 0.0])
        w = jnp.where(t == 60, 100.0, 1.0)
        d = x - target
        return w * (d @ d) + 0.01 * u @ u + 0.1 * (1 - jnp.cos(x[2])) * x[1] ** 2

    return dynamics, cost


def test_cost_never_increases_and_converges():
    dynamics, cost = pendulum_cart()
    x0 = jnp.array([0.0, 0.0, 2.5, 0.0])
    sol = ilqr(dynamics, cost, x0, jnp.zeros((60, 1)), max_iter=200)
    assert bool(sol.converged)
    h = np.asarray(sol.cost_history)
    assert np.all(np.diff(h) <= 0.0)
    assert h[-1] < 0.5 * h[0]
    np.testing.assert_allclose(h[int(sol.iterations)], sol.cost)


def _central_jacobian(f, z, eps):
    cols = [(f(z + eps * e) - f(z - eps * e)) / (2 * eps) for e in np.eye(z.shape[0])]
    return np.stack(cols, axis=-1)


def test_quadratization_matches_finite_differences():
    # the helicopter funnel problem in raw coordinates, at a perturbed, moving state
    task = tasks.make_task("funnel")
    Q, R, target = task.Q, task.R, task.target

    def dynamics(x, u, t):
        return helicopter.step(x, u, jnp.zeros(6))

    def cost(x, u, t):
        dx = helicopter.to_error(x, target[t])
        return dx @ Q @ dx + u @ R @ u

    dynamics, cost = jax.jit(dynamics), jax.jit(cost)
    rng = np.random.default_rng(1)
    T = 3
    X = np.asarray(target[150 : 150 + T + 1]) + 0.05 * rng.standard_normal((T + 1, 21))
    U = 0.1 * rng.standard_normal((T, 4))
    quad = quadratize(dynamics, cost, jnp.asarray(X), jnp.asarray(U))
    t0 = 1  # compare step 1 of the window (time index 1)
    x, u = X[t0], U[t0]
    f = lambda z: np.asarray(dynamics(jnp.asarray(z[:21]), jnp.asarray(z[21:]), t0))  # noqa: E731
    J = _central_jacobian(f, np.concatenate([x, u]), 1e-6)
    np.testing.assert_allclose(quad.A[t0], J[:, :21], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(quad.B[t0], J[:, 21:], rtol=1e-6, atol=1e-8)
    grad = jax.jit(jax.grad(cost, argnums=(0, 1)))

    def g(z):
        return np.concatenate([np.asarray(v) for v in grad(z[:21], z[21:], t0)])

    z = np.concatenate([x, u])
    Hfd = _central_jacobian(g, z, 1e-5)
    np.testing.assert_allclose(quad.lxx[t0], Hfd[:21, :21], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(quad.lxu[t0], Hfd[:21, 21:], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(quad.luu[t0], Hfd[21:, 21:], rtol=1e-6, atol=1e-9)
    c = lambda z: np.asarray(cost(jnp.asarray(z[:21]), jnp.asarray(z[21:]), t0))[None]  # noqa: E731
    gfd = _central_jacobian(c, z, 1e-6)[0]
    np.testing.assert_allclose(quad.lx[t0], gfd[:21], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(quad.lu[t0], gfd[21:], rtol=1e-6, atol=1e-8)
    # the terminal terms use u = 0 at t = T
    cT = lambda z: np.asarray(cost(jnp.asarray(z), jnp.zeros(4), T))[None]  # noqa: E731
    gT = _central_jacobian(cT, X[T], 1e-6)[0]
    np.testing.assert_allclose(quad.lx_T, gT, rtol=1e-6, atol=1e-8)


def test_usable_inside_vmap(rng, lq):
    dynamics, cost, _, _ = lq
    x0s = jnp.asarray(rng.standard_normal((2, 4)))
    batched = jax.vmap(lambda x0: ilqr(dynamics, cost, x0, jnp.zeros((30, 2))).U)(x0s)
    for i in range(2):
        np.testing.assert_allclose(
            batched[i], ilqr(dynamics, cost, x0s[i], jnp.zeros((30, 2))).U, rtol=1e-10
        )


def test_input_checks_name_the_argument(lq):
    dynamics, cost, _, _ = lq
    with pytest.raises(ValueError, match=r"x0 must have shape"):
        ilqr(dynamics, cost, jnp.zeros((4, 1)), jnp.zeros((5, 2)))
    with pytest.raises(ValueError, match=r"U0 must have shape"):
        ilqr(dynamics, cost, jnp.zeros(4), jnp.zeros(5))
    with pytest.raises(ValueError, match=r"dynamics\(x0, U0\[0\], 0\) must have shape"):
        ilqr(lambda x, u, t: x[:2], cost, jnp.zeros(4), jnp.zeros((5, 2)))
    with pytest.raises(ValueError, match=r"cost\(x0, U0\[0\], 0\) must be a scalar"):
        ilqr(dynamics, lambda x, u, t: x, jnp.zeros(4), jnp.zeros((5, 2)))
    with pytest.raises(ValueError, match=r"K0 must have shape"):
        ilqr(dynamics, cost, jnp.zeros(4), jnp.zeros((5, 2)), K0=jnp.zeros((5, 2, 3)))
    with pytest.raises(ValueError, match=r"max_iter"):
        ilqr(dynamics, cost, jnp.zeros(4), jnp.zeros((5, 2)), max_iter=0)
    with pytest.raises(ValueError, match=r"U0 must be finite"):
        ilqr(dynamics, cost, jnp.zeros(4), jnp.full((5, 2), jnp.nan))
