"""The policies a :class:`~loopid.systems.from_gymnasium.GymSystem` flies: objects with
``act(obs [k, n_raw], t [k], index [k]) -> actions [k, m]``, called on the rows of the vector
env that run a slot (``t``: steps since each row's reset; ``index``: each row's sub-policy,
e.g. its seed's gain).

- :class:`LinearPolicy`: the loop's affine gains ``K: [horizon, m, n]`` with
  ``a_t = a_op − K_τ Δx_t`` (τ = steps since the episode's reset, ``Δx = [o[observe] − o*; 1]``),
  as in :mod:`loopid.algorithms.plant`;
- :class:`CallablePolicy`: a user's function of one observation (or of a batch);
- :class:`OpenLoopPolicy`: a nominal action sequence.

The system clips every action to the action Box and casts it to its dtype before the step.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["CallablePolicy", "LinearPolicy", "OpenLoopPolicy"]


class LinearPolicy:
    """Affine gains ``K [C, T, m, n]`` (C stacked policies): ``a = a_op − K[c, τ] [o − o*; 1]``.

    ``K`` may also be ``[T, m, n]`` or ``[m, n]`` (one policy; time-invariant) or ``[m, n_obs]``
    (no feedforward column). ``act(obs [k, n_obs], t [k], index [k])`` picks policy ``index``.
    """

    def __init__(self, K, target, a_op, observe=None):
        K = np.asarray(K, dtype=np.float64)
        self.observe = observe
        self.target = np.asarray(target, dtype=np.float64)
        self.a_op = np.asarray(a_op, dtype=np.float64)
        n_obs, m = self.target.shape[0], self.a_op.shape[0]
        if K.ndim >= 2 and K.shape[-2:] == (m, n_obs):
            K = np.concatenate([K, np.zeros((*K.shape[:-1], 1))], axis=-1)
        if K.ndim < 2 or K.ndim > 4 or K.shape[-2:] != (m, n_obs + 1):
            raise ValueError(
                f"K must be [(C,) (T,) {m}, {n_obs + 1}] or [{m}, {n_obs}], got {K.shape}"
            )
        while K.ndim < 4:
            K = K[None]
        self.K = K

    def act(self, obs, t, index):
        if self.observe is not None:
            obs = obs[:, self.observe]
        dx = np.concatenate([obs - self.target, np.ones((obs.shape[0], 1))], axis=1)
        Kr = self.K[index % self.K.shape[0], np.minimum(t, self.K.shape[1] - 1)]
        return self.a_op - np.einsum("kmn,kn->km", Kr, dx)


class CallablePolicy:
    """A user's policy ``fn(obs [n_obs]) -> action [m]`` applied row by row (``batched=True``:
    ``fn(obs [k, n_obs]) -> [k, m]`` in one call)."""

    def __init__(self, fn: Callable, m: int, *, batched: bool = False):
        if not callable(fn):
            raise TypeError(f"policy must be callable, got {fn!r}")
        self.fn, self.m, self.batched = fn, m, batched

    def act(self, obs, t, index):
        if self.batched:
            a = np.asarray(self.fn(obs), dtype=np.float64)
        else:
            a = np.stack([np.asarray(self.fn(o), dtype=np.float64).reshape(-1) for o in obs])
        if a.shape != (obs.shape[0], self.m):
            raise ValueError(
                f"policy returned actions of shape {a.shape}, expected {(obs.shape[0], self.m)}"
            )
        return a


class OpenLoopPolicy:
    """A nominal action sequence ``U [T, m]``: ``a_τ = U[τ]`` (the last row after the end)."""

    def __init__(self, U):
        self.U = np.atleast_2d(np.asarray(U, dtype=np.float64))

    def act(self, obs, t, index):
        return self.U[np.minimum(t, self.U.shape[0] - 1)]
