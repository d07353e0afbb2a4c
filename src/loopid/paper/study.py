"""The reading study (``loopid study``): every reading of the paper's open details.

The paper leaves some details of its experiments open; each defensible reading is a scenario
field (``delay_mode``, ``nu_pending``, ``funnel_nominal``, ``pads``, ``pg_samples``;
:mod:`loopid.experiments.families.helicopter.readings`). A :class:`Reading` changes fields of the
paper's panels (:data:`SCENARIOS`, the preset ``probable``) and names the panels and methods whose
results the change can touch. The study runs each reading one factor at a time from ``probable``,
and the preset ``literal`` as a whole. It is one run directory
(:func:`loopid.experiments.execute.run_cells`: resume, atomic cells, workers, Ray) holding, for
every reading, exactly those cells, as the scenario ``PANEL-ID`` (the default reading's
scenarios keep the panels' names); every other cell of a reading is the default's or a part's,
which is the same computation (a method whose inputs the field does not reach). The default
reading is the run of ``loopid reproduce`` itself: ``--reproduce DIR`` copies that run's
finished cells of the same configuration (:func:`share_cells`) instead of computing them again.

The readings themselves are in :mod:`loopid.paper.study_readings`, the
outputs (``study.md`` and the figures) in
:mod:`loopid.paper.study_report`; this module plans the study's cells and
runs it (:func:`run_study`, what ``loopid study`` calls).
"""

import time
from collections.abc import Callable, Sequence
from pathlib import Path

import pyarrow as pa

from loopid.experiments.families.helicopter.readings import READING_FIELDS
from loopid.experiments.families.helicopter.scenario import SCENARIOS, Scenario
from loopid.experiments.seeds import seeds_from_value
from loopid.paper.study_readings import (
    BY_ID,
    DEFAULT,
    FIGURES,
    READINGS,
    Reading,
    reading_table,
    scenario_name,
    source,
    study_table,
)
from loopid.paper.study_report import (
    funnel_prediction_lines,
    load,
    write_outputs,
)

__all__ = [
    "BY_ID",
    "DEFAULT",
    "FIGURES",
    "READINGS",
    "READING_FIELDS",
    "Reading",
    "funnel_prediction_lines",
    "load",
    "reading_table",
    "run_study",
    "scenario_name",
    "share_cells",
    "source",
    "study_cells",
    "study_table",
    "write_outputs",
]


def study_cells(base: dict[str, Scenario]) -> tuple[list[Scenario], dict[str, tuple[str, ...]]]:
    """Every scenario the study runs (the readings' changes applied to ``base``, validated) and
    the methods each runs; a pure combination runs nothing of its own."""
    scenarios, methods = [], {}
    for r in READINGS:
        for p in (r.runs_on or r.panels) if r.methods else ():
            s = base[p].replace(name=scenario_name(r, p), **r.changes)
            scenarios.append(s)
            methods[s.name] = r.methods
    return scenarios, methods


def share_cells(out: Path, reproduce: Path, scenarios: Sequence[Scenario], seeds) -> list[str]:
    """Copy into ``out/cells`` every finished cell of the ``loopid reproduce`` run directory
    ``reproduce`` whose scenario has the same configuration (every field, the name included)
    and the same seeds as one of ``scenarios``; return the files copied."""
    import shutil
    import tomllib

    from loopid.experiments.rundir import RunDir, normalized

    config = normalized(tomllib.loads((Path(reproduce) / "config.toml").read_text()))
    recorded = seeds_from_value(config.get("run", {}).get("seeds", []))
    if recorded.tolist() != [int(x) for x in seeds]:
        return []
    theirs, ours = RunDir(reproduce), RunDir(out)
    copied = []
    for s in scenarios:
        if config.get("scenario", {}).get(s.name) != s.to_dict():
            continue
        for f in sorted(theirs.cells.glob(f"{s.name}__*.parquet")):
            target = ours.cells / f.name
            if target.exists():
                continue
            # the artifacts first, the rows last: a copied cell is finished with everything
            for part in (f.with_suffix(".npz"), f.with_suffix(".json"), f):
                if part.exists():
                    tmp = ours.cells / f".{part.name}.tmp"
                    shutil.copy2(part, tmp)
                    tmp.replace(ours.cells / part.name)
            copied.append(f.name)
    return copied


def run_study(
    out: Path,
    changes: dict,
    *,
    reproduce: Path | None = None,
    executor: str = "local",
    ray_address: str | None = None,
    workers: int | None = None,
    memory: float | None = None,
    on_cell=None,
    log: Callable[[str], None] = lambda line: None,
    started: float | None = None,
) -> pa.Table:
    """Run the study into ``out`` and write its outputs; return the readings' table.

    ``changes``: scenario fields set on every panel first (``--quick``, ``--seeds``);
    ``reproduce``: a ``loopid reproduce`` run directory whose finished cells of the same
    configuration and seeds are copied, not recomputed (:func:`share_cells`); ``executor``,
    ``ray_address``, ``workers``, ``memory``, ``on_cell``, ``log``: those of
    :func:`loopid.experiments.execute.run_cells`; ``started``: the ``time.perf_counter()`` the
    command started at (``study.md`` gives the time since). Every problem with the arguments is
    a ``ValueError`` raised before anything is written.
    """
    from loopid.experiments.execute import check_cells, resolved_config, run_cells
    from loopid.experiments.rundir import RunDir
    from loopid.files import write_atomic

    started = time.perf_counter() if started is None else started
    base = {name: s.replace(**changes) for name, s in SCENARIOS.items()}
    scenarios, methods = study_cells(base)
    seed_list = check_cells(scenarios, methods, None)
    if reproduce is not None and not (Path(reproduce) / "config.toml").is_file():
        raise ValueError(f"--reproduce {str(reproduce)!r} holds no config.toml")
    RunDir(out).prepare(resolved_config(scenarios, methods, seed_list))
    if reproduce is not None:
        shared = share_cells(out, reproduce, scenarios, seed_list)
        log(f"{len(shared)} cells shared with {reproduce}")
    table = run_cells(
        out, scenarios, methods, executor_name=executor, ray_address=ray_address,
        workers=workers, memory=memory, on_cell=on_cell, log=log,
    )  # fmt: skip
    readings = study_table(table, base)
    write_atomic(readings, Path(out) / "study.parquet")
    prediction = funnel_prediction_lines(base["funnel"])
    write_outputs(
        out, readings, base, command_s=time.perf_counter() - started, prediction=prediction
    )
    return readings
