"""The policy-fraction schedules of Algorithm 1: how each learning method splits its batches.

Ross & Bagnell (2012), Algorithm 1: at iteration n = 2, 3, …, each of the m slots of the batch
comes from running the current policy π_{n−1} with probability ``p_n``, and from the
exploration distribution ν otherwise. The methods differ only in ``p_n``:

========  ================================================================
schedule  p_n for n = 2, 3, …
========  ================================================================
dagger    ``dagger_fraction`` (½ by default): the paper's DAgger
batch     0: all data from ν (system identification in one batch)
abbeel    0 at n = 2 (ν's data), then 1: only the current policy's data
========  ================================================================

Iteration 1 solves the initial model and collects nothing (``p_1 = 0``).
"""

import numpy as np

SCHEDULES = ("dagger", "batch", "abbeel")


def policy_fractions(schedule: str, iterations: int, *, dagger_fraction: float = 0.5) -> np.ndarray:
    """``[iterations]`` policy fractions ``p_n`` of ``schedule`` (:data:`SCHEDULES`; entry 0,
    iteration 1, collects nothing). One-line ``ValueError`` for an unknown schedule or a
    ``dagger_fraction`` outside [0, 1]."""
    if schedule not in SCHEDULES:
        raise ValueError(f"unknown schedule {schedule!r}; choose from {', '.join(SCHEDULES)}")
    if not 0.0 <= dagger_fraction <= 1.0:
        raise ValueError(f"dagger_fraction must lie in [0, 1], got {dagger_fraction!r}")
    p = np.zeros(iterations)
    if schedule == "dagger":
        p[1:] = dagger_fraction
    elif schedule == "abbeel":
        p[2:] = 1.0
    return p
