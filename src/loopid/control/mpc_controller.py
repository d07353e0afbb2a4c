"""Model-predictive control for Gymnasium envs (:class:`MPCController`): the re-planning step of
:mod:`loopid.control.mpc` (:func:`~loopid.control.mpc.replan`) run from Python on a vector env's
rows, the policy interface of :meth:`loopid.systems.GymSystem.rollouts`.

At each call the rows due a plan (a new episode, or ``every`` steps since their last plan) are
planned together by one jitted, vmapped iLQR (``[B, ...]`` with the rows padded to a power of two
B, so a handful of batch sizes compile); the others apply their plan's local feedback
``Δu = U_τ − K_τ(Δx − X_τ) − α k_τ`` in NumPy. Coordinates, warm starts and arguments:
:class:`MPCController`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from loopid.control.ilqr import DEFAULT_ALPHAS, ILQRSolution
from loopid.control.mpc import Replanner, replan, replanner
from loopid.control.plan_settings import check_problem

__all__ = ["MPCController"]


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
        check_problem(self.model, self.cost, probe, x, self.U0)
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
