"""The checks a run makes before anything is written (:mod:`loopid.experiments.execute`): its
cells, that ``out`` can be written, and that its rows fit the memory budget. Each raises
``ValueError`` in one line naming the bad value."""

import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from loopid.experiments import chunks
from loopid.experiments.families import family_of
from loopid.experiments.seeds import seed_list

#: A scenario of any family (its config dataclass).
Scenario = Any

#: The methods of a run: one list for every scenario, or a list per scenario name.
Methods = Sequence[str] | Mapping[str, Sequence[str]]


def methods_of(methods: Methods, s: Scenario) -> list[str]:
    """The methods scenario ``s`` runs."""
    if isinstance(methods, Mapping):
        return list(methods[s.name])
    return list(methods)


#: What a task holds in host memory per iteration (the iteration's row objects, about 1 kB) and
#: per row of the table (one seed at one iteration, 14 float64/int columns and their share of
#: the objects, about 150 B): :func:`check_rows`.
ITERATION_BYTES, ROW_BYTES = 1000, 150


def check_rows(
    scenarios: Sequence[Scenario], seeds: np.ndarray, limit: int, methods: int = 1
) -> None:
    """Refuse, in one line, a scenario whose rows alone cannot fit one process's memory budget
    (``limit`` bytes): a task keeps every iteration's rows of its seeds (of each of its
    ``methods``, a lane set's) until it ends, about ``iterations · (ITERATION_BYTES + ROW_BYTES
    · seeds · methods)`` bytes, whatever the chunking of its seeds (so ``--iterations
    1000000000`` is refused at once instead of running for hours)."""
    chunk = chunks.lane_width(len(seeds)) * methods
    for s in scenarios:
        need = s.iterations * (ITERATION_BYTES + ROW_BYTES * chunk)
        if need > limit:
            raise ValueError(
                f"{s.name}: {s.iterations} iterations of {chunk} seeds a task "
                f"keep about {chunks.size_text(need)} of rows, more than the memory budget of "
                f"{chunks.size_text(limit)} per worker; lower --iterations"
            )


def check_writable(out) -> None:
    """``ValueError`` in one line unless a run directory can be created and written at ``out``
    (tried with a temporary file in its nearest existing folder; nothing is left behind)."""
    out = Path(out)
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"--out {str(out)!r}: {str(existing)!r} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as e:
        raise ValueError(f"--out {str(out)!r} cannot be written ({e.strerror or e})") from None


def check_cells(scenarios: Sequence[Scenario], methods: Methods, seeds) -> np.ndarray:
    """Validate a run's cells before anything is written; return the seeds as an array."""
    if not scenarios:
        raise ValueError("no scenarios to run")
    names = [s.name for s in scenarios]
    if len(set(names)) != len(names):
        raise ValueError(f"scenario names must differ, got {names}")
    family = family_of(scenarios[0])
    others = sorted({family_of(s).name for s in scenarios} - {family.name})
    if others:
        raise ValueError(
            f"one run directory holds one family's scenarios: {family.name}, not also {others}"
        )
    if isinstance(methods, Mapping) and set(methods) != set(names):
        raise ValueError(f"methods are given for {sorted(methods)}, the scenarios are {names}")
    for s in scenarios:
        chosen = methods_of(methods, s)
        if not chosen:
            raise ValueError("no methods to run")
        if len(set(chosen)) != len(chosen):
            raise ValueError(f"methods must differ, got {chosen}")
        family.check_methods(s, chosen)
    seeds = seed_list(scenarios[0]) if seeds is None else np.asarray(seeds)
    if seeds.ndim != 1 or seeds.size == 0 or not np.issubdtype(seeds.dtype, np.integer):
        raise ValueError(f"seeds must be a non-empty list of integers, got {seeds.tolist()!r}")
    if (seeds < 0).any():
        raise ValueError(f"seeds must be >= 0, got {seeds.tolist()}")
    for s in scenarios:
        family.check(s)
    return seeds
