"""Model-predictive control (MPC) with warm-started iLQR on a learned model: one compiled
episode on a JAX system (:func:`mpc_rollout`) and a jitted re-planner for Gymnasium envs
(:class:`MPCController`), and the re-planning step itself (:class:`Replanner`, :func:`replan`,
:func:`local_action`) for controllers that live inside a larger compiled loop (the JAX plants'
MPC, :mod:`loopid.algorithms.mpc_plant`). Problem, conventions and settings:
:mod:`loopid.control.plan`.

MPC (receding horizon; e.g. Tassa, Erez & Todorov 2012): every ``every`` steps, plan over the
next ``horizon`` steps from the current state with ``iterations`` iLQR iterations, warm-started
from the previous plan's policy shifted by ``every`` steps (its last action repeated open loop),
and between re-plans apply the plan's local feedback ``u = U_τ − K_τ(x − X_τ) − α k_τ``
(τ = steps since the plan). :func:`mpc_rollout` runs a whole episode on a JAX system as one
``lax.scan`` (vmappable over starts and seeds); :class:`MPCController` is the same controller for
Gymnasium envs, one jitted, vmapped planning call for all envs at each step.

Why ``alternatives`` (the swing-up's local minima, measured): :mod:`loopid.control.plan`.

The episode itself (``_mpc``: warm start, local feedback, :class:`MPCRollout`) is defined in
:mod:`loopid.control.plan`, because :func:`~loopid.control.plan`'s seed runs it and the package
keeps an acyclic import graph (``tests/test_imports.py``); this module is its public face.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.control._checks import check_finite
from loopid.control.ilqr import DEFAULT_ALPHAS, ILQRSolution
from loopid.control.plan import (
    MPCRollout,
    _alternatives,
    _best_plan,
    _check_every,
    _check_problem,
    _initial_actions,
    _local_action,
    _mpc,
    _positive_int,
    _Settings,
    _settings,
    _warm_start,
)

__all__ = [
    "MPCController",
    "MPCRollout",
    "Replanner",
    "empty_plan",
    "local_action",
    "mpc_rollout",
    "replan",
    "replanner",
]


_mpc_jit = jax.jit(_mpc, static_argnums=(0, 1, 2, 3, 4, 5, 11))


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
    T = _positive_int("T", T)
    n, m = _check_problem(model_dynamics, cost, params, x0, r.U0)
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
    settings: _Settings


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
    horizon = _positive_int("horizon", horizon)
    every = _check_every(every, horizon)
    iterations = _positive_int("iterations", iterations)
    U0, m = _initial_actions(U0, horizon)
    s = _settings(alphas, tol, atol, mu_init, mu_min, mu_max, mu_factor)
    U_alt = _alternatives(alternatives, horizon, m)
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
    U_w, K_w = _warm_start(previous.X, previous.U, previous.K, shift)
    U_init = jnp.where(fresh, r.U0, U_w)
    K_init = jnp.where(fresh, 0.0, K_w)
    return _best_plan(
        r.model, r.cost, r.iterations, params, x, U_init, K_init, t, r.settings, r.alternatives
    )


def local_action(r: Replanner, plan: ILQRSolution, x, tau) -> jax.Array:
    """The plan's feedback ``u = U_τ − K_τ(x − X_τ) − α k_τ`` at ``τ`` steps since it was made."""
    return _local_action(plan, x, tau, r.alpha)


# ----------------------------------------------------------------------------- host MPC
def _plan_rows(
    model, cost, iterations, stacked, params, dx, t, fresh, U_user, X, U, K, shift, s, U_alt
):
    """One iLQR plan per row (vmapped): warm-started from the row's previous plan (X, U, K)
    advanced by ``shift``, or from ``U_user`` where ``fresh``. Returns the plans."""
    r = Replanner(model, cost, U_user.shape[0], 1, iterations, U_user, U_alt, 0.0, s)

    def one(dx, t, fresh, X, U, K, shift, p):
        previous = ILQRSolution(X, U, K, *([None] * 5))
        return replan(r, p, dx, t, previous, fresh, shift)

    p_axis = 0 if stacked else None
    axes = (0, 0, 0, 0, 0, 0, 0, p_axis)
    return jax.vmap(one, in_axes=axes)(dx, t, fresh, X, U, K, shift, params)


_plan_rows_jit = jax.jit(_plan_rows, static_argnums=(0, 1, 2, 3))


class MPCController:
    """MPC for Gymnasium envs: ``act(obs [k, n_raw], t [k], index [k]) -> actions [k, m]``, the
    policy interface of :meth:`loopid.systems.GymSystem.rollouts`.

    Coordinates are :class:`~loopid.systems.GymSystem`'s: ``Δx = [o[observe] − o*; 1]``,
    ``a = a_op + Δu``; ``model_dynamics(params, Δx, Δu, t)`` and ``cost(Δx, Δu, t)`` work in
    them, with t the steps since the env's reset. At each call the rows due a plan (a new
    episode, or ``every`` steps since their last plan) are planned together by one jitted,
    vmapped iLQR (rows padded to a power of two, so a handful of batch sizes compile); the others
    apply their plan's feedback ``Δu = U_τ − K_τ(Δx − X_τ) − α k_τ``.

    Warm starts follow each episode: a row continues the previous call's row with the same
    ``index``, ``t − 1`` and the nearest predicted state ``X_{τ+1}`` (so the envs may come in any
    order, and some may stop or restart); t = 0, or no such row, starts from ``U0``.

    Args:
        model_dynamics, cost: as in :func:`mpc_rollout` (static: keep the same objects).
        params: the model's parameters; with ``stacked=True`` every leaf has a leading axis C and
            row r plans with ``params[index[r] % C]`` (one model per seed).
        U0: initial actions of a new episode's plan, ``[m]`` or ``[horizon, m]`` (Δu).
        horizon, every, iterations, alternatives, alpha, ilqr settings: as in
            :func:`mpc_rollout`.
        target: ``o* [n_obs]``; ``observe``: observation indices (default all); ``a_op``: ``[m]``
            (default 0).
    """

    def __init__(
        self,
        model_dynamics,
        cost,
        params,
        U0,
        *,
        horizon: int,
        target,
        observe=None,
        a_op=None,
        every: int = 1,
        iterations: int = 10,
        alternatives=None,
        alpha: float = 0.0,
        stacked: bool = False,
        tol: float = 1e-9,
        atol: float = 0.0,
        alphas=DEFAULT_ALPHAS,
        mu_init: float = 0.0,
        mu_min: float = 1e-6,
        mu_max: float = 1e10,
        mu_factor: float = 10.0,
    ):
        r = replanner(
            model_dynamics, cost, U0, horizon=horizon, every=every, iterations=iterations,
            alternatives=alternatives, alpha=alpha, tol=tol, atol=atol, alphas=alphas,
            mu_init=mu_init, mu_min=mu_min, mu_max=mu_max, mu_factor=mu_factor,
        )  # fmt: skip
        self.horizon, self.every, self.iterations, self.U0 = r.horizon, r.every, r.iterations, r.U0
        self.m, self.alpha = r.U0.shape[1], r.alpha
        self.alternatives, self.settings = r.alternatives, r.settings
        self.target = np.asarray(target, np.float64).reshape(-1)
        self.observe = None if observe is None else np.asarray(observe, np.int64)
        self.a_op = np.zeros(self.m) if a_op is None else np.asarray(a_op, np.float64)
        if self.a_op.shape != (self.m,):
            raise ValueError(f"a_op must have shape [{self.m}], got {self.a_op.shape}")
        self.n = self.target.shape[0] + 1
        self.model, self.cost, self.stacked = model_dynamics, cost, bool(stacked)
        self.set_params(params)
        self.reset()

    def set_params(self, params) -> None:
        """Plan with new model parameters from now on (same shapes: no recompilation)."""
        probe = jax.tree.map(lambda p: p[0], params) if self.stacked else params
        x = jnp.zeros(self.n)
        _check_problem(self.model, self.cost, probe, x, self.U0)
        self.params = params
        self.C = jax.tree.leaves(params)[0].shape[0] if self.stacked else 1

    def reset(self) -> None:
        """Forget every episode's plan."""
        self._rows = None  # (index, t, predicted Δx, plan arrays, t_plan) of the last call

    def error(self, obs) -> np.ndarray:
        """``Δx = [o[observe] − o*; 1]``: ``obs [k, n_raw]`` -> ``[k, n]``."""
        obs = np.asarray(obs, np.float64)
        if self.observe is not None:
            obs = obs[:, self.observe]
        return np.concatenate([obs - self.target, np.ones((obs.shape[0], 1))], axis=1)

    def _match(self, dx, t, index) -> np.ndarray:
        """For each row, the previous call's row it continues (−1: a new episode)."""
        prev = np.full(len(t), -1)
        if self._rows is None:
            return prev
        p_index, p_t, p_pred = self._rows[:3]
        taken = np.zeros(len(p_t), bool)
        for r in range(len(t)):
            ok = (p_index == index[r]) & (p_t == t[r] - 1) & ~taken
            if t[r] > 0 and ok.any():
                d = np.where(ok, np.sum((p_pred - dx[r]) ** 2, axis=1), np.inf)
                prev[r] = int(np.argmin(d))
                taken[prev[r]] = True
        return prev

    def act(self, obs, t, index) -> np.ndarray:
        dx = self.error(obs)
        t = np.asarray(t, np.int64).reshape(-1)
        index = np.asarray(index, np.int64).reshape(-1)
        k, H, m, n = dx.shape[0], self.horizon, self.m, self.n
        prev = self._match(dx, t, index)
        X = np.zeros((k, H + 1, n))
        U = np.zeros((k, H, m))
        K = np.zeros((k, H, m, n))
        kk = np.zeros((k, H, m))
        t_plan = t.copy()
        if self._rows is not None:
            old = prev >= 0
            X[old], U[old], K[old], kk[old] = (a[prev[old]] for a in self._rows[3])
            t_plan[old] = self._rows[4][prev[old]]
        fresh = prev < 0
        due = fresh | (t - t_plan >= self.every)
        if due.any():
            rows = np.flatnonzero(due)
            B = 1 << int(np.ceil(np.log2(len(rows))))
            pad = np.concatenate([rows, np.full(B - len(rows), rows[0])])
            shift = np.minimum(t[pad] - t_plan[pad], H)
            params = self.params
            if self.stacked:
                params = jax.tree.map(lambda p: p[index[pad] % self.C], params)
            sol = _plan_rows_jit(
                self.model,
                self.cost,
                self.iterations,
                self.stacked,
                params,
                jnp.asarray(dx[pad]),
                jnp.asarray(t[pad]),
                jnp.asarray(fresh[pad]),
                self.U0,
                jnp.asarray(X[pad]),
                jnp.asarray(U[pad]),
                jnp.asarray(K[pad]),
                jnp.asarray(shift),
                self.settings,
                self.alternatives,
            )
            n_rows = len(rows)
            X[rows], U[rows] = np.asarray(sol.X)[:n_rows], np.asarray(sol.U)[:n_rows]
            K[rows], kk[rows] = np.asarray(sol.K)[:n_rows], np.asarray(sol.k)[:n_rows]
            t_plan[rows] = t[rows]
        tau = t - t_plan
        r = np.arange(k)
        dev = dx - X[r, tau]
        du = U[r, tau] - np.einsum("kmn,kn->km", K[r, tau], dev) - self.alpha * kk[r, tau]
        self._rows = (index, t, X[r, tau + 1], (X, U, K, kk), t_plan)
        return self.a_op + du
