"""The buffers a :class:`~loopid.systems.from_gymnasium.GymSystem` fills (:class:`Slot`) and what
it records in them (:class:`Rollouts`).

A *slot* is one fixed-shape buffer of ``horizon`` steps: its episode stops at ``terminated``,
``truncated``, after ``horizon`` actions, at a non-finite action, or (training slots,
``restart=True``) when ``‖[Δx_{:−1}; Δu]‖₂ > stop_norm``; a training slot then resets and goes
on filling its buffer (as the JAX plant restarts from μ); a test slot masks the rest.

Seeding (:func:`slot_streams`): slot ``j`` owns a NumPy generator ``default_rng(seed_j)``; it
draws the action noise ``ε [horizon, m]`` first, then one reset seed per episode
(``integers(2**32)``). Every reset of a used sub-environment is seeded, so a slot's data depends
on its seed alone, not on which sub-environment ran it or on ``num_envs``. (Sub-environments
left idle once the queue is empty are reset with seed 0 and their steps discarded.)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Rollouts", "Slot", "slot_streams"]


class Slot(NamedTuple):
    """One buffer to fill: ``policy`` (index into the policies list), ``index`` (its sub-policy,
    e.g. the seed's gain), ``seed`` (the slot's generator seed), ``action_std`` and ``restart``."""

    policy: int
    index: int
    seed: int
    action_std: float = 0.0
    restart: bool = True


class Rollouts(NamedTuple):
    """Recorded slots, numpy, leading axes ``[R, T]``.

    ``x`` [R, T, n_raw] raw observations, ``dx``/``dx_next`` [R, T, n], ``du`` [R, T, m] applied
    action minus ``a_op``, ``reward`` [R, T] the env's rewards, ``t`` [R, T] int32 steps since
    reset, ``mask`` [R, T] (the step was
    taken, finite and inside ``stop_norm``); ``steps`` [R] actions taken, ``terminated`` [R]
    (an episode ended by ``terminated``), ``finite`` [R] (no non-finite action or observation).
    """

    x: np.ndarray
    dx: np.ndarray
    du: np.ndarray
    dx_next: np.ndarray
    t: np.ndarray
    mask: np.ndarray
    reward: np.ndarray
    steps: np.ndarray
    terminated: np.ndarray
    finite: np.ndarray


def slot_streams(slot: Slot, horizon: int, m: int) -> tuple[np.ndarray, np.random.Generator]:
    """A slot's action noise ``ε [horizon, m]`` and the generator that then draws its episodes'
    reset seeds (``integers(2**32)`` per reset), from ``default_rng(slot.seed)``."""
    rng = np.random.default_rng(slot.seed)
    return rng.standard_normal((horizon, m)) * slot.action_std, rng
