"""The readings of the reading study (``loopid study``): which fields each changes, which
cells it computes itself, and its table.

A :class:`Reading` changes fields of the paper's panels (:data:`SCENARIOS`, the preset
``probable``) and names the panels and methods whose results the change can touch; every other
cell of a reading is the default's or a part's, which is the same computation (a method whose
inputs the field does not reach). In the study's run directory a reading's cells are the
scenario ``PANEL-ID`` (:func:`scenario_name`; the default reading's keep the panels' names);
:func:`reading_table` gathers a reading's full table from them.

Why a method is untouched by a field (the cells a reading inherits):

- ``delay_mode``: the expert L and the policy gradient fly fixed gains, for which ``fifo`` and
  ``latency`` are the same closed loop (the test cost's ``ΔuᵀRΔu`` term sums commanded changes
  under ``fifo`` and applied ones under ``latency``: equal to ~1e-12 relative; the policy
  gradient's own training rollouts are FIFO rollouts of that closed loop);
- ``nu_pending`` (used under ``fifo`` only, so its readings also set ``delay_mode = fifo``):
  only ν queries change: L and PG draw none; under ``rollout`` ν_t is queried as under
  ``hold``, so D_t and B_t are the ``fifo`` reading's;
- ``funnel_nominal``: the expert is iLQR on the true simulator (no nominal);
- ``pg_samples``, ``pg_update``: only the policy gradient;
- ``nu_t_center``: only ν_t's draws, so only D_t and B_t. On hover ``trim`` is ``target`` bit
  for bit (the hover target holds the trim controls), so ``nu-t-trim`` runs the funnel alone and
  takes the hover panels from ``nu-t-target``.

The ``literal`` reading takes each cell from the one-factor reading that changes it (``fifo``,
``spec``), which is exact because those parts touch disjoint cells, except the cells that two of
its fields reach, which it runs itself on every panel: the policy gradient (``pg_samples`` and
``pg_update``), and D_t and B_t (``nu_t_center`` with ``delay_mode`` or ``funnel_nominal``; on
hover only ``nu_t_center`` reaches them, and those two cells repeat ``nu-t-target``'s).
"""

from typing import NamedTuple

import pyarrow as pa
import pyarrow.compute as pc

from loopid.experiments.families.helicopter.methods import LEARNING_METHODS, METHODS
from loopid.experiments.families.helicopter.readings import (
    DEFAULT_PRESET,
    PRESETS,
    READING_FIELDS,
    reading_text,
)
from loopid.experiments.families.helicopter.scenario import SCENARIOS, Scenario
from loopid.experiments.results import concat


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
NU_T_METHODS = ("dagger-t", "batch-t")
FIFO = {"delay_mode": "fifo"}

READINGS: tuple[Reading, ...] = (
    Reading("probable", "default", "probable (the default)", {}, ALL_PANELS, METHODS),
    Reading(
        "literal", "literal", "delay_mode = fifo, funnel_nominal = spec, "
        "pg_samples = transitions, pg_update = conservative, nu_t_center = target",
        dict(PRESETS["literal"]), ALL_PANELS, ("pg", *NU_T_METHODS),
        parts=("fifo", "spec"),
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
        "pg-conservative", "pg", "pg_update = conservative", {"pg_update": "conservative"},
        ALL_PANELS, ("pg",),
    ),
    Reading(
        "nu-t-target", "nu-t", "nu_t_center = target", {"nu_t_center": "target"}, ALL_PANELS,
        NU_T_METHODS,
    ),
    Reading(
        "nu-t-trim", "nu-t", "nu_t_center = trim", {"nu_t_center": "trim"}, ALL_PANELS,
        NU_T_METHODS, parts=("nu-t-target",), runs_on=("funnel",),
    ),
)  # fmt: skip
BY_ID = {r.id: r for r in READINGS}
FIGURES = ("delay", "funnel", "pg", "nu-t", "literal")
DEFAULT = DEFAULT_PRESET  # the default reading is the default preset, run by reproduce


def scenario_name(r: Reading, panel: str) -> str:
    """The run's scenario for reading ``r`` on ``panel``: the panel's own name for the default
    (the name ``reproduce`` uses, so its cells can be shared), ``PANEL-ID`` otherwise."""
    return panel if r.id == DEFAULT else f"{panel}-{r.id}"


def source(r: Reading, panel: str, method: str) -> Reading:
    """The reading whose cell (``panel``, ``method``) reading ``r`` shows: its own, else the
    first of its parts that computes it, else the default's."""
    for candidate in (r, *(BY_ID[i] for i in r.parts)):
        if candidate.runs(panel, method):
            return candidate
    return BY_ID[DEFAULT]


def reading_table(r: Reading, table: pa.Table, base: dict[str, Scenario]) -> pa.Table:
    """Reading ``r``'s full table on its panels: each (panel, method) cell from the reading (or
    the part of a combination) that computed it, else the default's, with the scenario named
    after the panel and the columns ``reading`` and the reading fields' values (strings)."""
    pieces = []
    for panel in r.panels:
        s = base[panel].replace(**r.changes)
        for method in METHODS:
            piece = relabel(table, scenario_name(source(r, panel, method), panel), panel)
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


def relabel(t: pa.Table, panel: str, title: str) -> pa.Table:
    """Rows of ``panel`` in ``t`` with the scenario renamed ``title`` (the figure's panel)."""
    t = t.filter(pc.equal(t["scenario"], panel))
    i = t.schema.get_field_index("scenario")
    return t.set_column(i, "scenario", pa.array([title] * t.num_rows, pa.string()))
