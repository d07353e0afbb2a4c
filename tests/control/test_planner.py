"""loopid.control's planner (plan.py, mpc.py): iLQR with traced model parameters equals the
closed-over model, its gains replay the plan, MPC on an LQ problem is the infinite-horizon LQR
closed loop, vmap equals one at a time, the host controller equals the JAX rollout, the pendulum
swing-up, bad settings.

Run time is almost all compilation (measured: ~97% of it), so the tests share compiled programs:
keep the same model/cost objects, shapes and static settings (``iterations``, horizons) where a
test does not need its own."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.control import (
    MPCController,
    Penalized,
    as_gains,
    dlqr,
    ilqr,
    mpc_rollout,
    plan,
    quadratic_cost,
)
from loopid.systems import pendulum
from loopid.systems.pendulum import PendulumParams

COST = Penalized(pendulum.cost_obs, 2.0, 100.0)  # Gym's cost in Δx, with the torque penalty
PUSH = jnp.array([[2.0], [-2.0]])  # the swing-up's alternative initial actions (±u_max)
TRACES = {"model": 0}


def model(p, x, u, t):
    """Pendulum-v1 in error coordinates with its constants as (traced) parameters."""
    TRACES["model"] += 1
    return pendulum.step_obs(x, u, t, p)


def true(x, u, t):
    return pendulum.step_obs(x, u, t)


def traced(p: PendulumParams) -> PendulumParams:
    return PendulumParams(*(jnp.asarray(v, jnp.float64) for v in p))


def start(th, thdot=0.0):
    return pendulum.to_error(jnp.array([th, thdot]))


def test_plan_with_traced_params_equals_true_model_ilqr():
    """The learned model equal to the truth (its parameters traced) gives the true-model iLQR's
    trajectory; new parameter values reuse the one compilation (the model is traced once)."""
    x0 = start(2.0, 1.0)
    U0 = jnp.full((200, 1), 0.3)  # the swing-up test's shapes and settings: one compilation
    ref = ilqr(true, COST, x0, U0, max_iter=40)
    sol = plan(model, COST, x0, U0, params=traced(PendulumParams()), iterations=40)
    assert int(sol.iterations) == int(ref.iterations) >= 3
    for a, b in zip(sol, ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)
    n_traces = TRACES["model"]
    heavy = plan(model, COST, x0, U0, params=traced(PendulumParams(g=10.5)), iterations=40)
    assert TRACES["model"] == n_traces  # no retracing for new parameter values
    assert float(jnp.abs(heavy.X - sol.X).max()) > 1e-3  # ... which do change the plan
    # vmapped over three models (one per seed) under jit: each equals its own plan
    gs = jnp.array([10.0, 10.5, 9.5])
    many = jax.jit(
        jax.vmap(lambda g: plan(model, COST, x0, U0, params=PendulumParams(g=g), iterations=40))
    )(gs)
    for i, one in ((0, sol), (1, heavy)):
        for a, b in zip(one, many, strict=True):
            np.testing.assert_allclose(a, b[i], rtol=1e-10, atol=1e-10)


def test_as_gains_replays_the_plan():
    """u_t = −K'_t x_t on the model reproduces (X, U) with α = 0 and, with α = 1, the rollout
    of u_t = U_t − K_t(x_t − X_t) − k_t (a plan stopped early by a loose tol: k ≠ 0). The
    first test's shapes and static settings: no new compilation of the planner."""
    x0 = start(2.5)
    U0 = jnp.full((200, 1), 0.5)
    sol = plan(model, COST, x0, U0, params=traced(PendulumParams()), iterations=40, tol=0.1)
    assert float(jnp.abs(sol.k).max()) > 1e-3

    def fly(policy):
        def body(x, t):
            u = policy(x, t)
            return true(x, u, t), (x, u)

        x_end, (X, U) = jax.lax.scan(body, x0, jnp.arange(200))
        return jnp.concatenate([X, x_end[None]]), U

    K0 = as_gains(sol, alpha=0.0)
    assert K0.shape == (200, 1, 4)
    X, U = fly(lambda x, t: -K0[t] @ x)
    np.testing.assert_allclose(X, sol.X, atol=1e-10)
    np.testing.assert_allclose(U, sol.U, atol=1e-10)
    K1 = as_gains(sol)
    X1, U1 = fly(lambda x, t: -K1[t] @ x)
    X2, U2 = fly(lambda x, t: sol.U[t] - sol.K[t] @ (x - sol.X[t]) - sol.k[t])
    np.testing.assert_allclose(X1, X2, atol=1e-10)
    np.testing.assert_allclose(U1, U2, atol=1e-10)
    # batched solutions give batched gains
    both = jax.tree.map(lambda a: jnp.stack([a, a]), sol)
    np.testing.assert_allclose(as_gains(both)[1], K1, atol=0)


def lq_system():
    """A discretised double integrator with a spring (open-loop unstable) and an LQ cost."""
    A = jnp.array([[1.0, 0.1], [0.2, 1.0]])
    B = jnp.array([[0.0], [0.1]])
    Q, R = jnp.diag(jnp.array([1.0, 0.1])), jnp.array([[0.01]])
    return A, B, Q, R


def lq_true(x, u, t):
    A, B, _, _ = lq_system()
    return A @ x + B @ u


def lq_model(p, x, u, t):
    return p[0] @ x + p[1] @ u


def test_mpc_on_lq_problem_is_the_lqr_closed_loop():
    """With a long horizon, the receding-horizon iLQR (exact in one step on an LQ problem),
    re-planning every 4 steps and flying the plan's feedback in between, is the infinite-horizon
    LQR closed loop x_{t+1} = (A − B K∞) x_t, u_t = −K∞ x_t."""
    every = 4
    A, B, Q, R = lq_system()
    cost = quadratic_cost(Q, R)
    K = dlqr(A, B, Q, R).K
    x0 = jnp.array([1.0, -0.5])
    run = mpc_rollout(
        (A, B), lq_true, lq_model, cost, x0, 40, U0=jnp.zeros(1), horizon=80, every=every,
        iterations=3,
    )  # fmt: skip
    X = [x0]
    for _ in range(40):
        X.append((A - B @ K) @ X[-1])
    X = jnp.stack(X)
    np.testing.assert_allclose(run.X, X, atol=1e-8)
    np.testing.assert_allclose(run.U, -(X[:-1] @ K.T), atol=1e-8)
    assert bool(run.converged.all()) and run.iterations.shape == (-(-40 // every),)
    costs = jax.vmap(cost)(run.X[:-1], run.U)
    np.testing.assert_allclose(run.costs, costs, rtol=1e-12)
    # a short horizon is not the LQR loop (the test can tell)
    short = mpc_rollout(
        (A, B), lq_true, lq_model, cost, x0, 40, U0=jnp.zeros(1), horizon=3, every=1, iterations=3
    )
    assert float(jnp.abs(short.X - X).max()) > 1e-3


def test_vmap_equals_one_at_a_time_and_the_host_controller(rng):
    """mpc_rollout under jit + vmap over three starts equals one start at a time; the
    Gymnasium-side controller, fed the three pendulums' observations in a shuffled order each
    step, flies each one as mpc_rollout does (its warm starts follow the episodes)."""
    ths = np.array([np.pi - 0.2, 2.0, -2.5])
    X0 = jnp.stack([start(th) for th in ths])
    settings = dict(horizon=12, every=3, iterations=4, alternatives=PUSH)
    p = traced(PendulumParams())
    U0 = jnp.full(1, 0.1)
    run = jax.jit(jax.vmap(lambda x0: mpc_rollout(p, true, model, COST, x0, 20, U0=U0, **settings)))
    many = run(X0)
    for i in range(3):
        one = mpc_rollout(p, true, model, COST, X0[i], 20, U0=U0, **settings)
        for a, b in zip(one, many, strict=True):
            np.testing.assert_allclose(a, b[i], rtol=1e-10, atol=1e-10)
    assert float(jnp.abs(many.X[0] - many.X[1]).max()) > 0.1  # the starts differ

    ctrl = MPCController(model, COST, p, U0, target=pendulum.TARGET, a_op=[0.0], **settings)
    x = np.stack([ths, np.zeros(3)], axis=1)
    U = np.zeros((3, 20, 1))
    for t in range(20):
        order = rng.permutation(3)
        obs = np.asarray(pendulum.observe(jnp.asarray(x[order])))
        U[order, t] = ctrl.act(obs, np.full(3, t), np.zeros(3, np.int64))
        x = np.asarray(jax.vmap(pendulum.step)(jnp.asarray(x), jnp.asarray(U[:, t])))
    np.testing.assert_allclose(U, many.U, atol=1e-8)


def test_swing_up_from_hanging():
    """Pendulum-v1 from hanging (θ = π, at rest), 200 steps: iLQR from zero actions stops in a
    local minimum and never swings up (the Gauss-Newton model of the bottom is a minimum); seeded
    by an MPC episode (horizon 40, re-plan every step, 10 iterations, ±2 alternatives) it swings
    up and holds upright for the last quarter. Measured: unseeded J ≈ 1499, seeded ≈ 300 (the
    gym cost of the plan)."""
    x0 = start(np.pi)
    U0 = jnp.zeros((200, 1))
    p = traced(PendulumParams())
    stuck = plan(model, COST, x0, U0, params=p, iterations=40)
    assert float(stuck.cost) > 1000
    sol = plan(
        model, COST, x0, U0, params=p, iterations=40, seed_horizon=40,
        seed_alternatives=PUSH,
    )  # fmt: skip
    th = pendulum.from_error(sol.X)[:, 0]
    assert float(sol.cost) < 350
    assert float(jnp.abs(th[150:]).max()) < 0.05
    assert float(jnp.abs(sol.U).max()) < 2.01  # the penalty keeps the torque (nearly) inside


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(horizon=0), "horizon must be a positive int, got 0"),
        (dict(every=0), r"every must be an int in \[1, horizon=10\], got 0"),
        (dict(every=11), r"every must be an int in \[1, horizon=10\], got 11"),
        (dict(iterations=0), "iterations must be a positive int, got 0"),
        (dict(alternatives=jnp.zeros((2, 3))), "alternatives must have shape"),
    ],
)
def test_bad_settings_raise(kwargs, message):
    settings = dict(horizon=10, every=2, iterations=3) | kwargs
    x0 = start(1.0)
    for call in (
        lambda: mpc_rollout(
            PendulumParams(), true, model, COST, x0, 20, U0=jnp.zeros(1), **settings
        ),
        lambda: MPCController(
            model, COST, PendulumParams(), jnp.zeros(1), target=pendulum.TARGET, **settings
        ),
    ):
        with pytest.raises(ValueError, match=message) as err:
            call()
        assert "\n" not in str(err.value)
    if "iterations" in kwargs:
        with pytest.raises(ValueError, match=message):
            plan(model, COST, x0, jnp.zeros((5, 1)), params=PendulumParams(), iterations=0)
    with pytest.raises(ValueError, match="seed_horizon must be a positive int <= T=5, got 6"):
        plan(model, COST, x0, jnp.zeros((5, 1)), params=PendulumParams(), seed_horizon=6)
    with pytest.raises(ValueError, match="u_limit must be a positive number"):
        Penalized(pendulum.cost_obs, 0.0)
