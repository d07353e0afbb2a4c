"""Helicopter tasks: targets, start states, noise, delay and quadratic costs.

A task fixes a target trajectory x*_0..x*_{T−1} [T, 21], the start state x_0 [21], the process
noise std (the noise is std·N(0, I_6) per step, see ``helicopter.noise_sequence``), the actuation
delay d (steps) and the cost

    J = Σ_{t=0}^{T−1} Δx_tᵀ Q Δx_t + Σ_{t=0}^{T−2} Δu_tᵀ R Δu_t,   Δx_t = to_error(x_t, x*_t),

over T states and T − 1 commanded actions (hover: T = 401, 400 actions; funnel: T = 600).
Q = dt·diag(w) with the weights w expanded over the 21 error coordinates, R = dt·1e-6·I
*(choice: the course weights; the paper's own are not published)*.
"""

import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np

from loopid.systems import helicopter
from loopid.systems.base import Task

#: The helicopter tasks, one per panel of the paper's Figure 2.
TASK_NAMES = ("hover", "hover-delay", "funnel")
#: The tasks that hold one hover target (time-invariant); every other task follows a trajectory.
HOVER_TASKS = ("hover", "hover-delay")
#: Hover cost weights over [u_prev ×4, du_prev ×4, ned_dot ×3, ned ×3, pqr ×3, q ×3, const ×1].
HOVER_WEIGHTS = (0.0, 1000.0, 1.0, 1.0, 1.0, 1.0, 0.0)
#: Funnel cost weights, over the same blocks.
FUNNEL_WEIGHTS = (0.0, 1000.0, 0.01, 10.0, 1.0, 10.0, 0.0)
WEIGHT_BLOCKS = (4, 4, 3, 3, 3, 3, 1)
ACTION_WEIGHT = 1e-6
HOVER_STEPS = 400

_DEFAULTS = {  # name: (noise_std, delay)
    "hover": (1.0, 0),
    "hover-delay": (1.0, 1),
    "funnel": (0.1, 0),
}
#: Each task's own delay d (steps), which a scenario's ``delay`` overrides.
TASK_DELAYS = {name: delay for name, (_, delay) in _DEFAULTS.items()}


def cost_matrices(weights) -> tuple[jax.Array, jax.Array]:
    """(Q [21, 21], R [4, 4]) = (dt·diag(w expanded over the error coordinates), dt·1e-6·I).

    ``weights`` has 7 entries, over [u_prev, du_prev, ned_dot, ned, pqr, q, const].
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (len(WEIGHT_BLOCKS),) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(
            f"weights must be 7 finite non-negative numbers over [u_prev, du_prev, ned_dot, ned, "
            f"pqr, q, const], got {weights!r}"
        )
    diag = np.repeat(w, WEIGHT_BLOCKS)  # in NumPy: the same products, no compiled programs
    Q = helicopter.DT * np.diag(diag)
    R = helicopter.DT * ACTION_WEIGHT * np.eye(helicopter.N_ACTION)
    return jnp.asarray(Q), jnp.asarray(R)


def _check_noise_std(noise_std) -> float:
    if isinstance(noise_std, bool) or not isinstance(noise_std, numbers.Real):
        raise ValueError(f"noise_std must be a finite number >= 0, got {noise_std!r}")
    if not math.isfinite(noise_std) or noise_std < 0:
        raise ValueError(f"noise_std must be a finite number >= 0, got {noise_std!r}")
    return float(noise_std)


def _check_delay(delay) -> int:
    if isinstance(delay, bool) or not isinstance(delay, numbers.Integral) or delay < 0:
        raise ValueError(f"delay must be an integer >= 0 (steps), got {delay!r}")
    return int(delay)


def make_task(name: str, *, noise_std=None, delay=None, pads: bool = True) -> Task:
    """Build a task: ``"hover"`` (d = 0, std 1), ``"hover-delay"`` (d = 1, std 1), ``"funnel"``.

    ``noise_std`` and ``delay`` override the task's defaults. The funnel (d = 0, std 0.1) starts
    at rest at its first target state; ``pads=False`` gives the 400-step variant started on the
    circle (ignored for hover). Raises ValueError naming a bad value and the allowed ones.
    """
    if name not in _DEFAULTS:
        raise ValueError(f"unknown task name {name!r}; allowed: {', '.join(TASK_NAMES)}")
    default_std, default_delay = _DEFAULTS[name]
    std = _check_noise_std(default_std if noise_std is None else noise_std)
    d = _check_delay(default_delay if delay is None else delay)
    if name == "funnel":
        target = helicopter.funnel_target(pads=pads)
        Q, R = cost_matrices(FUNNEL_WEIGHTS)
    else:
        target = jnp.asarray(np.tile(np.asarray(helicopter.hover_target()), (HOVER_STEPS + 1, 1)))
        Q, R = cost_matrices(HOVER_WEIGHTS)
    return Task(
        name=name,
        target=target,
        noise_std=std,
        delay=d,
        Q=Q,
        R=R,
        x0=target[0],
        time_varying=not is_hover(name),
    )


def is_hover(task: "str | Task") -> bool:
    """Whether ``task`` (a task or its name) is a hover: the one place that decides it."""
    return (task if isinstance(task, str) else task.name) in HOVER_TASKS
