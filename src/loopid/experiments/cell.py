"""One task, run in the calling process: a whole cell (scenario × method, or a lane set's
methods) or one chunk of its seeds, into its rows, timings and final policies.

An executor (:mod:`loopid.experiments.executors`) runs :func:`run_chunk` for each task that
:func:`loopid.experiments.execute.run_all` planned (:mod:`loopid.experiments.jobs`); the run
saves what it returns (:class:`CellResult`), or resplits the seeds of a task that returned
:class:`Oversized` (:func:`loopid.experiments.jobs.resplit`).
"""

import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa

from loopid.algorithms.contracts import Row
from loopid.experiments import compilations
from loopid.experiments.compilations import Programs
from loopid.experiments.families import family_of
from loopid.experiments.jobs import method_names
from loopid.experiments.results import trace_table, with_metadata

#: A scenario of any family (its config dataclass).
Scenario = Any


class CellResult(NamedTuple):
    """A finished cell: its rows (with its timings in the table's metadata) and what it ended
    with (:attr:`loopid.algorithms.contracts.Trace.final`, saved by :mod:`.artifacts`)."""

    table: pa.Table
    seeds: np.ndarray
    final: dict
    shared: dict


def run_cell(
    s: Scenario,
    method: str | tuple[str, ...],
    seeds,
    progress: Callable[[int, Row], None] | None = None,
    *,
    started: float | None = None,
    built: Programs | None = None,
) -> CellResult | dict[str, CellResult]:
    """One cell: its rows (:func:`loopid.experiments.results.trace_table`), with its timings in
    the table's metadata: ``wall_s`` (the whole cell) and ``first_s`` (until iteration 2's row
    came back: compilation plus two iterations, or, where the loop runs blocks of iterations,
    plus the first block), both from ``started`` (a ``time.perf_counter()``; default now); and
    its final policies and models.

    A tuple of methods is a lane set (the family's ``lane_sets``, run by its ``run_lanes``):
    ``{method: CellResult}``, each cell's ``wall_s`` and ``first_s`` the lane set's times shared
    equally among its methods (metadata ``lane_set`` names them), so that a lane set's cells
    add up to its time. ``compiled`` and ``loaded``: the XLA programs this process built for it
    since ``built`` (:func:`loopid.experiments.compilations.programs`; default now), compiled
    anew or loaded from the persistent cache; a lane set's are its first method's (0 for the
    others), so that they add up too."""
    t0 = time.perf_counter() if started is None else started
    built = compilations.programs() if built is None else built
    first = [None]

    def tick(n: int, row: Row) -> None:
        if n == min(2, s.iterations):
            first[0] = time.perf_counter() - t0
        if progress is not None:
            progress(n, row)

    family = family_of(s)
    if isinstance(method, tuple):
        traces = family.run_lanes(method, s, seeds, progress=tick)
    else:
        traces = {method: family.run(method, s, seeds, progress=tick)}
    wall = time.perf_counter() - t0
    programs = compilations.programs() - built
    results = {}
    for k, (m, trace) in enumerate(traces.items()):
        share = len(traces)
        meta = {"wall_s": f"{wall / share:.3f}", "first_s": f"{(first[0] or wall) / share:.3f}"}
        meta |= {"compiled": str(programs.compiled if k == 0 else 0)}
        meta |= {"loaded": str(programs.loaded if k == 0 else 0)}
        if isinstance(method, tuple):
            meta["lane_set"] = ",".join(method)
        table = with_metadata(trace_table(s.name, m, trace), **meta)
        shared = family.shared(s, m)
        results[m] = CellResult(table, np.asarray(trace.seeds), dict(trace.final or {}), shared)
    return results if isinstance(method, tuple) else results[method]


def _out_of_memory(e: BaseException) -> bool:
    text = str(e)
    return isinstance(e, MemoryError) or "RESOURCE_EXHAUSTED" in text or "Out of memory" in text


class Oversized(NamedTuple):
    """What a task returns instead of running when its programs need ``nbytes`` (at its seed
    count), more than its process's share of the memory budget."""

    nbytes: int


def run_chunk(
    s: Scenario,
    method: str | tuple[str, ...],
    seeds,
    progress: Callable[[int, Row], None] | None = None,
    *,
    limit: int | None = None,
) -> CellResult | dict[str, CellResult] | Oversized:
    """What an executor runs: :func:`run_cell` on a whole cell's or one chunk's seeds (of one
    method, or of a lane set's); an out-of-memory error from JAX becomes one line saying what
    to lower.

    ``limit``: the bytes this process may use. For a family with a memory estimate the task
    first compiles its programs and reads their peak from them (``family.memory``, the same
    compilation the run then reuses), and returns :class:`Oversized` instead of running when
    it is above ``limit``."""
    family = family_of(s)
    started = time.perf_counter()  # the cell's time includes the compilation measured here
    built = compilations.programs()  # and its programs those compiled here
    if limit is not None and family.memory is not None:
        nbytes = int(family.memory(s, method, len(seeds)))
        if nbytes > limit:
            return Oversized(nbytes)
    try:
        return run_cell(s, method, seeds, progress, started=started, built=built)
    except Exception as e:
        if _out_of_memory(e):
            raise ValueError(
                f"{s.name} / {method_names(method)}: out of memory running {len(seeds)} seeds at "
                "once; lower --memory (chunks are sized to it) or --workers"
            ) from None
        raise
