"""Gymnasium registration of the helicopter tasks (called once by ``import loopid``)."""

import gymnasium

ENV_IDS = {
    "loopid/HelicopterHover-v0": "hover",
    "loopid/HelicopterHoverDelay-v0": "hover-delay",
    "loopid/HelicopterFunnel-v0": "funnel",
}


def register_envs() -> None:
    """Register every helicopter task id; a second call is a no-op."""
    for env_id, task in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="loopid.systems.as_gymnasium:HelicopterEnv",
                kwargs={"task": task},
            )
