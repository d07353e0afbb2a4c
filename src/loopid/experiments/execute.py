"""Running a set of cells (scenario × method) into a run directory, with progress and resume,
for any family (:mod:`loopid.experiments.families`).

:func:`run_cells` checks everything before anything is written (the cells, the executor, the
workers against the machine's CPUs and memory, that ``out`` can be written, that a run
directory already there holds the same configuration), then:

1. splits each unfinished cell's missing seeds into tasks (:mod:`loopid.experiments.jobs`:
   one method's, or a lane set's methods'), in chunks of
   :data:`~loopid.experiments.chunks.LANE_WIDTH` lanes on a CPU (families with a memory estimate;
   :mod:`loopid.experiments.chunks`; on an accelerator, one process per device, or threads
   sharing one device, and chunks as large as its memory allows:
   :mod:`loopid.experiments.backend`);
2. hands the tasks (whole cells and chunks) to an executor
   (:mod:`loopid.experiments.executors`). A task first compiles its programs and reads their
   memory from them (the family's ``memory``); one that needs more than its process's share of
   the budget returns :class:`~loopid.experiments.cell.Oversized` instead of running, and its
   seeds go to a second round in chunks sized from that measurement
   (:func:`loopid.experiments.chunks.chunk_size`). So the
   estimate costs nothing extra: it is the compilation the task runs, in the process that runs
   it. Each finished task is saved the moment it is in, atomically: a cell's artifacts, then
   its rows; a chunk's files, merged into its cell's once all are in;
3. rewrites ``results.parquet`` in the fixed scenario × method order after every cell.

:func:`run_all` does the same for several run directories at once (``loopid reproduce``: the
helicopter's and, inside it, the MDP study's), their tasks given to one executor.

Rerunning the same call skips what is finished and ends with the same table, row for row. The
run directory and its ``config.toml`` are created when the first task finishes, so a run that
finishes nothing leaves nothing behind. :func:`write_outputs` draws ``figure.png`` and writes
``report.md`` through the run's family. One run directory holds one family's scenarios.
"""

import os
import shutil
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa

import loopid
from loopid.experiments import artifacts, backend, chunks
from loopid.experiments.cell import CellResult, Oversized, run_chunk
from loopid.experiments.cell import run_cell as run_cell  # also importable from here
from loopid.experiments.checks import (
    Methods,
    check_cells,
    check_rows,
    check_writable,
    methods_of,
)
from loopid.experiments.executors import (
    Job,
    check_executor,
    check_workers,
    executor,
    ray_session,
)
from loopid.experiments.families import Family, family_of, scenario_names
from loopid.experiments.jobs import (
    ProgressFactory,
    lane_sets,
    plan,
    progress_bars,
    resplit,
)
from loopid.experiments.report import cell_times, report_text
from loopid.experiments.results import with_metadata
from loopid.experiments.rundir import RunDir, config_family, normalized
from loopid.experiments.seeds import seeds_value
from loopid.files import write_atomic_bytes

#: A scenario of any family (its config dataclass).
Scenario = Any


def resolved_config(scenarios: Sequence[Scenario], methods: Methods, seeds) -> dict:
    """The configuration written to ``config.toml``: everything that determines the table."""
    if isinstance(methods, Mapping):
        listed = {s.name: methods_of(methods, s) for s in scenarios}
    else:
        listed = list(methods)
    return {
        "run": {
            "loopid_version": loopid.__version__,
            "family": family_of(scenarios[0]).name,
            "methods": listed,
            "seeds": seeds_value(seeds),
        },
        "scenario": {s.name: s.to_dict() for s in scenarios},
    }


class Run(NamedTuple):
    """One run directory's cells, as :func:`run_all` takes them: ``out``, its ``scenarios`` (one
    family's), their ``methods`` (one list, or ``{scenario name: list}``) and ``seeds``
    (default: the first scenario's)."""

    out: Any
    scenarios: Sequence[Scenario]
    methods: Methods
    seeds: Any = None


def run_cells(
    out,
    scenarios: Sequence[Scenario],
    methods: Methods,
    seeds=None,
    *,
    executor_name: str = "local",
    ray_address: str | None = None,
    workers: int = 1,
    memory: float | None = None,
    on_cell: ProgressFactory | None = None,
    log: Callable[[str], None] | None = None,
    lanes: bool | None = None,
) -> pa.Table:
    """Run every (scenario, method) cell not yet finished in ``out``; return the full table.

    ``scenarios``: configs of one family. ``methods``: one list for every scenario, or
    ``{scenario name: list}``. ``seeds`` defaults to the first scenario's
    (:func:`loopid.experiments.seeds.seed_list`; all scenarios of one run share the seeds).
    ``executor_name``: ``local`` or ``ray`` (``ray_address`` joins a cluster). ``workers``: the
    local executor's worker processes (1: in this process). ``memory``: the memory budget in GB
    of all the processes computing at once (default: :func:`loopid.experiments.chunks.budget`);
    cells that do not fit run in seed chunks. Each finished cell is saved at once (atomically),
    its artifacts (:mod:`.artifacts`) before its rows; ``results.parquet`` is rewritten after
    every cell. ``lanes``: run the methods a family groups as lane sets (its ``lane_sets``) as
    one task per seed chunk, every (method, seed) pair a lane of one program (default: on an
    accelerator, where width is nearly free; a CPU runs each method's seeds as one program:
    there a lane set measured only 1.03x faster, ``benchmarks/lanes.py``, and its fewer, larger
    tasks balance less evenly over the workers); the table is the same either way.
    """
    return run_all(
        [Run(out, scenarios, methods, seeds)], executor_name=executor_name,
        ray_address=ray_address, workers=workers, memory=memory, on_cell=on_cell, log=log,
        lanes=lanes,
    )[0]  # fmt: skip


class _Planned(NamedTuple):
    """A run being computed: its directory, configuration, cells in table order, family, seeds,
    the tasks of its unfinished cells, its progress bars (None: none), and the outermost folder
    it creates (None: none)."""

    rd: RunDir
    config: dict
    order: list
    family: Family
    seeds: np.ndarray
    jobs: list[Job]
    progress: Callable | None
    created: Path | None


def run_all(
    runs: Sequence[Run],
    *,
    executor_name: str = "local",
    ray_address: str | None = None,
    workers: int = 1,
    memory: float | None = None,
    on_cell: ProgressFactory | None = None,
    log: Callable[[str], None] | None = None,
    lanes: bool | None = None,
) -> list[pa.Table]:
    """:func:`run_cells` for several run directories at once (each :class:`Run` one family's,
    their scenario names all different), their tasks given to one executor, so that the
    workers a run leaves idle at its end take another run's cells; return each run's table.
    Everything is checked before anything is written."""
    specs = [Run(*r) for r in runs]
    seeds = [check_cells(r.scenarios, r.methods, r.seeds) for r in specs]
    folders = [Path(r.out).absolute() for r in specs]
    if len(set(folders)) != len(folders):
        raise ValueError(f"each run needs its own directory, got {[str(f) for f in folders]}")
    names = [s.name for r in specs for s in r.scenarios]
    if len(set(names)) != len(names):
        raise ValueError(f"scenario names must differ across the runs, got {names}")
    check_executor(executor_name, ray_address)
    chunks.check_memory(memory)
    threads = executor_name == "local" and backend.shared_device()  # workers share the device
    if executor_name == "local":  # on other accelerators, one process per device
        workers = backend.fold_workers(check_workers(workers), log)
    options = {"workers": workers, "threads": threads} if executor_name == "local" else {}
    if executor_name == "local" and workers > 1 and not threads:
        chunks.check_processes(workers)
    for r in specs:
        check_writable(r.out)
    if executor_name == "ray":
        import ray

        if not ray.is_initialized():  # connect before anything is written (a bad address)
            with ray_session(ray_address):
                return run_all(
                    [r._replace(seeds=s) for r, s in zip(specs, seeds, strict=True)],
                    executor_name="ray", memory=memory, on_cell=on_cell, log=log, lanes=lanes,
                )  # fmt: skip
    processes = options.get("workers", 1) if executor_name == "local" else (os.cpu_count() or 1)
    # each process (or thread) computing at once gets its share
    limit = chunks.budget(memory, processes, threads=threads)
    if lanes is None:
        lanes = backend.accelerator()
    planned = [_plan(r, s, limit, lanes, on_cell, log) for r, s in zip(specs, seeds, strict=True)]
    owner = {s.name: p for r, p in zip(specs, planned, strict=True) for s in r.scenarios}

    def progress(job: Job):
        bars = owner[job.scenario.name].progress
        return bars(job) if bars is not None else None

    on_job = progress if on_cell is not None else None

    def run_round(jobs, task) -> list[Job]:
        """Run the jobs, saving each finished one; return the Oversized ones' smaller chunks."""
        retry = []
        for job, done in executor(executor_name)(jobs, task, on_job=on_job, **options):
            p = owner[job.scenario.name]  # the run the task belongs to
            if isinstance(done, Oversized):
                retry += resplit(job, done.nbytes, p.seeds, limit)
                continue
            results = done if isinstance(done, dict) else {job.method: done}  # a lane set's
            for m, result in results.items():
                _save(p, job._replace(method=m), result, log)
        return retry

    try:
        # each task measures itself; those over budget come back as chunks sized from that
        # measurement (chunks.chunk_size), which run as they are
        retry = run_round([job for p in planned for job in p.jobs], partial(run_chunk, limit=limit))
        if retry:
            run_round(retry, run_chunk)
    except BaseException:
        # a run that finished nothing leaves nothing behind (a full disk, an interrupt): what
        # it wrote goes, then the folders it created that are left empty (a run that saved a
        # cell or chunk resumes from it; a nested run's folder stays with its cells)
        for p in planned:
            if p.created is not None and not any(p.rd.cells.rglob("*.parquet")):
                _remove_created(p)
        raise
    return [p.rd.write_results(p.order, save=p.rd.exists()) for p in planned]


def _plan(r: Run, seeds, limit: int, lanes: bool, on_cell, log) -> _Planned:
    """A run's unfinished cells (finished ones logged as skipped) and their tasks."""
    rd = RunDir(r.out)
    config = resolved_config(r.scenarios, r.methods, seeds)
    rd.prepare(config, create=False)
    order = [(s.name, m) for s in r.scenarios for m in methods_of(r.methods, s)]
    family = family_of(r.scenarios[0])
    todo = []
    for s in r.scenarios:
        for m in methods_of(r.methods, s):
            if rd.finished(s.name, m):  # a damaged cell's files moved aside: not finished
                if log:
                    log(f"{s.name} / {m}: already finished, skipped")
            else:
                todo.append((s, m))
    groups = lane_sets(family, todo) if lanes and family.run_lanes is not None else None
    widest = max((len(t) for sets in (groups or {}).values() for t in sets), default=1)
    check_rows(r.scenarios, seeds, limit, widest)
    jobs = plan(rd, todo, seeds, family, groups)
    progress = progress_bars(rd, todo, seeds, on_cell)
    return _Planned(rd, config, order, family, seeds, jobs, progress, _first_missing(rd.path))


def _remove_created(p: _Planned) -> None:
    """Remove what run ``p`` (which saved nothing) wrote, then each folder from its own up to
    :attr:`_Planned.created` that is left empty (one that holds another run stays)."""
    for name in ("config.toml", "results.parquet"):
        (p.rd.path / name).unlink(missing_ok=True)
    shutil.rmtree(p.rd.cells, ignore_errors=True)
    path, top = p.rd.path.absolute(), p.created.absolute()
    for folder in (path, *path.parents):
        if not folder.is_relative_to(top):
            break
        if folder.is_dir():  # a run that failed before its first save made none of its own
            if any(folder.iterdir()):
                break
            folder.rmdir()


def _save(p: _Planned, job, done: CellResult, log) -> None:
    """Save a finished task of run ``p`` (module docstring): a whole cell's artifacts then rows,
    or a chunk's files (merged into its cell's once all are in); then ``results.parquet``."""
    rd, config, order, family, seeds = p.rd, p.config, p.order, p.family, p.seeds
    s, method = job.scenario, job.method
    rd.ensure(config)
    count = job.part[1] - job.part[0]
    if len(job.seeds) > count:  # seed-major rows: drop the padding
        table = done.table.slice(0, count * s.iterations)
        final = _first(done.final, count)
        done = CellResult(table, seeds[slice(*job.part)], final, done.shared)
    chunked = count < len(seeds)
    if chunked:
        files = chunks.ChunkFiles(rd.cells, s.name, method)
        files.save(chunks.Chunk(*job.part, job.seeds), done.table, done.final)
        if files.missing(len(seeds)):
            return
        table, final = files.merged()
        done = CellResult(table, seeds, final, done.shared)
    t0 = time.perf_counter()
    artifacts.write(rd.cells, s.name, method, family.name, done.seeds, done.final,
                    s.to_dict(), done.shared)  # fmt: skip
    table = with_metadata(done.table, artifacts_s=f"{time.perf_counter() - t0:.3f}")
    rd.save_cell(s.name, method, table)  # last: a finished cell has its artifacts
    if chunked:
        chunks.ChunkFiles(rd.cells, s.name, method).remove()
    rd.write_results(order)
    if log:
        meta = rd.cell_metadata(s.name, method)
        last = np.asarray(table.column("iteration")) == s.iterations
        final = np.median(np.asarray(table.column("test_cost"))[last])
        parts = f", {meta['chunks']} chunks" if "chunks" in meta else ""
        log(
            f"{s.name} / {method}: {float(meta['wall_s']):.1f} s{parts}, "
            f"final median cost {final:.4g}"
        )


def _first_missing(path: Path) -> Path | None:
    """The outermost folder of ``path`` (itself included) that does not exist yet: what a run
    into ``path`` creates; None when ``path`` exists."""
    path = Path(path).absolute()
    if path.exists():
        return None
    while not path.parent.exists():
        path = path.parent
    return path


def _first(final: dict, count: int) -> dict:
    return {k: np.asarray(v)[:count] for k, v in final.items()}


def run_family(run_dir) -> tuple[Family | None, dict[str, Scenario]]:
    """The family of a run directory and its scenarios' configs, from ``config.toml``; ``(None,
    {})`` without one."""
    run_dir = Path(run_dir)
    cfg_file = run_dir / "config.toml"
    if cfg_file.is_file():
        config = tomllib.loads(cfg_file.read_text())
        try:
            family = config_family(config)
            tables = normalized(config).get("scenario", {})  # older files: the readings they ran
            configs = {n: family.config(**d) for n, d in tables.items()}
        except (TypeError, ValueError) as e:
            raise ValueError(f"{cfg_file}: {' '.join(str(e).split())}") from None
        return family, configs
    return None, {}


def write_outputs(run_dir, table: pa.Table, command_s: float | None = None) -> None:
    """``figure.png``, ``trajectories.png`` (what the saved final policies fly, for the families
    that draw it) and ``report.md`` of a run directory, drawn by its family. Without a
    ``config.toml`` (a bare ``results.parquet``): the family and packaged configs of the table's
    scenario names (``ValueError`` when no registered family ships them)."""
    run_dir = Path(run_dir)
    family, configs = run_family(run_dir)
    if family is None:
        names = scenario_names()
        present = list(dict.fromkeys(table.column("scenario").to_pylist()))
        family = next((names[s] for s in present if s in names), None)
        if family is None:
            raise ValueError(
                f"{run_dir} holds no config.toml and no registered family ships its scenarios "
                f"({', '.join(present)})"
            )
        configs = {s: family.scenarios[s] for s in present if s in family.scenarios}
    family.figure(table, run_dir / "figure.png", configs)
    if family.trajectories is not None and (run_dir / "config.toml").is_file():
        family.trajectories(run_dir, configs, run_dir / "trajectories.png")
    cfg_file = run_dir / "config.toml"
    text = report_text(
        table,
        family.report(table, configs),
        config_text=cfg_file.read_text() if cfg_file.is_file() else None,
        times=cell_times(run_dir),
        command_s=command_s,
    )
    write_atomic_bytes(text.encode(), run_dir / "report.md")
