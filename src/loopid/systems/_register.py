"""Gymnasium registration of the helicopter tasks and the hanging pendulum (called once by
``import loopid``)."""

import gymnasium

ENV_IDS = {
    "loopid/HelicopterHover-v0": "hover",
    "loopid/HelicopterHoverDelay-v0": "hover-delay",
    "loopid/HelicopterFunnel-v0": "funnel",
}

PENDULUM_ID = "loopid/PendulumHanging-v0"
"""Pendulum-v1 started hanging down (:class:`loopid.systems.pendulum.PendulumHangingEnv`)."""


def register_envs() -> None:
    """Register every id above; a second call is a no-op."""
    for env_id, task in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="loopid.systems.as_gymnasium:HelicopterEnv",
                kwargs={"task": task},
            )
    if PENDULUM_ID not in gymnasium.registry:
        gymnasium.register(
            id=PENDULUM_ID,
            entry_point="loopid.systems.pendulum:PendulumHangingEnv",
            max_episode_steps=200,
        )
