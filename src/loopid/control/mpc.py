"""Model-predictive control (MPC) with warm-started iLQR on a learned model: one compiled
episode on a JAX system (:func:`mpc_rollout`), and the re-planning step itself
(:class:`Replanner`, :func:`replan`, :func:`local_action`) for controllers that live inside a
larger compiled loop (the JAX plants' MPC, :mod:`loopid.algorithms.mpc_plant`) and for the
jitted re-planner for Gymnasium envs (:class:`~loopid.control.mpc_controller.MPCController`).
Problem, conventions and settings: :mod:`loopid.control.plan`.

MPC (receding horizon; e.g. Tassa, Erez & Todorov 2012): every ``every`` steps, plan over the
next ``horizon`` steps from the current state with ``iterations`` iLQR iterations, warm-started
from the previous plan's policy shifted by ``every`` steps (its last action repeated open loop),
and between re-plans apply the plan's local feedback ``u = U_τ − K_τ(x − X_τ) − α k_τ``
(τ = steps since the plan). :func:`mpc_rollout` runs a whole episode on a JAX system as one
``lax.scan`` (vmappable over starts and seeds); :class:`~loopid.control.MPCController` is the
same controller for Gymnasium envs, one jitted, vmapped planning call for all envs at each step.

Why ``alternatives`` (the swing-up's local minima, measured): :mod:`loopid.control.plan`.

The episode's pieces (:func:`~loopid.control.receding_horizon.mpc_episode`, the warm start, the
local feedback, :class:`~loopid.control.receding_horizon.MPCRollout`) are defined in
:mod:`loopid.control.receding_horizon`, because :func:`~loopid.control.plan`'s seed runs an
episode too and the package keeps an acyclic import graph; this module is their public face.
The Gymnasium controller is :mod:`loopid.control.mpc_controller`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from loopid.control._checks import check_finite
from loopid.control.ilqr import DEFAULT_ALPHAS, ILQRSolution
from loopid.control.plan_settings import (
    Settings,
    alternative_actions,
    check_every,
    check_problem,
    ilqr_settings,
    initial_actions,
    positive_int,
)
from loopid.control.receding_horizon import (
    MPCRollout,
    best_plan,
    local_feedback,
    mpc_episode,
    warm_start,
)

__all__ = [
    "Replanner",
    "empty_plan",
    "local_action",
    "mpc_rollout",
    "replan",
    "replanner",
]


_mpc_jit = jax.jit(mpc_episode, static_argnums=(0, 1, 2, 3, 4, 5, 11))


def mpc_rollout(
    params,
    dynamics_true,
    model_dynamics,
    cost,
    x0,
    T: int,
    *,
    U0,
    horizon: int,
    every: int = 1,
    iterations: int = 10,
    alternatives=None,
    alpha: float = 0.0,
    tol: float = 1e-9,
    atol: float = 0.0,
    alphas=DEFAULT_ALPHAS,
    mu_init: float = 0.0,
    mu_min: float = 1e-6,
    mu_max: float = 1e10,
    mu_factor: float = 10.0,
) -> MPCRollout:
    """One MPC episode of ``T`` steps on the JAX system ``dynamics_true(x, u, t)`` from ``x0
    [n]``, planning on ``model_dynamics(params, x, u, t)`` (module docstring) as one ``lax.scan``.

    Args:
        params: the model's parameters (any pytree; traced).
        dynamics_true: ``(x [n], u [m], t) -> [n]``, the system flown (None: the model itself).
        model_dynamics: ``(params, x [n], u [m], t) -> [n]``, the system planned on.
        cost: ``(x, u, t) -> scalar``; plans over [t0, t0 + horizon] end with cost(x, 0, t0 + H).
        x0: ``[n]`` start state.
        T: episode length (static).
        U0: the first plan's initial actions, ``[m]`` (repeated) or ``[horizon, m]``.
        horizon: planning horizon H (static), ``every``: steps between re-plans, 1 <= every <= H
            (static), ``iterations``: iLQR iterations per plan (static).
        alternatives: optional ``[A, m]`` (constant) or ``[A, horizon, m]`` open-loop initial
            actions planned at every re-plan besides the warm start; the cheapest plan (on the
            model) is flown. A way out of local minima (the swing-up: ±u_limit), at A + 1 times
            the planning work.
        alpha: the step on iLQR's feedforward in the applied feedback u = U − K(x − X) − α k
            (0: follow the plan's own trajectory, the default; 1: its full next Newton step).
        tol, atol, alphas, mu_*: :func:`loopid.control.ilqr`'s settings (traced).

    Returns :class:`MPCRollout`. Vmappable over ``params``, ``x0`` and ``U0``; the checks read
    shapes only.
    """
    r = replanner(
        model_dynamics, cost, U0, horizon=horizon, every=every, iterations=iterations,
        alternatives=alternatives, alpha=alpha, tol=tol, atol=atol, alphas=alphas,
        mu_init=mu_init, mu_min=mu_min, mu_max=mu_max, mu_factor=mu_factor,
    )  # fmt: skip
    T = positive_int("T", T)
    n, m = check_problem(model_dynamics, cost, params, x0, r.U0)
    x = jax.ShapeDtypeStruct((n,), jnp.float64)
    u = jax.ShapeDtypeStruct((m,), jnp.float64)
    if dynamics_true is not None:
        if jax.eval_shape(dynamics_true, x, u, jnp.asarray(0)).shape != (n,):
            raise ValueError(f"dynamics_true(x0, u, t) must have shape {(n,)}")
    check_finite("x0", x0)
    x0 = jnp.asarray(x0, jnp.float64)
    a = jnp.asarray(r.alpha, jnp.float64)
    return _mpc_jit(
        dynamics_true, model_dynamics, cost, T, r.every, r.iterations, params, x0, r.U0, a,
        r.settings, 0, r.alternatives,
    )  # fmt: skip


# ----------------------------------------------------------------------------- the re-planning step
class Replanner(NamedTuple):
    """MPC's settings for a controller that re-plans inside a larger compiled loop (build it with
    :func:`replanner`; hashable except for the arrays, which are traced).

    Attributes:
        model: ``(params, x [n], u [m], t) -> [n]``, the model planned on (static).
        cost: ``(x, u, t) -> scalar`` (static).
        horizon: H, the steps of each plan; ``every``: steps between re-plans (1 <= every <= H);
            ``iterations``: iLQR iterations per plan.
        U0: ``[H, m]`` the actions a fresh plan starts from (a new episode's first plan).
        alternatives: ``[A, H, m]`` open-loop actions also planned at every re-plan (the
            cheapest plan on the model is kept), or None.
        alpha: the step on iLQR's feedforward in the applied feedback (:func:`local_action`).
        settings: iLQR's numeric settings (traced).
    """

    model: Callable
    cost: Callable
    horizon: int
    every: int
    iterations: int
    U0: jax.Array
    alternatives: jax.Array | None
    alpha: float
    settings: Settings


def replanner(
    model_dynamics,
    cost,
    U0,
    *,
    horizon: int,
    every: int = 1,
    iterations: int = 10,
    alternatives=None,
    alpha: float = 0.0,
    tol: float = 1e-9,
    atol: float = 0.0,
    alphas=DEFAULT_ALPHAS,
    mu_init: float = 0.0,
    mu_min: float = 1e-6,
    mu_max: float = 1e10,
    mu_factor: float = 10.0,
) -> Replanner:
    """A checked :class:`Replanner` (arguments as in :func:`mpc_rollout`; ``U0`` ``[m]`` or
    ``[horizon, m]``). ValueError naming a bad size or setting."""
    horizon = positive_int("horizon", horizon)
    every = check_every(every, horizon)
    iterations = positive_int("iterations", iterations)
    U0, m = initial_actions(U0, horizon)
    s = ilqr_settings(alphas, tol, atol, mu_init, mu_min, mu_max, mu_factor)
    U_alt = alternative_actions(alternatives, horizon, m)
    return Replanner(model_dynamics, cost, horizon, every, iterations, U0, U_alt, float(alpha), s)


def empty_plan(r: Replanner, n: int) -> ILQRSolution:
    """A plan of zeros with :func:`replan`'s shapes (``X [H+1, n]``, ``U [H, m]``, ...): the
    placeholder a controller carries before its first plan (pass ``fresh=True`` with it)."""
    H, m = r.U0.shape
    z = jnp.float64(0.0)
    return ILQRSolution(
        jnp.zeros((H + 1, n)), jnp.zeros((H, m)), jnp.zeros((H, m, n)), jnp.zeros((H, m)), z,
        jnp.int32(0), jnp.bool_(False), jnp.zeros(r.iterations + 1),
    )  # fmt: skip


def replan(r: Replanner, params, x, t, previous: ILQRSolution, fresh, shift=None) -> ILQRSolution:
    """One MPC plan (pure; vmappable): iLQR on ``r.model(params, ·)`` over ``r.horizon`` steps
    from the state ``x [n]`` at time ``t``, warm-started from ``previous`` advanced by ``shift``
    steps (default ``r.every``; its policy ``u_j = U_{j+s} − K_{j+s}(x − X_{j+s})``, the last
    action repeated open loop past its end), or from ``r.U0`` where ``fresh``; with
    ``r.alternatives`` the cheapest of those plans on the model."""
    shift = r.every if shift is None else shift
    t = jnp.asarray(t).astype(int)  # the planner's clock is the default integer type
    U_w, K_w = warm_start(previous.X, previous.U, previous.K, shift)
    U_init = jnp.where(fresh, r.U0, U_w)
    K_init = jnp.where(fresh, 0.0, K_w)
    return best_plan(
        r.model, r.cost, r.iterations, params, x, U_init, K_init, t, r.settings, r.alternatives
    )


def local_action(r: Replanner, plan: ILQRSolution, x, tau) -> jax.Array:
    """The plan's feedback ``u = U_τ − K_τ(x − X_τ) − α k_τ`` at ``τ`` steps since it was made."""
    return local_feedback(plan, x, tau, r.alpha)
