"""Running a set of cells (scenario × method) into a run directory, with progress and resume."""

import time
from collections.abc import Callable, Sequence

import numpy as np

import loopid
from loopid.algorithms.loop import Row
from loopid.experiments.results import trace_table
from loopid.experiments.rundir import RunDir
from loopid.experiments.runner import run
from loopid.experiments.scenarios import Scenario

#: ``on_cell(scenario, method, iterations) -> per-iteration callback`` (for progress bars).
ProgressFactory = Callable[[str, str, int], Callable[[int, Row], None] | None]


def resolved_config(scenarios: Sequence[Scenario], methods: Sequence[str], seeds) -> dict:
    """The configuration written to ``config.toml``: everything that determines the table."""
    return {
        "run": {
            "loopid_version": loopid.__version__,
            "methods": list(methods),
            "seeds": [int(s) for s in seeds],
        },
        "scenario": {s.name: s.to_dict() for s in scenarios},
    }


def run_cells(
    out,
    scenarios: Sequence[Scenario],
    methods: Sequence[str],
    seeds=None,
    *,
    on_cell: ProgressFactory | None = None,
    log: Callable[[str], None] | None = None,
):
    """Run every (scenario, method) cell not yet finished in ``out``; return the full table.

    ``seeds`` defaults to ``range(scenario.seeds)`` of the first scenario (all scenarios of one
    run share the seeds). Each finished cell is saved at once (atomically); ``results.parquet``
    is rewritten after every cell.
    """
    if seeds is None:
        seeds = np.arange(scenarios[0].seeds)
    seeds = np.asarray(seeds)
    rd = RunDir(out)
    rd.prepare(resolved_config(scenarios, methods, seeds))
    order = [(s.name, m) for s in scenarios for m in methods]
    for s in scenarios:
        for m in methods:
            if rd.done(s.name, m):
                if log:
                    log(f"{s.name} / {m}: already finished, skipped")
                continue
            t0 = time.perf_counter()
            cb = on_cell(s.name, m, s.iterations) if on_cell else None
            trace = run(m, s, seeds, progress=cb)
            rd.save_cell(s.name, m, trace_table(s.name, m, trace))
            rd.write_results(order)
            if log:
                final = np.median(trace.rows.test_cost[:, -1])
                secs = time.perf_counter() - t0
                log(f"{s.name} / {m}: {secs:.1f} s, final median cost {final:.4g}")
    return rd.write_results(order)
