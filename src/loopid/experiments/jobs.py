"""The tasks of a run (:mod:`loopid.experiments.execute`): which cells and seed chunks run
as one task, a task that came back over its memory share split again, and the progress bars a
task advances.

A task (:class:`~loopid.experiments.executors.Job`) is one cell's missing seeds, or one chunk
of them (:mod:`loopid.experiments.chunks`), of one method, or of several methods run as one
program: with lanes on and a family that has ``run_lanes``, the methods of one of its *lane
sets* (``lane_sets``: the methods grouped by the compiled program they share) that miss the
same seeds, every (method, seed) pair a lane, the ``method`` then being the tuple of them.
Otherwise a lane set only names the program that its methods' one-method tasks share.
"""

from collections.abc import Callable
from typing import Any

import numpy as np

from loopid.experiments import backend, chunks
from loopid.experiments.executors import Job
from loopid.experiments.families import Family
from loopid.experiments.rundir import RunDir

#: A scenario of any family (its config dataclass).
Scenario = Any

#: ``on_cell(scenario, method, total) -> advance(completed)`` (for progress bars): a cell's work
#: is ``total`` = seeds × iterations; ``advance`` is called with the seed-iterations done so far
#: over all its chunks.
ProgressFactory = Callable[[str, str, int], Callable[[int], None] | None]


def method_names(method: str | tuple[str, ...]) -> str:
    """A task's method, or its lane set's methods, for messages."""
    return method if isinstance(method, str) else ",".join(method)


def lane_sets(family: Family, todo) -> dict[str, list[tuple[str, ...]]]:
    """``{scenario name: lane sets}`` of the unfinished cells (the family's ``lane_sets`` of
    each scenario's unfinished methods)."""
    methods: dict[str, list[str]] = {}
    configs = {}
    for s, m in todo:
        methods.setdefault(s.name, []).append(m)
        configs[s.name] = s
    return {name: family.lane_sets(configs[name], ms) for name, ms in methods.items()}


def plan(rd: RunDir, todo, seeds: np.ndarray, family: Family, groups=None) -> list[Job]:
    """The tasks of the unfinished cells: each cell's missing seeds, for families with a memory
    estimate in chunks of :func:`loopid.experiments.chunks.lane_width` lanes (on a CPU exactly
    that many, padded; on an accelerator at most, at least ``MIN_CHUNK``), else whole; a cell
    that is one chunk is saved as a cell, with no chunk files. ``groups`` (:func:`lane_sets`):
    the methods of a lane set that miss the same seeds run as one task per chunk (its
    ``method`` the tuple of them)."""
    if family.memory:  # chunked: on a CPU every chunk one lane width (one program shape)
        most = chunks.lane_width(len(seeds))
        least = chunks.MIN_CHUNK if backend.accelerator() else most
    else:
        most, least = len(seeds), 1
    missing = {
        (s.name, m): tuple(chunks.ChunkFiles(rd.cells, s.name, m).missing(len(seeds)))
        for s, m in todo
    }
    grouped = groups if groups is not None else lane_sets(family, todo)
    tasks = list(todo)
    if groups is not None:
        configs = {s.name: s for s, _ in todo}
        tasks = []
        for name, sets in groups.items():
            for lane_set in sets:
                same: dict[tuple, list[str]] = {}  # methods missing the same seeds
                for m in lane_set:
                    same.setdefault(missing[(name, m)], []).append(m)
                for ms in same.values():
                    tasks.append((configs[name], ms[0] if len(ms) == 1 else tuple(ms)))
    # the methods a lane set can hold share a compiled program when run one at a time
    shared = {
        (name, m): lane_set
        for name, named in grouped.items()
        for lane_set in named
        for m in lane_set
    }
    jobs = []
    for s, m in tasks:
        first = m if isinstance(m, str) else m[0]
        left = list(missing[(s.name, first)])
        parts = chunks.split(seeds, left, min(len(left), most), least)
        lanes = isinstance(m, tuple)  # a lane set's program is not its methods' one at a time
        program = (s.name, m if lanes else shared.get((s.name, m), (m,)), lanes)
        jobs += jobs_of(s, m, parts, program)
    return jobs


def jobs_of(s: Scenario, method: str | tuple, parts: list[chunks.Chunk], program=None) -> list[Job]:
    """A task per chunk; ``program`` (:attr:`Job.program`, without the seed count): the key of
    the programs the task runs, completed with its chunk's seed count (None: its own)."""
    return [
        Job(s, method, c.seeds, (c.start, c.stop), program and (*program, len(c.seeds)))
        for c in parts
    ]


def resplit(job: Job, nbytes: int, seeds: np.ndarray, limit: int) -> list[Job]:
    """An :class:`Oversized` task's seeds as chunks that fit ``limit``
    (:func:`loopid.experiments.chunks.chunk_size`: the programs' memory is affine in the seeds,
    so ``⌊S · limit / nbytes⌋`` of them fit); a one-line ``ValueError`` when not even
    ``MIN_CHUNK`` do."""
    where = f"{job.scenario.name} / {method_names(job.method)}"
    size = chunks.chunk_size(nbytes, len(job.seeds), limit, where)
    parts = chunks.split(seeds, list(range(*job.part)), size)
    return jobs_of(job.scenario, job.method, parts, job.program and job.program[:-1])


def progress_bars(rd: RunDir, todo, seeds: np.ndarray, on_cell: ProgressFactory | None):
    """``on_job(job) -> callback(n, row)``: one bar per cell over seeds × iterations, its
    chunks' iterations adding up (saved chunks count as done); a lane set's task advances the
    bar of each of its methods."""
    if on_cell is None:
        return None
    bars: dict = {}

    def bar(s: Scenario, method: str):
        key = (s.name, method)
        if key not in bars:
            saved = len(seeds) - len(chunks.ChunkFiles(rd.cells, *key).missing(len(seeds)))
            bars[key] = (on_cell(s.name, method, len(seeds) * s.iterations), {}, saved)
        return bars[key]

    def on_job(job: Job):
        s = job.scenario
        methods = (job.method,) if isinstance(job.method, str) else job.method
        count = job.part[1] - job.part[0]
        mine = [bar(s, m) for m in methods]
        mine = [b for b in mine if b[0] is not None]
        if not mine:
            return None

        def tick(n: int, row) -> None:
            for advance, parts, saved in mine:
                parts[job.part] = n * count
                advance(saved * s.iterations + sum(parts.values()))

        return tick

    return on_job
