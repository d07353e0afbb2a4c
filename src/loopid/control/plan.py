"""Planning on a learned model: iLQR with the model's parameters traced and its policy as the
loop's gains (the costs it is used with: :mod:`loopid.control.costs`; model-predictive control:
:mod:`loopid.control.mpc`).

Problem (the :mod:`loopid.control.ilqr` problem with a parameterised model)::

    minimise_U  Σ_{t=0}^{T-1} cost(x_t, u_t, t0 + t) + cost(x_T, 0, t0 + T)
    subject to  x_{t+1} = dynamics(params, x_t, u_t, t0 + t),   x_0 given,

with ``dynamics(params, x [n], u [m], t) -> [n]`` and ``cost(x, u, t) -> scalar``. ``params`` is
any pytree (a learned model's weights) and ``t0`` an int; both are *traced* arguments, while
``dynamics`` and ``cost`` are static (hashed by identity, or by value for
:class:`~loopid.control.costs.QuadraticCost`): one compilation of :func:`plan` serves every model
the loop learns, every iteration and, under ``jax.vmap``, every seed. Keep the same function
objects to reuse the compiled code.

Policies. iLQR's local policy ``u_t = U_t − K_t(x_t − X_t) − α k_t`` is, in the loop's error
coordinates (the state ends with the constant 1), one time-varying affine gain
``u_t = −K'_t x_t`` (:func:`as_gains`), the ``K [horizon, m, n]`` every other solver of the loop
returns (Ross & Bagnell 2012, Algorithm 1: the policy handed to the real system).

Clipped actions: a clip in the dynamics has zero derivative outside its range, so iLQR cannot
see that a larger torque does nothing; the costs of :mod:`loopid.control.costs` add a smooth
penalty that keeps the plan inside the limit.

Local minima (measured on Pendulum-v1 from hanging, 200 steps, the true model). iLQR over the
whole episode stops in a local minimum that never swings up, whatever the initial actions:
with the quadratic ``ΔxᵀQΔx``, Q = diag(1, 1, 0.1, 0), R = 0.001, from U0 = 0 it stops after
one iteration (hanging at rest is a stationary point: the cost's only gradient, along
cos θ − 1, is not reachable to first order, and the Gauss-Newton model even makes the bottom a
minimum, missing the cos curvature that lives in the dynamics' second derivatives); from
U0 = 0.2 it converges (226 iterations) to J = 773, pushing to the side and holding. With Gym's
own cost in Δx (:func:`loopid.systems.pendulum.cost_obs`, θ = atan2, whose gradient does not
vanish at the bottom) it still ends near 1250-1500 from zeros, constants, noise or sinusoids.
MPC (:mod:`loopid.control.mpc`) escapes: re-planning every step over 60 steps (10 iterations,
warm start plus the alternatives ±2, Gym's cost) swings up from every start tried, and the
200-step iLQR seeded by that episode (``plan(..., seed_horizon=60, seed_alternatives=[[2],
[-2]])``) converges in 31 more iterations to J = 295.4, which flown as gains on Gymnasium's env
costs 295.4 and holds upright for the last quarter. Without the alternatives MPC fails from the
exact hanging start (horizon 40-80) and on some noisy starts.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from loopid.control._checks import check_finite, shape_of
from loopid.control.ilqr import DEFAULT_ALPHAS, ILQRSolution
from loopid.control.plan_settings import (
    alternative_actions,
    check_every,
    check_problem,
    ilqr_settings,
    positive_int,
)
from loopid.control.receding_horizon import mpc_episode, plan_core

__all__ = ["as_gains", "plan"]


def _plan_seeded(dynamics, cost, iterations, seed, params, x0, U0, K0, t0, s, U_alt=None):
    """:func:`~loopid.control.receding_horizon.plan_core` from the actions of an MPC episode on
    the model itself when ``seed`` = (horizon, every, iterations) is given."""
    if seed is not None:
        H, every, seed_iterations = seed
        T = U0.shape[0]
        run = mpc_episode(
            None, dynamics, cost, T, every, seed_iterations, params, x0, U0[:H], 0.0, s, t0, U_alt
        )
        U0 = run.U
    return plan_core(dynamics, cost, iterations, params, x0, U0, K0, t0, s)


_plan_jit = jax.jit(_plan_seeded, static_argnums=(0, 1, 2, 3))


def plan(
    dynamics,
    cost,
    x0,
    U0,
    *,
    params=None,
    iterations: int = 50,
    K0=None,
    t0=0,
    tol: float = 1e-9,
    atol: float = 0.0,
    alphas=DEFAULT_ALPHAS,
    mu_init: float = 0.0,
    mu_min: float = 1e-6,
    mu_max: float = 1e10,
    mu_factor: float = 10.0,
    seed_horizon: int | None = None,
    seed_every: int = 1,
    seed_iterations: int = 10,
    seed_alternatives=None,
) -> ILQRSolution:
    """iLQR on the model ``dynamics(params, x, u, t)`` from ``x0 [n]`` and initial actions
    ``U0 [T, m]`` (module docstring); at most ``iterations`` iterations.

    ``params`` (any pytree) and ``t0`` (the time of x0, an int) are traced: calling again with
    other values, inside ``jit``, or under ``vmap`` (over params, x0, U0, ...) reuses one
    compilation. ``dynamics`` and ``cost`` are static. ``K0`` ``[T, m, n]``: optional initial
    feedback, the first nominal being u_t = U0_t − K0_t x_t. The other settings are
    :func:`loopid.control.ilqr`'s. Returns :class:`~loopid.control.ILQRSolution`.

    Seeding (``seed_horizon`` H set): iLQR over T steps finds a poor local minimum on problems
    such as the torque-limited swing-up, whatever the initial actions (module docstring). With
    H set, the initial actions are instead those of an MPC episode on the model itself
    (:func:`~loopid.control.mpc_rollout` with horizon H, ``seed_every``, ``seed_iterations``,
    ``alternatives=seed_alternatives``, first plan from ``U0[:H]``), refined by the T-step iLQR.
    ``K0`` must then be None.
    """
    n, m = check_problem(dynamics, cost, params, x0, U0, t0)
    iterations = positive_int("iterations", iterations)
    T = shape_of("U0", U0)[0]
    if K0 is not None and shape_of("K0", K0) != (T, m, n):
        raise ValueError(f"K0 must have shape {(T, m, n)}, got {shape_of('K0', K0)}")
    seed = None
    if seed_horizon is not None:
        H = positive_int("seed_horizon", seed_horizon, f" <= T={T}")
        if H > T:
            raise ValueError(f"seed_horizon must be a positive int <= T={T}, got {H}")
        seed = (H, check_every(seed_every, H), positive_int("seed_iterations", seed_iterations))
        if K0 is not None:
            raise ValueError("K0 must be None when seed_horizon is set (the MPC episode seeds)")
        U_alt = alternative_actions(seed_alternatives, H, m)
    elif seed_alternatives is not None:
        raise ValueError("seed_alternatives needs seed_horizon")
    else:
        U_alt = None
    for name, v in (("x0", x0), ("U0", U0), ("K0", K0)):
        check_finite(name, v)
    K0 = jnp.zeros((T, m, n), jnp.float64) if K0 is None else jnp.asarray(K0, jnp.float64)
    s = ilqr_settings(alphas, tol, atol, mu_init, mu_min, mu_max, mu_factor)
    x0 = jnp.asarray(x0, jnp.float64)
    U0 = jnp.asarray(U0, jnp.float64)
    t0 = jnp.asarray(t0)
    return _plan_jit(dynamics, cost, iterations, seed, params, x0, U0, K0, t0, s, U_alt)


def as_gains(solution: ILQRSolution, *, alpha: float = 1.0) -> Array:
    """The local policy ``u_t = U_t − K_t(x_t − X_t) − α k_t`` as loop gains ``u_t = −K'_t x_t``.

    In error coordinates (``x[-1] = 1``): ``K'_t = K_t − (U_t + K_t X_t − α k_t) e_nᵀ``, i.e. the
    last (feedforward) column of K_t minus ``U_t + K_t X_t − α k_t``. ``alpha = 1`` is iLQR's
    full next step (``k ≈ 0`` at convergence), ``alpha = 0`` replays the plan's own (X, U).
    Shapes: ``K [..., T, m, n]``, ``X [..., T+1, n]``, ``U [..., T, m]`` -> ``[..., T, m, n]``.
    """
    K, X, U, k = solution.K, solution.X, solution.U, solution.k
    c = U + jnp.einsum("...tmn,...tn->...tm", K, X[..., :-1, :]) - alpha * k
    return K.at[..., -1].add(-c)
