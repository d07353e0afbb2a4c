"""The real systems: the 21-state helicopter (pure JAX), its tasks, and its Gymnasium envs."""

from loopid.systems import helicopter, tasks
from loopid.systems.envs import HelicopterEnv
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
from loopid.systems.tasks import (
    FUNNEL_WEIGHTS,
    HOVER_WEIGHTS,
    TASK_NAMES,
    Task,
    cost_matrices,
    make_task,
    trajectory_cost,
)

__all__ = [
    "FUNNEL_WEIGHTS",
    "HOVER_WEIGHTS",
    "TASK_NAMES",
    "HelicopterEnv",
    "Task",
    "cost_matrices",
    "from_error",
    "funnel_target",
    "helicopter",
    "hover_target",
    "hover_trim",
    "linearize",
    "make_task",
    "noise_sequence",
    "rollout",
    "step",
    "step_delayed",
    "target_increment",
    "tasks",
    "to_error",
    "trajectory_cost",
]
