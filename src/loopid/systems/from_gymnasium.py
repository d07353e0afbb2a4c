"""Any Gymnasium environment with Box observations and actions as the real system of the loop.

A Gymnasium env has a *reset model* only (no generative model: the state cannot be set), so all
data comes from rollouts, collected many at once through a Gymnasium vector environment
(``SyncVectorEnv`` by default, ``AsyncVectorEnv`` on request) with autoreset *disabled*: the
adapter resets each sub-environment itself, with an explicit seed, when its episode ends.

Coordinates (what models and controllers see), for a target observation ``o*`` [n_obs] and an
operating action ``a_op`` [m]::

    Δx = [o[observe] − o*; 1]  [n = n_obs + 1]   (the constant 1 makes models and LQR affine)
    Δu = a − a_op              [m]

``observe`` (default: every entry) selects the observation entries the model sees, so n_obs may be
smaller than the env's observation size (Pendulum: sin θ and θ̇, leaving out cos θ, which a linear
model cannot follow: cos θ − 1 ≈ −θ²/2 looks like an unstable mode no linear control reaches).

Policies (:mod:`loopid.systems.gym_policies`) are objects with ``act(obs, t, index)``, e.g. the
loop's affine gains ``K: [horizon, m, n]`` with ``a_t = a_op − K_τ Δx_t`` (τ = steps since the
episode's reset). Every action is clipped to the action Box and cast to its dtype before the
step; the transition records the action actually applied. The cost on observations is
:mod:`loopid.systems.gym_cost`.

Data fill *slots* (:mod:`loopid.systems.gym_slots`): fixed-shape buffers of ``horizon`` steps,
each an episode that stops at ``terminated``, ``truncated``, after ``horizon`` actions, at a
non-finite action, or (training slots, ``restart=True``) when
``‖[Δx_{:−1}; Δu]‖₂ > stop_norm``; a training slot then resets and goes on filling its buffer
(as the JAX plant restarts from μ); a test slot masks the rest. Each slot seeds its own action
noise and resets, so its data depends on its seed alone (not on ``num_envs``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode

from loopid.systems.gym_cost import finite_vector
from loopid.systems.gym_policies import LinearPolicy
from loopid.systems.gym_slots import Rollouts, Slot, slot_streams

__all__ = ["GymSystem", "make_env_fn"]


def make_env_fn(env, kwargs: dict | None = None) -> Callable[[], gymnasium.Env]:
    """A factory for one sub-environment: from an id (``gymnasium.make(id, **kwargs)``), a
    factory, or an instance (deep-copied for every sub-environment)."""
    kwargs = dict(kwargs or {})
    if isinstance(env, str):
        return lambda: gymnasium.make(env, **kwargs)
    if isinstance(env, gymnasium.Env):
        return lambda: copy.deepcopy(env)
    if callable(env):
        return env
    raise TypeError(f"env must be an id, a gymnasium.Env or a factory, got {env!r}")


def _check_box(name: str, space) -> int:
    if not isinstance(space, gymnasium.spaces.Box):
        kind = type(space).__name__
        raise ValueError(
            f"{name} space must be a continuous Box, got {kind} ({space}); "
            "loopid needs Box observations and actions"
        )
    if len(space.shape) != 1:
        raise ValueError(f"{name} space must be a 1-D Box, got shape {space.shape}")
    return int(space.shape[0])


class GymSystem:
    """A Gymnasium env as the real system (see the module docstring).

    Args:
      env: an env id (``"Pendulum-v1"``), a factory ``() -> Env`` or an Env instance.
      target: the target observation ``o*`` [n_obs] (of the ``observe`` entries).
      observe: indices of the observation entries the model sees (default: all).
      a_op: the operating action [m] (default zeros).
      horizon: steps per episode (default: the env's ``max_episode_steps``).
      num_envs: sub-environments run at once.
      env_kwargs: keyword arguments for ``gymnasium.make``.
      reset_options: ``options`` passed to every reset (e.g. Pendulum's ``x_init``/``y_init``).
      vectorization: ``"sync"`` or ``"async"``.
      stop_norm: training slots end an episode when ``‖[Δx_{:−1}; Δu]‖₂ > stop_norm``.

    Raises ValueError for an unknown id, a non-Box space, or a size that does not match.
    """

    def __init__(
        self,
        env,
        *,
        target,
        observe=None,
        a_op=None,
        horizon: int | None = None,
        num_envs: int = 8,
        env_kwargs: dict | None = None,
        reset_options: dict | None = None,
        vectorization: str = "sync",
        stop_norm: float | None = None,
    ):
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if vectorization not in ("sync", "async"):
            raise ValueError(f"vectorization must be 'sync' or 'async', got {vectorization!r}")
        if stop_norm is not None and not stop_norm > 0:
            raise ValueError(f"stop_norm must be > 0, got {stop_norm!r}")
        self.env_fn = make_env_fn(env, env_kwargs)
        try:
            probe = self.env_fn()
        except gymnasium.error.Error as err:
            raise ValueError(f"cannot make env {env!r}: {str(err).splitlines()[0]}") from None
        try:
            self.n_raw = _check_box("observation", probe.observation_space)
            self.m = _check_box("action", probe.action_space)
            spec_steps = probe.spec.max_episode_steps if probe.spec is not None else None
            self.env_id = (
                probe.spec.id if probe.spec is not None else type(probe.unwrapped).__name__
            )
            self.low = np.asarray(probe.action_space.low, np.float64)
            self.high = np.asarray(probe.action_space.high, np.float64)
            self.action_dtype = probe.action_space.dtype
        finally:
            probe.close()
        if observe is None:
            self.observe = None
            self.n_obs = self.n_raw
        else:
            idx = np.asarray(observe)
            ok = idx.ndim == 1 and idx.size > 0 and np.issubdtype(idx.dtype, np.integer)
            if (
                not ok
                or idx.min() < 0
                or idx.max() >= self.n_raw
                or len(set(idx.tolist())) < idx.size
            ):
                raise ValueError(
                    f"observe must list distinct observation indices in [0, {self.n_raw}), "
                    f"got {np.asarray(observe).tolist()!r}"
                )
            self.observe = idx.astype(np.int64)
            self.n_obs = int(idx.size)
        self.n = self.n_obs + 1
        try:
            self.target = finite_vector("target", target, self.n_obs)
        except ValueError:
            raise ValueError(
                f"target must be {self.n_obs} finite numbers (the observed entries of "
                f"{self.env_id}), got {np.asarray(target).tolist()!r}"
            ) from None
        self.a_op = np.zeros(self.m) if a_op is None else finite_vector("a_op", a_op, self.m)
        if horizon is None:
            if spec_steps is None:
                raise ValueError(f"{self.env_id} has no max_episode_steps: give horizon")
            horizon = spec_steps
        if isinstance(horizon, bool) or not isinstance(horizon, int | np.integer) or horizon < 1:
            raise ValueError(f"horizon must be an integer >= 1, got {horizon!r}")
        self.horizon = int(horizon)
        self.num_envs = int(num_envs)
        self.reset_options = dict(reset_options or {})
        self.stop_norm = stop_norm
        vec = (
            gymnasium.vector.SyncVectorEnv
            if vectorization == "sync"
            else gymnasium.vector.AsyncVectorEnv
        )
        self.envs = vec(
            [self.env_fn] * self.num_envs, copy=False, autoreset_mode=AutoresetMode.DISABLED
        )

    def close(self) -> None:
        self.envs.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def observed(self, obs) -> np.ndarray:
        """The entries the model sees: obs [..., n_raw] -> [..., n_obs]."""
        obs = np.asarray(obs, np.float64)
        return obs if self.observe is None else obs[..., self.observe]

    def error(self, obs) -> np.ndarray:
        """``Δx = [o[observe] − o*; 1]``: obs [..., n_raw] -> [..., n]."""
        obs = self.observed(obs)
        return np.concatenate([obs - self.target, np.ones((*obs.shape[:-1], 1))], axis=-1)

    def linear_policy(self, K) -> LinearPolicy:
        """:class:`LinearPolicy` in this system's coordinates."""
        return LinearPolicy(K, self.target, self.a_op, self.observe)

    # ------------------------------------------------------------------------- collection
    def _reset(self, mask: np.ndarray, seeds: list) -> np.ndarray:
        options = {**self.reset_options, "reset_mask": mask}
        obs, _ = self.envs.reset(seed=seeds, options=options)
        return np.array(obs, np.float64)  # a copy: the vector env reuses its buffer

    def rollouts(self, policies: Sequence[Any], slots: Sequence[Slot]) -> Rollouts:
        """Fill every slot (module docstring) through the vector env; returns :class:`Rollouts`.

        ``policies``: objects with ``act(obs [k, n_raw], t [k], index [k]) -> [k, m]``.
        """
        R, T, E, m, n_raw = len(slots), self.horizon, self.num_envs, self.m, self.n_raw
        x = np.zeros((R, T, n_raw))
        x_next = np.zeros((R, T, n_raw))
        reward = np.zeros((R, T))
        du = np.zeros((R, T, m))
        t_buf = np.zeros((R, T), np.int32)
        mask = np.zeros((R, T), bool)
        steps = np.zeros(R, np.int64)
        terminated = np.zeros(R, bool)
        finite = np.ones(R, bool)
        streams = [slot_streams(s, T, m) for s in slots]
        rngs = [g for _, g in streams]
        eps = np.stack([e for e, _ in streams]) if R else np.zeros((0, T, m))
        pol_of = np.array([s.policy for s in slots], np.int64)
        idx_of = np.array([s.index for s in slots], np.int64)
        restart_of = np.array([s.restart for s in slots], bool)

        slot = np.full(E, -1)  # slot run by each sub-env (-1: idle)
        pos = np.zeros(E, np.int64)  # next buffer row of that slot
        tau = np.zeros(E, np.int64)  # steps since the sub-env's reset
        queue = 0

        def assign(envs_mask: np.ndarray, obs: np.ndarray | None) -> np.ndarray:
            """Reset the sub-envs in ``envs_mask``: a new episode of their slot, the next queued
            slot, or idle; returns the updated observations."""
            nonlocal queue
            seeds: list = [None] * E
            for i in np.flatnonzero(envs_mask):
                j = slot[i]
                if j < 0 or pos[i] >= T or not slots[j].restart:
                    j = queue if queue < R else -1
                    queue += j >= 0
                    slot[i], pos[i] = j, 0
                tau[i] = 0
                seeds[i] = int(rngs[j].integers(2**32)) if j >= 0 else 0
            fresh = self._reset(envs_mask, seeds)
            return fresh if obs is None else np.where(envs_mask[:, None], fresh, obs)

        obs = assign(np.ones(E, bool), None)
        act_dtype = self.action_dtype
        a = np.tile(self.a_op, (E, 1))
        single = len(policies) == 1
        while True:
            i = np.flatnonzero(slot >= 0)  # the sub-envs running a slot
            if i.size == 0:
                break
            j, p_, tau_i = slot[i], pos[i], tau[i]
            a[:] = self.a_op
            groups = [(0, slice(None))] if single else [(p, pol_of[j] == p) for p in set(pol_of[j])]
            for p, g in groups:
                a[i[g]] = policies[p].act(obs[i[g]], tau_i[g], idx_of[j[g]]) + eps[j[g], p_[g]]
            ok = np.isfinite(a).all(axis=1)
            a[~ok] = self.a_op
            applied = np.minimum(np.maximum(a, self.low), self.high).astype(act_dtype)
            nxt, rew, term, trunc, _ = self.envs.step(applied)
            nxt = np.array(nxt, np.float64)  # a copy: the vector env reuses its buffer
            ok &= np.isfinite(nxt).all(axis=1)

            ok_i = ok[i]
            d = applied[i].astype(np.float64) - self.a_op
            valid = ok_i.copy()
            if self.stop_norm is not None:  # training slots only
                e = self.observed(obs[i]) - self.target
                size = np.sqrt((e * e).sum(axis=1) + (d * d).sum(axis=1))
                valid &= (size <= self.stop_norm) | ~restart_of[j]
            x[j, p_], x_next[j, p_], du[j, p_] = obs[i], nxt[i], d
            t_buf[j, p_], mask[j, p_], reward[j, p_] = tau_i, valid, rew[i]
            steps[j] += ok_i
            terminated[j] |= term[i] & ok_i
            finite[j] &= ok_i

            pos[i] += 1
            tau[i] += 1
            ended = term | trunc | ~ok
            ended[i] |= ~valid | (tau[i] >= T) | (pos[i] >= T)
            # a slot without restart is done at its episode's end
            done = i[ended[i] & ~restart_of[j]]
            pos[done] = T
            obs = nxt
            if ended.any():
                obs = assign(ended, obs)
        dx = self.error(x)
        dx_next = self.error(x_next)
        zero = ~mask
        for a_ in (x, dx, du, dx_next, reward):
            a_[zero] = 0.0
        return Rollouts(x, dx, du, dx_next, t_buf, mask, reward, steps, terminated, finite)
