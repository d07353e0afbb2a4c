"""The reading study's outputs, from its table: ``study.md`` and one figure per group.

Outputs in ``OUT``, besides the run directory's own files: ``study.parquet`` (every reading's
table, each panel under its own name, with the columns ``reading`` and the reading fields),
``study.md`` (per reading: final medians per panel and method, the paper's five findings
computed from the table, and for the funnel each nominal's one-step prediction error along the
expert's flight) and one figure per figure group (``study_delay.png``, ``study_funnel.png``,
``study_pg.png``, ``study_nu-t.png``, ``study_literal.png``, in the layout of Figure 2).
"""

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from loopid.experiments.families.helicopter.methods import METHODS
from loopid.experiments.families.helicopter.readings import (
    DEFAULT_PRESET,
    PRESETS,
    READING_FIELDS,
    reading_text,
)
from loopid.experiments.families.helicopter.scenario import Scenario
from loopid.experiments.paired import VERDICT_WORDS
from loopid.experiments.results import concat
from loopid.files import write_atomic_bytes
from loopid.paper.study_readings import (
    ALL_PANELS,
    BY_ID,
    DEFAULT,
    FIGURES,
    READINGS,
    Reading,
    relabel,
)


def _cells(table: pa.Table, panel: str, method: str) -> pa.Table:
    mask = pc.and_(pc.equal(table["scenario"], panel), pc.equal(table["method"], method))
    return table.filter(mask)


def _subtable(table: pa.Table, reading: str) -> pa.Table:
    return table.filter(pc.equal(table["reading"], reading))


def _g(x: float) -> str:
    return f"{x:.3g}"


def medians(table: pa.Table) -> dict[tuple[str, str], float]:
    """``{(panel, method): median over seeds of the final test cost}`` of one reading."""
    from loopid.experiments.final_costs import Costs

    c = Costs(table)
    return {
        (s, m): float(np.median(c.at(s, m))) for s in c.scenarios for m in c.methods if c.has(s, m)
    }


ABBREV = {
    "expert": "L", "dagger-t": "D_t", "dagger-e": "D_e", "dagger-en": "D_en", "batch-t": "B_t",
    "batch-e": "B_e", "batch-en": "B_en", "abbeel": "A", "pg": "PG",
}  # fmt: skip


def medians_table(table: pa.Table) -> list[str]:
    """Markdown: reading × panel rows, a column per method, final medians over seeds."""
    order = ["expert", *[m for m in METHODS if m != "expert"]]
    lines = [
        "| reading | panel | " + " | ".join(ABBREV[m] for m in order) + " |",
        "|---|---|" + "---|" * len(order),
    ]
    for r in READINGS:
        sub = _subtable(table, r.id)
        if sub.num_rows == 0:
            continue
        med = medians(sub)
        for p in r.panels:
            cells = [_g(med[(p, m)]) if (p, m) in med else "" for m in order]
            lines.append(f"| {r.id} | {p} | " + " | ".join(cells) + " |")
    return lines


def reading_findings(table: pa.Table, r: Reading, base: dict[str, Scenario]) -> list:
    """The paper's five findings (:func:`loopid.experiments.families.helicopter.findings.findings`)
    on reading ``r``'s panels, each with its verdict (:func:`loopid.experiments.paired.combine`)."""
    from loopid.experiments.families.helicopter.findings import findings

    hover = {p for p in r.panels if base[p].task in ("hover", "hover-delay")}
    sub = _subtable(table, r.id)
    sub = sub.filter(pc.is_in(sub["scenario"], pa.array(list(r.panels), pa.string())))
    return findings(sub, hover)


#: The figures that draw one set of methods under each reading beside the default's.
SWEPT_METHODS = {"pg": ("pg",), "nu-t": ("dagger-t", "batch-t")}


def figures(table: pa.Table, out: Path) -> list[Path]:
    """One figure per group of readings, in the layout of Figure 2 (a panel per reading)."""
    from loopid.experiments.families.helicopter.report import figure

    paths = []
    for group in FIGURES:
        rs = [r for r in READINGS if r.figure == group]
        if group in ("delay", "funnel"):
            panel = rs[0].panels[0]
            rs = [BY_ID[DEFAULT], *rs]
            pieces = [
                relabel(_subtable(table, r.id), panel, f"{panel}: {r.label}")
                for r in rs
                if _subtable(table, r.id).num_rows
            ]
        elif group in SWEPT_METHODS:  # the default's curves beside each reading's
            methods = SWEPT_METHODS[group]
            default = _subtable(table, DEFAULT)
            pieces = []
            for p in ALL_PANELS:
                keep = [_cells(default, p, m) for m in ("expert", *methods)]
                for r in rs:
                    for m in methods:
                        other = _cells(_subtable(table, r.id), p, m)
                        name = f"{m} ({r.label.split(' = ')[-1]})"
                        other = other.set_column(
                            other.schema.get_field_index("method"),
                            "method",
                            pa.array([name] * other.num_rows, pa.string()),
                        )
                        keep.append(other)
                pieces.append(relabel(concat(keep), p, p))
        else:
            sub = _subtable(table, rs[0].id)
            pieces = [relabel(sub, p, f"{p}: literal readings") for p in ALL_PANELS]
        pieces = [pc_ for pc_ in pieces if pc_.num_rows]
        if not pieces:
            continue
        plain = concat([p.select(list(read_cols(p))) for p in pieces])
        paths.append(figure(plain, out / f"study_{group}.png"))
    return paths


def read_cols(t: pa.Table) -> list[str]:
    """The result columns a figure reads (the reading columns dropped)."""
    return [c for c in t.column_names if c not in ("reading", *READING_FIELDS)]


def study_text(
    table: pa.Table,
    base: dict[str, Scenario],
    *,
    command_s: float | None,
    seeds: int,
    cells_s: tuple[int, float] | None = None,
    prediction: list[str] | None = None,
) -> str:
    """The Markdown of ``study.md``."""
    from loopid.experiments import backend

    L = [
        "# loopid reading study",
        "",
        "Every reading of the details the paper leaves open, one factor at a time from the "
        "default preset `probable`, and the preset `literal` (the literal readings of the "
        "paper's text) as a whole. Each reading runs only the cells its fields can change; the "
        "others are the default's or another reading's (see "
        "`loopid.paper.study`). "
        "Medians over seeds of the test cost at each method's final iteration; "
        f"{seeds} seeds. 1e8 is the cost cap (diverged).",
        "",
        "The `samples` column (and a figure's x axis) counts transitions, except for the "
        "policy gradient under `pg_samples = rollouts` (the default), where it counts rollouts "
        "(one perturbed-gain rollout of the task horizon per sample).",
        "",
    ]
    if command_s is not None:
        line = (
            f"Wall time of this command: {command_s:.0f} s ({backend.describe()}, {_cpus()} CPUs)."
        )
        if cells_s is not None:
            line += (
                f" Its {cells_s[0]} cells took {cells_s[1]:.0f} s in all as each recorded it "
                "(cells shared or finished by an earlier, resumed run keep the time of the run "
                "that computed them; cells computed by parallel workers overlap)."
            )
        L += [line, ""]
    L += ["## Final medians", "", *medians_table(table), ""]
    L += ["## The paper's findings under each reading", "", VERDICT_WORDS, ""]
    L += [
        "| reading | panels | 1 D < B | 2 D good, one B | 3 D < L (hover) | 4 A plateau | "
        "5 PG little |",
        "|---|---|---|---|---|---|---|",
    ]
    found = {
        r.id: reading_findings(table, r, base) for r in READINGS if _subtable(table, r.id).num_rows
    }
    for r in READINGS:
        if r.id in found:
            verdicts = [f.verdict for f in found[r.id]]
            L.append(f"| {r.id} | {', '.join(r.panels)} | " + " | ".join(verdicts) + " |")
            if len(r.panels) > 1:  # a reading of several panels: each panel alone too
                for p in r.panels:
                    one = reading_findings(table, r._replace(panels=(p,)), base)
                    verdicts = [f.verdict for f in one]
                    L.append(f"| {r.id} | {p} | " + " | ".join(verdicts) + " |")
    L.append("")
    for r in READINGS:
        if r.id not in found:
            continue
        changed = {k: v for k, v in r.changes.items() if PRESETS[DEFAULT_PRESET].get(k) != v}
        changes = ", ".join(f"`{k} = {reading_text(v)}`" for k, v in changed.items()) or "none"
        L += [
            f"### {r.id}: {r.label}",
            "",
            f"Changes from `probable`: {changes}; panels: {', '.join(r.panels)}; "
            f"cells run: {_runs(r)}.",
            "",
        ]
        for f in found[r.id]:
            L.append(f"{f.number}. {f.claim} **{f.verdict}** (on means: {f.mean_verdict})")
            L += [f"   - {d}" for d in f.details]
        L.append("")
    if prediction:
        L += [
            "## The funnel's nominal models along the expert's flight",
            "",
            *prediction,
        ]
    return "\n".join(L) + "\n"


def _runs(r: Reading) -> str:
    """What reading ``r`` computes itself, and where its other cells come from."""
    own = f"{', '.join(r.methods)}" + (f" on {', '.join(r.runs_on)}" if r.runs_on else "")
    if not r.methods:
        own = "none"
    if r.parts:
        own += f"; the rest from {', '.join(r.parts)} where they change it"
    return own


#: An independent computation's figures (made before the study, to check against): one-step
#: velocity RMS along the expert's flight.
INDEPENDENT_PREDICTION = {"spec": 0.49, "no-increment": 0.47, "drift": 0.31, "heading": 0.09}
INDEPENDENT_TRUE_STEP = 0.18


def funnel_prediction_lines(s: Scenario) -> list[str]:
    """``study.md`` lines: each funnel nominal's one-step prediction error along the expert's
    flight (:func:`loopid.systems.helicopter.funnel_nominal.prediction_errors`: velocity RMS, 10
    noisy flights), on the whole target and on the circles, next to an independent computation's."""
    from loopid.experiments.families.helicopter import setup
    from loopid.systems.helicopter.funnel_nominal import (
        FUNNEL_NOMINALS,
        funnel_nominal,
        prediction_errors,
    )

    st = setup(s)
    task = st.plant.task
    circles = slice(100, 499) if s.pads else None
    rows = []
    for kind in FUNNEL_NOMINALS:
        model = funnel_nominal(kind, task)
        whole = prediction_errors(model, task, st.K_expert)
        on_circles = prediction_errors(model, task, st.K_expert, steps=circles)
        rows.append((kind, whole, on_circles))
    lines = [
        "RMS over the velocity entries of the one-step prediction error, the expert flying the "
        f"funnel (pads = {reading_text(s.pads)}, noise std {task.noise_std:g}, 10 flights); "
        "`true step`: the RMS of the velocity's own change in one step.",
        "",
        "| nominal | whole flight | circles only | an independent computation |",
        "|---|---|---|---|",
    ]
    for kind, whole, on_circles in rows:
        lines.append(
            f"| {kind} | {whole.prediction:.3f} | {on_circles.prediction:.3f} | "
            f"{INDEPENDENT_PREDICTION[kind]:.2f} |"
        )
    whole, on_circles = rows[0][1], rows[0][2]
    lines += [
        f"| true step | {whole.true_step:.3f} | {on_circles.true_step:.3f} | "
        f"{INDEPENDENT_TRUE_STEP:.2f} |",
        "",
    ]
    return lines


def _cpus() -> int:
    import os

    return os.cpu_count() or 1


def write_outputs(
    out: Path, table: pa.Table, base: dict[str, Scenario], *, command_s=None, prediction=None
) -> None:
    """``study.md`` and the figures from the study's table; ``study.md`` also gives the time
    the study's cells recorded (:func:`loopid.experiments.report.cell_times`)."""
    from loopid.experiments.report import cell_times

    out = Path(out)
    times = cell_times(out)
    cells_s = (len(times), sum(t[0] for t in times.values())) if times else None
    seeds = len(np.unique(np.asarray(table["seed"])))
    figures(table, out)
    text = study_text(
        table, base, command_s=command_s, seeds=seeds, prediction=prediction, cells_s=cells_s
    )
    write_atomic_bytes(text.encode(), out / "study.md")


def load(out: Path) -> pa.Table:
    """The study's ``study.parquet`` (its reading columns are strings, so it is read as it is
    rather than through :func:`loopid.experiments.results.read_table`)."""
    import pyarrow.parquet as pq

    return pq.read_table(Path(out) / "study.parquet")
