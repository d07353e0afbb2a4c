"""The loop and its agents: Algorithm 1 for every seed at once, the plant it runs on, the agents
it trains and the baselines it is compared with.

Public means listed here and documented: every submodule below is part of the API.
"""

__all__ = [
    "agents",
    "closed_loop",
    "collect",
    "contracts",
    "exploration",
    "gym_loop",
    "host_agent",
    "keys",
    "loop",
    "loop_program",
    "model_based",
    "mpc_plant",
    "planning_agent",
    "plant",
    "policy_gradient",
    "policy_gradient_rollouts",
    "policy_gradient_step",
    "schedules",
    "transitions",
]
