"""Planning on a learned model: iLQR with the model's parameters traced, its policy as the loop's
gains, and the costs it is used with (model-predictive control: :mod:`loopid.control.mpc`).

Problem (the :mod:`loopid.control.ilqr` problem with a parameterised model)::

    minimise_U  Σ_{t=0}^{T-1} cost(x_t, u_t, t0 + t) + cost(x_T, 0, t0 + T)
    subject to  x_{t+1} = dynamics(params, x_t, u_t, t0 + t),   x_0 given,

with ``dynamics(params, x [n], u [m], t) -> [n]`` and ``cost(x, u, t) -> scalar``. ``params`` is
any pytree (a learned model's weights) and ``t0`` an int; both are *traced* arguments, while
``dynamics`` and ``cost`` are static (hashed by identity, or by value for :class:`QuadraticCost`):
one compilation of :func:`plan` serves every model the loop learns, every iteration and, under
``jax.vmap``, every seed. Keep the same function objects to reuse the compiled code.

Policies. iLQR's local policy ``u_t = U_t − K_t(x_t − X_t) − α k_t`` is, in the loop's error
coordinates (the state ends with the constant 1), one time-varying affine gain
``u_t = −K'_t x_t`` (:func:`as_gains`), the ``K [horizon, m, n]`` every other solver of the loop
returns (Ross & Bagnell 2012, Algorithm 1: the policy handed to the real system).

Clipped actions: a clip in the dynamics has zero derivative outside its range, so iLQR cannot
see that a larger torque does nothing; :class:`QuadraticCost` adds a smooth penalty
``w Σ_i max(|u_i| − u_limit, 0)²`` that keeps the plan inside the limit (Pendulum-v1:
:mod:`loopid.systems.pendulum`).

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

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from loopid.control._checks import check_finite, shape_of
from loopid.control.ilqr import DEFAULT_ALPHAS, ILQRSolution, check_settings, ilqr_core

__all__ = [
    "MPCRollout",
    "Penalized",
    "QuadraticCost",
    "action_penalty",
    "as_gains",
    "plan",
    "quadratic_cost",
]


# ----------------------------------------------------------------------------- cost
def action_penalty(u, u_limit: float, weight: float):
    """``weight Σ_i max(|u_i| − u_limit, 0)²``: zero inside the limit, C¹, quadratic outside."""
    return weight * jnp.sum(jnp.maximum(jnp.abs(u) - u_limit, 0.0) ** 2)


@dataclass(frozen=True)
class Penalized:
    """``cost(x, u, t) + weight Σ_i max(|u_i| − u_limit, 0)²`` (:func:`action_penalty`).

    Keeps a plan inside an action limit that the dynamics enforce with a clip (module
    docstring). Hashable (by ``cost``'s identity and the two numbers), so a ``Penalized`` made
    twice from the same function shares compiled code."""

    cost: Callable
    u_limit: float
    weight: float = 100.0

    def __post_init__(self):
        if not callable(self.cost):
            raise TypeError(f"cost must be callable, got {self.cost!r}")
        _check_limit(self.u_limit, self.weight)

    def __call__(self, x, u, t=None):
        return self.cost(x, u, t) + action_penalty(u, self.u_limit, self.weight)


@dataclass(frozen=True)
class QuadraticCost:
    """``c(x, u, t) = xᵀQx + uᵀRu (+ weight Σ_i max(|u_i| − u_limit, 0)² when ``u_limit`` is
    set)``. Frozen and hashable by value (Q and R are kept as nested tuples), so two equal costs
    share compiled code. Build it with :func:`quadratic_cost`."""

    Q: tuple
    R: tuple
    u_limit: float | None = None
    weight: float = 100.0

    def __call__(self, x, u, t=None):
        Q = jnp.asarray(self.Q, jnp.float64)
        R = jnp.asarray(self.R, jnp.float64)
        c = x @ Q @ x + u @ R @ u
        if self.u_limit is not None:
            c = c + action_penalty(u, self.u_limit, self.weight)
        return c


def _check_limit(u_limit, weight) -> None:
    if u_limit is not None and not (np.isfinite(u_limit) and u_limit > 0):
        raise ValueError(f"u_limit must be a positive number or None, got {u_limit!r}")
    if not (np.isfinite(weight) and weight >= 0):
        raise ValueError(f"weight must be a non-negative number, got {weight!r}")


def quadratic_cost(Q, R, *, u_limit: float | None = None, weight: float = 100.0) -> QuadraticCost:
    """:class:`QuadraticCost` from ``Q [n, n]``, ``R [m, m]``, an optional action limit
    ``u_limit > 0`` and the penalty ``weight >= 0``; ValueError naming a bad value."""
    Q = np.asarray(Q, np.float64)
    R = np.asarray(R, np.float64)
    if Q.ndim != 2 or Q.shape[0] != Q.shape[1] or R.ndim != 2 or R.shape[0] != R.shape[1]:
        raise ValueError(f"Q and R must be square matrices, got shapes {Q.shape} and {R.shape}")
    _check_limit(u_limit, weight)
    as_tuple = lambda A: tuple(tuple(float(v) for v in row) for row in A)  # noqa: E731
    limit = None if u_limit is None else float(u_limit)
    return QuadraticCost(as_tuple(Q), as_tuple(R), limit, float(weight))


# ----------------------------------------------------------------------------- checks
def _positive_int(name: str, value, hint: str = "") -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive int{hint}, got {value!r}")
    return int(value)


def _check_every(every, horizon: int) -> int:
    if (
        isinstance(every, bool)
        or not isinstance(every, int | np.integer)
        or not (1 <= every <= horizon)
    ):
        raise ValueError(f"every must be an int in [1, horizon={horizon}], got {every!r}")
    return int(every)


def _check_problem(dynamics, cost, params, x0, U0, t0=0) -> tuple[int, int]:
    """Shapes of x0 [n] and U0 [T, m] and of what dynamics/cost return (jax.eval_shape)."""
    sx = shape_of("x0", x0)
    sU = shape_of("U0", U0)
    if len(sx) != 1:
        raise ValueError(f"x0 must have shape [n], got shape {sx}")
    if len(sU) != 2 or sU[0] < 1:
        raise ValueError(f"U0 must have shape [T, m] with T >= 1, got shape {sU}")
    x = jax.ShapeDtypeStruct(sx, jnp.float64)
    u = jax.ShapeDtypeStruct(sU[1:], jnp.float64)
    t = jax.ShapeDtypeStruct((), jnp.asarray(t0).dtype)
    x_next = jax.eval_shape(dynamics, params, x, u, t)
    if x_next.shape != sx:
        raise ValueError(f"dynamics(params, x0, U0[0], t) must have shape {sx}, got {x_next.shape}")
    c = jax.eval_shape(cost, x, u, t)
    if c.shape != ():
        raise ValueError(f"cost(x0, U0[0], t) must be a scalar, got shape {c.shape}")
    return sx[0], sU[1]


def _initial_actions(U0, horizon: int) -> tuple[Array, int]:
    """``U0`` as ``[horizon, m]``: a ``[m]`` vector is repeated, ``[horizon, m]`` kept."""
    s = shape_of("U0", U0)
    if len(s) == 1:
        U0 = jnp.broadcast_to(jnp.asarray(U0, jnp.float64), (horizon, s[0]))
    elif len(s) != 2 or s[0] != horizon:
        raise ValueError(f"U0 must have shape [m] or [horizon={horizon}, m], got shape {s}")
    check_finite("U0", U0)
    return jnp.asarray(U0, jnp.float64), int(U0.shape[-1])


def _alternatives(alternatives, horizon: int, m: int):
    """``alternatives`` as ``[A, horizon, m]`` (``[A, m]``: constant actions), or None."""
    if alternatives is None:
        return None
    s = shape_of("alternatives", alternatives)
    A = jnp.asarray(alternatives, jnp.float64)
    if len(s) == 2 and s[1] == m and s[0] >= 1:
        A = jnp.broadcast_to(A[:, None, :], (s[0], horizon, m))
    elif not (len(s) == 3 and s[0] >= 1 and s[1:] == (horizon, m)):
        raise ValueError(
            f"alternatives must have shape [A, {m}] or [A, horizon={horizon}, {m}] with A >= 1, "
            f"got shape {s}"
        )
    check_finite("alternatives", alternatives)
    return A


# ----------------------------------------------------------------------------- plan
class _Settings(NamedTuple):
    """iLQR's numeric settings (traced, so changing them does not recompile)."""

    alphas: Array
    tol: Array
    atol: Array
    mu_init: Array
    mu_min: Array
    mu_max: Array
    mu_factor: Array


def _settings(alphas, tol, atol, mu_init, mu_min, mu_max, mu_factor) -> _Settings:
    alphas = check_settings(alphas, mu_init, mu_min, mu_max, mu_factor)
    f = lambda v: jnp.asarray(v, jnp.float64)  # noqa: E731
    return _Settings(alphas, f(tol), f(atol), f(mu_init), f(mu_min), f(mu_max), f(mu_factor))


def _plan(dynamics, cost, iterations, params, x0, U0, K0, t0, s: _Settings) -> ILQRSolution:
    """Jittable core: iLQR on ``dynamics(params, ·)`` with the clock started at ``t0``."""
    dyn = lambda x, u, t: dynamics(params, x, u, t0 + t)  # noqa: E731
    stage = lambda x, u, t: cost(x, u, t0 + t)  # noqa: E731
    return ilqr_core(dyn, stage, x0, U0, K0, s.alphas, iterations, s.tol, s.atol, *s[3:])


def _best_plan(model, cost, iterations, params, x, U_init, K_init, t0, s, U_alt):
    """The plan from (U_init, K_init) or, with ``U_alt [A, H, m]``, the cheapest of it and the
    A plans from the open-loop actions ``U_alt`` (all planned at once, vmapped)."""
    if U_alt is None:
        return _plan(model, cost, iterations, params, x, U_init, K_init, t0, s)
    U0 = jnp.concatenate([U_init[None], U_alt])
    K0 = jnp.concatenate([K_init[None], jnp.zeros((U_alt.shape[0], *K_init.shape))])
    one = lambda U0, K0: _plan(model, cost, iterations, params, x, U0, K0, t0, s)  # noqa: E731
    sols = jax.vmap(one)(U0, K0)
    i = jnp.argmin(jnp.where(jnp.isfinite(sols.cost), sols.cost, jnp.inf))
    return jax.tree.map(lambda a: a[i], sols)


# ----------------------------------------------------------------------------- the MPC episode
# (its public face is loopid.control.mpc; it lives here because plan's seed runs it)
def _warm_start(X, U, K, shift):
    """The previous plan's policy (X [H+1, n], U [H, m], K [H, m, n]) advanced by ``shift``
    steps as iLQR's initial closed loop ``u_j = U0_j − K0_j x``: U0_j = U_{j+s} + K_{j+s} X_{j+s}
    and K0_j = K_{j+s} while j + s < H, then U_{H-1} open loop (K0 = 0). ``shift`` may be traced.
    """
    H = U.shape[0]
    j = jnp.arange(H) + shift
    inside = j < H
    i = jnp.minimum(j, H - 1)
    U0 = jnp.where(inside[:, None], U[i] + jnp.einsum("hmn,hn->hm", K[i], X[i]), U[H - 1])
    K0 = jnp.where(inside[:, None, None], K[i], 0.0)
    return U0, K0


def _local_action(sol: ILQRSolution, x, tau, alpha):
    return sol.U[tau] - sol.K[tau] @ (x - sol.X[tau]) - alpha * sol.k[tau]


class MPCRollout(NamedTuple):
    """Result of :func:`mpc_rollout`.

    Attributes:
        X: ``[T+1, n]`` states of the true system.
        U: ``[T, m]`` actions applied.
        costs: ``[T]`` stage costs ``cost(X_t, U_t, t)``.
        iterations: ``[P]`` iLQR iterations of each of the P = ⌈T / every⌉ plans.
        converged: ``[P]`` whether each plan converged within its ``iterations``.
    """

    X: Array
    U: Array
    costs: Array
    iterations: Array
    converged: Array


def _mpc(true, model, cost, T, every, iterations, params, x0, U0, alpha, s, start=0, U_alt=None):
    """Jittable core of :func:`mpc_rollout` (``true=None``: fly the model itself); the clock
    starts at ``start``."""
    H, m = U0.shape
    n = x0.shape[0]
    blocks = -(-T // every)
    if true is None:
        true = lambda x, u, t: model(params, x, u, t)  # noqa: E731

    def block(carry, b):
        x, U_init, K_init = carry
        t0 = start + b * every
        sol = _best_plan(model, cost, iterations, params, x, U_init, K_init, t0, s, U_alt)

        def inner(x, j):
            u = _local_action(sol, x, j, alpha)
            return true(x, u, t0 + j), (x, u)

        x_end, (Xs, Us) = jax.lax.scan(inner, x, jnp.arange(every))
        U_next, K_next = _warm_start(sol.X, sol.U, sol.K, every)
        return (x_end, U_next, K_next), (Xs, Us, sol.iterations, sol.converged)

    K0 = jnp.zeros((H, m, n), jnp.float64)
    (x_end, _, _), (Xs, Us, its, conv) = jax.lax.scan(block, (x0, U0, K0), jnp.arange(blocks))
    Xs = Xs.reshape(blocks * every, n)
    Us = Us.reshape(blocks * every, m)
    X = jnp.concatenate([Xs, x_end[None]])[: T + 1]  # blocks·every >= T steps were run
    U = Us[:T]
    costs = jax.vmap(cost)(X[:-1], U, start + jnp.arange(T))
    return MPCRollout(X, U, costs, its, conv)


def _plan_seeded(dynamics, cost, iterations, seed, params, x0, U0, K0, t0, s, U_alt=None):
    """:func:`_plan` from the actions of an MPC episode on the model itself when ``seed`` =
    (horizon, every, iterations) is given."""
    if seed is not None:
        H, every, seed_iterations = seed
        T = U0.shape[0]
        run = _mpc(
            None, dynamics, cost, T, every, seed_iterations, params, x0, U0[:H], 0.0, s, t0, U_alt
        )
        U0 = run.U
    return _plan(dynamics, cost, iterations, params, x0, U0, K0, t0, s)


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
    n, m = _check_problem(dynamics, cost, params, x0, U0, t0)
    iterations = _positive_int("iterations", iterations)
    T = shape_of("U0", U0)[0]
    if K0 is not None and shape_of("K0", K0) != (T, m, n):
        raise ValueError(f"K0 must have shape {(T, m, n)}, got {shape_of('K0', K0)}")
    seed = None
    if seed_horizon is not None:
        H = _positive_int("seed_horizon", seed_horizon, f" <= T={T}")
        if H > T:
            raise ValueError(f"seed_horizon must be a positive int <= T={T}, got {H}")
        seed = (H, _check_every(seed_every, H), _positive_int("seed_iterations", seed_iterations))
        if K0 is not None:
            raise ValueError("K0 must be None when seed_horizon is set (the MPC episode seeds)")
        U_alt = _alternatives(seed_alternatives, H, m)
    elif seed_alternatives is not None:
        raise ValueError("seed_alternatives needs seed_horizon")
    else:
        U_alt = None
    for name, v in (("x0", x0), ("U0", U0), ("K0", K0)):
        check_finite(name, v)
    K0 = jnp.zeros((T, m, n), jnp.float64) if K0 is None else jnp.asarray(K0, jnp.float64)
    s = _settings(alphas, tol, atol, mu_init, mu_min, mu_max, mu_factor)
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
