"""``report.md`` of a run directory: what every family's report shares, then the family's own
sections (:class:`loopid.experiments.families.base.Family` ``report``).

The common part: the version and date, the figure, the resolved ``config.toml``, the wall time
(this command's, and the cells' as each recorded it) and, per scenario, the final test cost of
every method (:func:`final_table`). Every number comes from ``results.parquet`` and the cells'
recorded times. The helicopter's sections add the paper's findings
(:mod:`loopid.experiments.families.helicopter.findings`); the finite MDPs' add the exact bounds.
"""

import datetime
import os
import platform
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa

import loopid
from loopid.experiments import backend
from loopid.experiments.final_costs import Costs, significant


class CellTime(NamedTuple):
    """What a finished cell recorded of its run: seconds in all (``wall_s``), until its
    iteration 2's row (``first_s``), writing its saved policies and models (``artifacts_s``, 0
    if not recorded), and the XLA programs it built, ``compiled`` anew and ``loaded`` from the
    persistent compilation cache (None if not recorded)."""

    wall_s: float
    first_s: float
    artifacts_s: float
    compiled: int | None = None
    loaded: int | None = None


def cell_times(run_dir: Path) -> dict[tuple[str, str], CellTime]:
    """``{(scenario, method): CellTime}`` of the finished cells of a run."""
    from loopid.experiments.results import metadata

    out = {}
    for f in sorted((Path(run_dir) / "cells").glob("*__*.parquet")):
        meta = metadata(f)
        if "wall_s" in meta:
            s, m = f.stem.split("__", 1)
            counted = "compiled" in meta and "loaded" in meta
            out[(s, m)] = CellTime(
                float(meta["wall_s"]),
                float(meta.get("first_s", meta["wall_s"])),
                float(meta.get("artifacts_s", 0.0)),
                int(meta["compiled"]) if counted else None,
                int(meta["loaded"]) if counted else None,
            )
    return out


def programs_line(times: dict[tuple[str, str], CellTime]) -> str | None:
    """The report's line on the XLA programs the cells built (None when no cell recorded it)."""
    counted = [t for t in times.values() if t.compiled is not None]
    if not counted:
        return None
    compiled = sum(t.compiled for t in counted)
    loaded = sum(t.loaded for t in counted)
    missing = len(times) - len(counted)
    rest = f"; {missing} cells from before counting did not record theirs" if missing else ""
    return (
        f"- XLA programs the cells built: {compiled} compiled, {loaded} loaded from the "
        f"compilation cache (cells skipped on resume keep the counts of the run that computed "
        f"them{rest})"
    )


def final_table(c: Costs, s: str) -> list[str]:
    """Markdown table of scenario ``s``: per method the final cost's mean ± s.e. and median over
    seeds, the seeds with a diverged test run and the last iteration."""
    lines = [
        "| method | final mean ± s.e. | final median | seeds diverged | iterations |",
        "|---|---|---|---|---|",
    ]
    for m in c.methods:
        if not c.has(s, m):
            continue
        v = c.at(s, m)
        se = v.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else 0.0
        lines.append(
            f"| {m} | {significant(v.mean())} ± {significant(se)} | "
            f"{significant(float(np.median(v)))} | "
            f"{c.diverged_seeds(s, m)}/{v.size} | {c.last_iteration(s, m)} |"
        )
    return lines


def final_cost_sections(
    table: pa.Table, notes: dict[str, str] | None = None, title: str = "Final test cost"
) -> list[str]:
    """``## Final test cost``, then per scenario its :func:`final_table`, preceded by the
    scenario's line in ``notes`` when there is one."""
    c = Costs(table)
    lines = [f"## {title} per scenario and method", ""]
    for s in c.scenarios:
        lines += [f"### {s}", ""]
        if notes and s in notes:
            lines += [notes[s], ""]
        lines += [*final_table(c, s), ""]
    return lines


def report_text(
    table: pa.Table,
    sections: list[str],
    *,
    config_text: str | None = None,
    times: dict | None = None,
    command_s: float | None = None,
    title: str = "loopid report",
) -> str:
    """The Markdown of ``report.md``: the common header (module docstring), then ``sections``."""
    import jax

    now = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    L = [
        f"# {title}",
        "",
        f"loopid {loopid.__version__}, {now}; {table.num_rows} rows from `results.parquet`; "
        f"figure: `figure.png`.",
        "",
        "![figure](figure.png)",
        "",
        "## Configuration",
        "",
    ]
    if config_text is None:
        L += ["(no `config.toml` next to the table)", ""]
    else:
        L += ["```toml", config_text.strip(), "```", ""]
    L += ["## Wall time", ""]
    machine = (
        f"{platform.machine()}, {os.cpu_count()} CPUs, JAX {jax.__version__} on "
        f"{backend.describe()}"
    )
    if command_s is not None:
        L.append(f"- this command: {command_s:.1f} s ({machine})")
    if times:
        wall = sum(t[0] for t in times.values())
        first = sum(t[1] for t in times.values())
        saving = sum(t[2] for t in times.values())
        L += [
            f"- cells: {len(times)}, {wall:.1f} s in all as recorded by each cell "
            f"(cells skipped on resume keep the time of the run that computed them; cells "
            f"computed by parallel workers overlap, so the sum can exceed the command's time)",
            f"- of which until each cell's iteration 2 (compilation, or loading it from the "
            f"cache, plus two iterations): {first:.1f} s; after it: {wall - first:.1f} s",
            f"- saving the cells' final policies and models (`cells/*.npz`): {saving:.1f} s",
        ]
        line = programs_line(times)
        if line is not None:
            L.append(line)
    L.append("")
    L += sections
    if L[-1] != "":
        L.append("")
    return "\n".join(L)
