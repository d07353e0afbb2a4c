"""Gymnasium registration of loopid's environments: the helicopter tasks
(:mod:`loopid.systems.helicopter.gymnasium_env`) and the hanging pendulum (called once by
``import loopid``)."""

import gymnasium

from loopid.systems.helicopter.gymnasium_env import register_helicopter_envs

PENDULUM_ID = "loopid/PendulumHanging-v0"
"""Pendulum-v1 started hanging down (:class:`loopid.systems.pendulum.PendulumHangingEnv`)."""


def register_envs() -> None:
    """Register every loopid id; a second call is a no-op."""
    register_helicopter_envs()
    if PENDULUM_ID not in gymnasium.registry:
        gymnasium.register(
            id=PENDULUM_ID,
            entry_point="loopid.systems.pendulum:PendulumHangingEnv",
            max_episode_steps=200,
        )
