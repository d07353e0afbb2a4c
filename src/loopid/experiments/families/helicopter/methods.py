"""The methods of the paper's Figure 2 and how each draws its data.

Every learning method is Algorithm 1 with its own exploration distribution ν and its own
schedule of policy fractions ``p_n`` (the probability that a slot of iteration n's batch comes
from running the current policy rather than from ν):

============  =====  ==============================================================
method        ν      p_n for n = 2, 3, …
============  =====  ==============================================================
dagger-*      *      ½ (``dagger_fraction``)
batch-*       *      0: all data from ν
abbeel        e      0 at n = 2 (expert data), then 1: only the current policy's data
============  =====  ==============================================================

``expert`` (the linearised expert L) and ``pg`` (model-free policy gradient) do not learn a model;
they have their own runners with the same call shape.
"""

import numpy as np

from loopid.algorithms import schedules

METHODS = (
    "dagger-t",
    "dagger-e",
    "dagger-en",
    "batch-t",
    "batch-e",
    "batch-en",
    "abbeel",
    "expert",
    "pg",
)
LEARNING_METHODS = METHODS[:7]


def check_method(method: str) -> str:
    """Return ``method`` if it is known, else raise ``ValueError`` listing the known ones."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    return method


def nu_kind(method: str) -> str | None:
    """The exploration distribution a method draws from: ``"t"``, ``"e"``, ``"en"`` or None."""
    check_method(method)
    if method == "abbeel":
        return "e"
    if method.startswith(("dagger-", "batch-")):
        return method.split("-", 1)[1]
    return None


def policy_fractions(method: str, iterations: int, *, dagger_fraction: float = 0.5) -> np.ndarray:
    """``[iterations]`` policy fractions ``p_n`` (entry 0, iteration 1, collects nothing): the
    schedule the method follows (:func:`loopid.algorithms.schedules.policy_fractions`)."""
    check_method(method)
    if method not in LEARNING_METHODS:
        raise ValueError(f"{method!r} does not learn a model, it has no policy fractions")
    schedule = method.split("-", 1)[0]  # dagger-* -> dagger, batch-* -> batch, abbeel
    return schedules.policy_fractions(schedule, iterations, dagger_fraction=dagger_fraction)
