"""A gym scenario's env: the one place the experiment builds (and closes) a Gymnasium env.

The scenario's ``[env]`` table and its cost's ``target`` and ``action_op`` fix the coordinates
(:mod:`loopid.systems.from_gymnasium`): ``Δx = [o[observe] − o*; 1]`` (``n = n_obs + 1``) and
``Δu = a − a_op`` (``m`` actions). :func:`make_system` builds the vector env the loop steps
(:class:`~loopid.systems.from_gymnasium.GymSystem`, close it), :func:`opened_system` the same
inside a ``with`` block that closes it, :func:`rendering_env` one plain env drawing
``rgb_array`` frames. :func:`env_shape` is what the compiled agent needs to know of the env
(:class:`~loopid.algorithms.host_agent.EnvShape`).
"""

from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

import gymnasium
import numpy as np

from loopid.algorithms.host_agent import EnvShape
from loopid.experiments.families.gym.scenario import GymScenario
from loopid.systems.from_gymnasium import GymSystem


class EnvSpec(NamedTuple):
    """The scenario's env fields as plain values (``gymnasium.make`` keywords, the reset
    options, the observed entries, the target ``o*`` and operating action ``a_op``, the
    horizon in steps, the vector env's size and kind, the training restart norm)."""

    env_id: str
    env_kwargs: dict
    reset_options: dict
    observe: list | None
    target: list
    action_op: list | None
    horizon: int | None
    num_envs: int
    vectorization: str
    stop_norm: float | None


def env_spec(s: GymScenario) -> EnvSpec:
    """The :class:`EnvSpec` of ``s``."""
    v = s.plain
    return EnvSpec(
        v["env_id"], v["env_kwargs"], v["reset_options"], v["observe"], v["target"],
        v["action_op"], v["horizon"], v["num_envs"], v["vectorization"], v["stop_norm"],
    )  # fmt: skip


def make_system(s: GymScenario) -> GymSystem:
    """The scenario's env as a :class:`~loopid.systems.from_gymnasium.GymSystem` (close it)."""
    e = env_spec(s)
    return GymSystem(
        e.env_id, target=e.target, env_kwargs=e.env_kwargs, observe=e.observe, a_op=e.action_op,
        horizon=e.horizon, num_envs=e.num_envs, reset_options=e.reset_options,
        vectorization=e.vectorization, stop_norm=e.stop_norm,
    )  # fmt: skip


@contextmanager
def opened_system(s: GymScenario) -> Iterator[GymSystem]:
    """:func:`make_system`, closed when the ``with`` block ends (however it ends)."""
    system = make_system(s)
    try:
        yield system
    finally:
        system.close()


def rendering_env(s: GymScenario) -> gymnasium.Env:
    """One env of the scenario drawing ``rgb_array`` frames (``render()``); close it."""
    e = env_spec(s)
    return gymnasium.make(e.env_id, render_mode="rgb_array", **e.env_kwargs)


def env_shape(system: GymSystem) -> EnvShape:
    """The :class:`~loopid.algorithms.host_agent.EnvShape` of a built env."""
    room = np.minimum(system.high - system.a_op, system.a_op - system.low)
    u_limit = float(room.min()) if np.all(np.isfinite(room)) and room.min() > 0 else None
    observe = None if system.observe is None else tuple(int(i) for i in system.observe)
    return EnvShape(system.n, system.n_obs, system.m, system.horizon,
                    tuple(np.asarray(system.target).tolist()),
                    tuple(np.asarray(system.a_op).tolist()), observe, u_limit)  # fmt: skip
