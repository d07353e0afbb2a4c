"""Running a set of cells (scenario × method) into a run directory, with progress and resume,
for any family (:mod:`loopid.experiments.families`).

:func:`run_cells` checks everything, prepares the run directory (refusing one made with another
configuration), then hands the unfinished cells to an executor
(:mod:`loopid.experiments.executors`) and saves each cell the moment it finishes (atomically),
rewriting ``results.parquet`` in the fixed scenario × method order. Rerunning the same call
skips the finished cells and ends with the same table, row for row. :func:`write_outputs` draws
``figure.png`` and writes ``report.md`` through the run's family. One run directory holds one
family's scenarios.
"""

import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa

import loopid
from loopid.algorithms.loop import Row
from loopid.experiments import artifacts
from loopid.experiments.config import seed_list
from loopid.experiments.executors import (
    Job,
    check_executor,
    check_workers,
    executor,
    ray_session,
)
from loopid.experiments.families import FAMILIES, Family, family_of, scenario_names
from loopid.experiments.report import cell_times, report_text
from loopid.experiments.results import trace_table, with_metadata, write_atomic_bytes
from loopid.experiments.rundir import RunDir

#: A scenario of any family (its config dataclass).
Scenario = Any

#: ``on_cell(scenario, method, iterations) -> per-iteration callback`` (for progress bars).
ProgressFactory = Callable[[str, str, int], Callable[[int, Row], None] | None]


#: The methods of a run: one list for every scenario, or a list per scenario name.
Methods = Sequence[str] | Mapping[str, Sequence[str]]


def methods_of(methods: Methods, s: Scenario) -> list[str]:
    """The methods scenario ``s`` runs."""
    if isinstance(methods, Mapping):
        return list(methods[s.name])
    return list(methods)


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
            "seeds": [int(s) for s in seeds],
        },
        "scenario": {s.name: s.to_dict() for s in scenarios},
    }


class CellResult(NamedTuple):
    """A finished cell: its rows (with its timings in the table's metadata) and what it ended
    with (:attr:`loopid.algorithms.loop.Trace.final`, saved by :mod:`.artifacts`)."""

    table: pa.Table
    seeds: np.ndarray
    final: dict
    shared: dict


def run_cell(
    s: Scenario, method: str, seeds, progress: Callable[[int, Row], None] | None = None
) -> CellResult:
    """One cell: its rows (:func:`loopid.experiments.results.trace_table`), with its timings in
    the table's metadata: ``wall_s`` (the whole cell) and ``first_s`` (until iteration 2 was
    done: compilation plus two iterations); and its final policies and models."""
    t0 = time.perf_counter()
    first = [None]

    def tick(n: int, row: Row) -> None:
        if n == min(2, s.iterations):
            first[0] = time.perf_counter() - t0
        if progress is not None:
            progress(n, row)

    trace = family_of(s).run(method, s, seeds, progress=tick)
    wall = time.perf_counter() - t0
    table = trace_table(s.name, method, trace)
    table = with_metadata(table, wall_s=f"{wall:.3f}", first_s=f"{first[0] or wall:.3f}")
    family = family_of(s)
    shared = family.shared(s, method) if family.shared is not None else {}
    return CellResult(table, np.asarray(trace.seeds), dict(trace.final or {}), shared)


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
    if family.check is not None:
        for s in scenarios:
            family.check(s)
    return seeds


def run_cells(
    out,
    scenarios: Sequence[Scenario],
    methods: Methods,
    seeds=None,
    *,
    executor_name: str = "local",
    ray_address: str | None = None,
    workers: int = 1,
    on_cell: ProgressFactory | None = None,
    log: Callable[[str], None] | None = None,
) -> pa.Table:
    """Run every (scenario, method) cell not yet finished in ``out``; return the full table.

    ``scenarios``: configs of one family. ``methods``: one list for every scenario, or
    ``{scenario name: list}``. ``seeds`` defaults to the first scenario's
    (:func:`loopid.experiments.config.seed_list`; all scenarios of one run share the seeds).
    ``executor_name``: ``local`` or ``ray`` (``ray_address`` joins a cluster). ``workers``: the
    local executor's worker processes (1: in this process). Each finished cell is saved at once
    (atomically), its artifacts (:mod:`.artifacts`) before its rows; ``results.parquet`` is
    rewritten after every cell.
    """
    seeds = check_cells(scenarios, methods, seeds)
    check_executor(executor_name, ray_address)
    options = {"workers": check_workers(workers)} if executor_name == "local" else {}
    if executor_name == "ray":
        import ray

        if not ray.is_initialized():  # connect before anything is written (a bad address)
            with ray_session(ray_address):
                return run_cells(
                    out, scenarios, methods, seeds, executor_name="ray", on_cell=on_cell, log=log
                )
    rd = RunDir(out)
    rd.prepare(resolved_config(scenarios, methods, seeds))
    order = [(s.name, m) for s in scenarios for m in methods_of(methods, s)]
    jobs = []
    for s in scenarios:
        for m in methods_of(methods, s):
            if rd.done(s.name, m):
                if log:
                    log(f"{s.name} / {m}: already finished, skipped")
            else:
                jobs.append(Job(s, m))
    family = family_of(scenarios[0]).name
    for job, done in executor(executor_name)(jobs, seeds, run_cell, on_cell=on_cell, **options):
        name, t0 = job.scenario.name, time.perf_counter()
        artifacts.write(rd.cells, name, job.method, family, done.seeds, done.final,
                        job.scenario.to_dict(), done.shared)  # fmt: skip
        table = with_metadata(done.table, artifacts_s=f"{time.perf_counter() - t0:.3f}")
        rd.save_cell(name, job.method, table)  # last: a finished cell has its artifacts
        rd.write_results(order)
        if log:
            meta = rd.cell_metadata(job.scenario.name, job.method)
            last = np.asarray(table.column("iteration")) == job.scenario.iterations
            final = np.median(np.asarray(table.column("test_cost"))[last])
            log(
                f"{job.scenario.name} / {job.method}: {float(meta['wall_s']):.1f} s, "
                f"final median cost {final:.4g}"
            )
    return rd.write_results(order)


def run_family(run_dir) -> tuple[Family | None, dict[str, Scenario]]:
    """The family of a run directory and its scenarios' configs, from ``config.toml``; ``(None,
    {})`` without one."""
    run_dir = Path(run_dir)
    cfg_file = run_dir / "config.toml"
    if cfg_file.is_file():
        config = tomllib.loads(cfg_file.read_text())
        name = config.get("run", {}).get("family", "helicopter")
        if name not in FAMILIES:
            raise ValueError(f"{cfg_file}: unknown family {name!r}")
        family = FAMILIES[name]
        try:
            configs = {n: family.config(**d) for n, d in config.get("scenario", {}).items()}
        except (TypeError, ValueError) as e:
            raise ValueError(f"{cfg_file}: {' '.join(str(e).split())}") from None
        return family, configs
    return None, {}


def write_outputs(run_dir, table: pa.Table, command_s: float | None = None) -> None:
    """``figure.png``, ``trajectories.png`` (what the saved final policies fly, for the families
    that draw it) and ``report.md`` of a run directory, drawn by its family. Without a
    ``config.toml`` (a bare ``results.parquet``): the family and packaged configs of the table's
    scenario names, the helicopter's when no name is registered."""
    run_dir = Path(run_dir)
    family, configs = run_family(run_dir)
    if family is None:
        names = scenario_names()
        present = list(dict.fromkeys(table.column("scenario").to_pylist()))
        family = next((names[s] for s in present if s in names), FAMILIES["helicopter"])
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
