"""The real systems: the 21-state helicopter (pure JAX), its tasks and Gymnasium envs, a
linear-Gaussian test system, finite MDPs, and any Gymnasium environment (:class:`GymSystem`)."""

from loopid.systems import helicopter
from loopid.systems.base import Dynamics, Task, trajectory_cost
from loopid.systems.from_gymnasium import GymSystem
from loopid.systems.gym_cost import ObservationCost, observation_cost
from loopid.systems.helicopter import (
    from_error,
    funnel_target,
    hover_target,
    hover_trim,
    linearize,
    noise_sequence,
    rollout,
    step,
    step_delayed,
    target_increment,
    to_error,
)
from loopid.systems.helicopter.gymnasium_env import HelicopterEnv
from loopid.systems.helicopter.tasks import (
    FUNNEL_WEIGHTS,
    HOVER_WEIGHTS,
    TASK_NAMES,
    cost_matrices,
    make_task,
)
from loopid.systems.linear import linear_dynamics, linear_task
from loopid.systems.mdp import FiniteMDP, check_mdp, gridworld, make_mdp, random_mdp, trap_mdp

__all__ = [
    "FUNNEL_WEIGHTS",
    "HOVER_WEIGHTS",
    "TASK_NAMES",
    "Dynamics",
    "FiniteMDP",
    "GymSystem",
    "HelicopterEnv",
    "ObservationCost",
    "Task",
    "check_mdp",
    "cost_matrices",
    "from_error",
    "funnel_target",
    "gridworld",
    "helicopter",
    "hover_target",
    "hover_trim",
    "linear_dynamics",
    "linear_task",
    "linearize",
    "make_mdp",
    "make_task",
    "noise_sequence",
    "observation_cost",
    "random_mdp",
    "rollout",
    "step",
    "step_delayed",
    "target_increment",
    "to_error",
    "trajectory_cost",
    "trap_mdp",
]
