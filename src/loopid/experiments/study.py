"""The reading study (``loopid study``): every reading of the paper's open details.

The paper leaves some details of its experiments open; each defensible reading is a scenario
field (``delay_mode``, ``nu_pending``, ``funnel_nominal``, ``pads``, ``pg_samples``;
:mod:`loopid.experiments.readings`). A :class:`Reading` changes fields of the paper's panels
(:data:`SCENARIOS`, the preset ``probable``) and names the panels and methods whose results the
change can touch. The study runs each reading one factor at a time from ``probable``, and the
preset ``literal`` as a whole. It is one run directory
(:func:`loopid.experiments.execute.run_cells`: resume, atomic cells, workers, Ray) holding, for
every reading, exactly those cells, as the scenario ``PANEL-ID`` (the default reading's
scenarios keep the panels' names); every other cell of a reading is the default's or a part's,
which is the same computation (a method whose inputs the field does not reach). The default
reading is the run of ``loopid reproduce`` itself: ``--reproduce DIR`` copies that run's
finished cells of the same configuration (:func:`share_cells`) instead of computing them again.

Why a method is untouched by a field (the cells a reading inherits):

- ``delay_mode``: the expert L and the policy gradient fly fixed gains, for which ``fifo`` and
  ``latency`` are the same closed loop (the test cost's ``ΔuᵀRΔu`` term sums commanded changes
  under ``fifo`` and applied ones under ``latency``: equal to ~1e-12 relative; the policy
  gradient's own training rollouts are FIFO rollouts of that closed loop);
- ``nu_pending`` (used under ``fifo`` only, so its readings also set ``delay_mode = fifo``):
  only ν queries change: L and PG draw none; under ``rollout`` ν_t is queried as under
  ``hold``, so D_t and B_t are the ``fifo`` reading's;
- ``funnel_nominal``: the expert is iLQR on the true simulator (no nominal);
- ``pg_samples``: only the policy gradient.

The ``literal`` reading takes each cell from the one-factor reading that changes it (``fifo``,
``spec``, ``pg-transitions``), which is exact because those parts touch disjoint cells, except
the funnel's policy gradient, which two of its fields reach, and which it runs itself.

Outputs in ``OUT``, besides the run directory's own files: ``study.parquet`` (every reading's
table, each panel under its own name, with the columns ``reading`` and the reading fields),
``study.md`` (per reading: final medians per panel and method, the paper's five findings
computed from the table, and for the funnel each nominal's one-step prediction error along the
expert's flight) and one figure per figure group (``study_delay.png``, ``study_funnel.png``,
``study_pg.png``, ``study_literal.png``, in the layout of Figure 2).
"""

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from loopid.algorithms.methods import LEARNING_METHODS, METHODS
from loopid.experiments.config import seeds_from_value
from loopid.experiments.readings import DEFAULT_PRESET, PRESETS, READING_FIELDS, reading_text
from loopid.experiments.results import concat, write_atomic_bytes
from loopid.experiments.scenarios import SCENARIOS, Scenario


class Reading(NamedTuple):
    """One reading: ``id`` (a directory name), ``figure`` (which ``study_FIGURE.png`` draws it),
    ``label``, the field ``changes`` away from the default, the ``panels`` (scenario names) its
    table covers, the ``methods`` whose cells it runs (on ``runs_on`` panels; None: all of
    ``panels``), and ``parts``: ids of readings whose cells it takes where it runs none of its
    own (a combination, or a reading whose other cells equal another reading's)."""

    id: str
    figure: str
    label: str
    changes: dict
    panels: tuple[str, ...]
    methods: tuple[str, ...]
    parts: tuple[str, ...] = ()
    runs_on: tuple[str, ...] | None = None

    def runs(self, panel: str, method: str) -> bool:
        """Whether this reading computes the cell (``panel``, ``method``) itself."""
        return method in self.methods and panel in (self.runs_on or self.panels)


ALL_PANELS = tuple(SCENARIOS)
NU_E_METHODS = ("dagger-e", "dagger-en", "batch-e", "batch-en", "abbeel")
FIFO = {"delay_mode": "fifo"}

READINGS: tuple[Reading, ...] = (
    Reading("probable", "default", "probable (the default)", {}, ALL_PANELS, METHODS),
    Reading(
        "literal", "literal", "delay_mode = fifo, funnel_nominal = spec, "
        "pg_samples = transitions", dict(PRESETS["literal"]), ALL_PANELS, ("pg",),
        parts=("fifo", "spec", "pg-transitions"), runs_on=("funnel",),
    ),
    Reading(
        "fifo", "delay", "delay_mode = fifo", FIFO, ("hover-delay",), LEARNING_METHODS,
    ),
    Reading(
        "nu-zero", "delay", "delay_mode = fifo, nu_pending = zero",
        {**FIFO, "nu_pending": "zero"}, ("hover-delay",), LEARNING_METHODS,
    ),
    Reading(
        "nu-rollout", "delay", "delay_mode = fifo, nu_pending = rollout",
        {**FIFO, "nu_pending": "rollout"}, ("hover-delay",), NU_E_METHODS, parts=("fifo",),
    ),
    Reading(
        "spec", "funnel", "funnel_nominal = spec", {"funnel_nominal": "spec"},
        ("funnel",), (*LEARNING_METHODS, "pg"),
    ),
    Reading(
        "no-increment", "funnel", "funnel_nominal = no-increment",
        {"funnel_nominal": "no-increment"}, ("funnel",), (*LEARNING_METHODS, "pg"),
    ),
    Reading(
        "drift", "funnel", "funnel_nominal = drift", {"funnel_nominal": "drift"},
        ("funnel",), (*LEARNING_METHODS, "pg"),
    ),
    Reading("no-pads", "funnel", "pads = false", {"pads": False}, ("funnel",), METHODS),
    Reading(
        "pg-transitions", "pg", "pg_samples = transitions", {"pg_samples": "transitions"},
        ALL_PANELS, ("pg",),
    ),
    Reading(
        "pg-descent", "pg", "pg_update = descent", {"pg_update": "descent"}, ALL_PANELS, ("pg",),
    ),
)  # fmt: skip
BY_ID = {r.id: r for r in READINGS}
FIGURES = ("delay", "funnel", "pg", "literal")
DEFAULT = DEFAULT_PRESET  # the default reading is the default preset, run by reproduce


def scenario_name(r: Reading, panel: str) -> str:
    """The run's scenario for reading ``r`` on ``panel``: the panel's own name for the default
    (the name ``reproduce`` uses, so its cells can be shared), ``PANEL-ID`` otherwise."""
    return panel if r.id == DEFAULT else f"{panel}-{r.id}"


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


def source(r: Reading, panel: str, method: str) -> Reading:
    """The reading whose cell (``panel``, ``method``) reading ``r`` shows: its own, else the
    first of its parts that computes it, else the default's."""
    for candidate in (r, *(BY_ID[i] for i in r.parts)):
        if candidate.runs(panel, method):
            return candidate
    return BY_ID[DEFAULT]


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


def reading_table(r: Reading, table: pa.Table, base: dict[str, Scenario]) -> pa.Table:
    """Reading ``r``'s full table on its panels: each (panel, method) cell from the reading (or
    the part of a combination) that computed it, else the default's, with the scenario named
    after the panel and the columns ``reading`` and the reading fields' values (strings)."""
    pieces = []
    for panel in r.panels:
        s = base[panel].replace(**r.changes)
        for method in METHODS:
            piece = _relabel(table, scenario_name(source(r, panel, method), panel), panel)
            piece = piece.filter(pc.equal(piece["method"], method))
            n = piece.num_rows
            piece = piece.append_column("reading", pa.array([r.id] * n, pa.string()))
            for f in READING_FIELDS:
                text = reading_text(getattr(s, f))
                piece = piece.append_column(f, pa.array([text] * n, pa.string()))
            pieces.append(piece)
    return concat(pieces)


def study_table(table: pa.Table, base: dict[str, Scenario]) -> pa.Table:
    """Every reading's table (:func:`reading_table`) from the study run's ``results.parquet``."""
    return concat([reading_table(r, table, base) for r in READINGS])


# ----------------------------------------------------------------------------- outputs


def _cells(table: pa.Table, panel: str, method: str) -> pa.Table:
    mask = pc.and_(pc.equal(table["scenario"], panel), pc.equal(table["method"], method))
    return table.filter(mask)


def _subtable(table: pa.Table, reading: str) -> pa.Table:
    return table.filter(pc.equal(table["reading"], reading))


def _g(x: float) -> str:
    return f"{x:.3g}"


def medians(table: pa.Table) -> dict[tuple[str, str], float]:
    """``{(panel, method): median over seeds of the final test cost}`` of one reading."""
    from loopid.experiments.findings import Costs

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
    """The paper's five findings (:func:`loopid.experiments.findings.findings`) on reading
    ``r``'s panels, each holds / does not hold."""
    from loopid.experiments.findings import findings

    hover = {p for p in r.panels if base[p].task in ("hover", "hover-delay")}
    sub = _subtable(table, r.id)
    sub = sub.filter(pc.is_in(sub["scenario"], pa.array(list(r.panels), pa.string())))
    return findings(sub, hover)


def figures(table: pa.Table, out: Path) -> list[Path]:
    """One figure per group of readings, in the layout of Figure 2 (a panel per reading)."""
    from loopid.experiments.plots import figure

    paths = []
    for group in FIGURES:
        rs = [r for r in READINGS if r.figure == group]
        if group in ("delay", "funnel"):
            panel = rs[0].panels[0]
            rs = [BY_ID[DEFAULT], *rs]
            pieces = [
                _relabel(_subtable(table, r.id), panel, f"{panel}: {r.label}")
                for r in rs
                if _subtable(table, r.id).num_rows
            ]
        elif group == "pg":
            pieces = []
            for p in ALL_PANELS:
                default = _subtable(table, DEFAULT)
                keep = [_cells(default, p, m) for m in ("expert", "pg")]
                for r in rs:
                    other = _cells(_subtable(table, r.id), p, "pg")
                    name = f"pg ({r.label.split(' = ')[-1]})"
                    other = other.set_column(
                        other.schema.get_field_index("method"),
                        "method",
                        pa.array([name] * other.num_rows, pa.string()),
                    )
                    keep.append(other)
                pieces.append(_relabel(concat(keep), p, p))
        else:
            sub = _subtable(table, rs[0].id)
            pieces = [_relabel(sub, p, f"{p}: literal readings") for p in ALL_PANELS]
        pieces = [pc_ for pc_ in pieces if pc_.num_rows]
        if not pieces:
            continue
        plain = concat([p.select(list(read_cols(p))) for p in pieces])
        paths.append(figure(plain, out / f"study_{group}.png"))
    return paths


def read_cols(t: pa.Table) -> list[str]:
    """The result columns a figure reads (the reading columns dropped)."""
    return [c for c in t.column_names if c not in ("reading", *READING_FIELDS)]


def _relabel(t: pa.Table, panel: str, title: str) -> pa.Table:
    """Rows of ``panel`` in ``t`` with the scenario renamed ``title`` (the figure's panel)."""
    t = t.filter(pc.equal(t["scenario"], panel))
    i = t.schema.get_field_index("scenario")
    return t.set_column(i, "scenario", pa.array([title] * t.num_rows, pa.string()))


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
        "others are the default's or another reading's (see `loopid.experiments.study`). "
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
    L += ["## The paper's findings under each reading", ""]
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
SPEC_PREDICTION = {"spec": 0.49, "no-increment": 0.47, "drift": 0.31, "heading": 0.09}
SPEC_TRUE_STEP = 0.18


def funnel_prediction_lines(s: Scenario) -> list[str]:
    """``study.md`` lines: each funnel nominal's one-step prediction error along the expert's
    flight (:func:`loopid.systems.funnel_nominal.prediction_errors`: velocity RMS, 10 noisy
    flights), on the whole target and on the circles, next to an independent computation's."""
    from loopid.experiments.families.helicopter import setup
    from loopid.systems.funnel_nominal import FUNNEL_NOMINALS, funnel_nominal, prediction_errors

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
            f"{SPEC_PREDICTION[kind]:.2f} |"
        )
    whole, on_circles = rows[0][1], rows[0][2]
    lines += [
        f"| true step | {whole.true_step:.3f} | {on_circles.true_step:.3f} | "
        f"{SPEC_TRUE_STEP:.2f} |",
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
