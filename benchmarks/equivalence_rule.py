"""A ``loopid reproduce`` run against a reference run: the equivalence rule an engine change that
may move bits is held to.

The rule compares the new run's tables with the reference's (a 20-seed ``loopid reproduce`` run
directory: ``results.parquet``, the helicopter's Figure 2 table, and ``mdp/results.parquet``,
the finite-MDP study's). The new run is *equivalent* when every clause holds:

1. in every (scenario, method) cell where no seed has a diverged test trajectory, the final
   median equal to :data:`RTOL_MEDIAN` (5e-4) relative;
2. in every other cell, the count of seeds with a diverged trajectory within ±1
   (:data:`DIVERGED_SLACK`) of the reference's, and the final median on the same side of "good"
   (at most :data:`~loopid.experiments.families.helicopter.findings.GOOD_FACTOR` = 2 × L);
3. the paper's findings' verdicts the same, on medians and on means;
4. the MDP table equal to :data:`RTOL_MDP` (1e-12) relative.

How each word is read here (the same readings as the reports',
:class:`loopid.experiments.final_costs.Costs`):

- **final**: each (scenario, method) cell's last iteration, its largest ``iteration`` (the
  panels run for different numbers of iterations);
- **a seed has a diverged trajectory** when its ``diverged`` column (the count of its test
  trajectories that hit the cost cap or a non-finite state) is above 0 at that final iteration.
  A cell goes to clause 2 when any seed has one *in the reference or in the new table*: a cell
  that starts (or stops) diverging is judged by the clause made for diverging cells, whose count
  check then bounds how many seeds may do so;
- **median**: the median over seeds of ``test_cost`` at the final iteration; in clause 1 the
  relative change is ``|new − reference| / |reference|`` (NaN equal to NaN, an infinity equal to
  itself only);
- **the count within ±1**: the number of the cell's seeds (20 in the reference) with a diverged
  trajectory, at most one above or below the reference's number;
- **L**: the median over seeds of the ``expert`` method's final ``test_cost`` in the same
  scenario, each table's own (as its report's findings read it); the expert's own cell is then
  judged by clause 1 or 2 like any other;
- **good**: a final median at most 2 × L (the findings' :data:`GOOD_FACTOR`); "the same side"
  means good in both tables or in neither;
- **the findings' verdicts**: :func:`loopid.experiments.families.helicopter.findings.findings`
  on each whole table, with the hover panels the report passes it (the scenarios whose task is a
  hover: from the reference run's ``config.toml``, else the packaged scenarios of those names);
  each :class:`~loopid.experiments.families.helicopter.findings.Finding`'s ``verdict`` and
  ``mean_verdict`` equal, finding by finding (``number``);
- **the MDP table equal**: the same rows in the same order; every float column of the reference
  to :data:`RTOL_MDP` relative, ``|new − reference| <= 1e-12 |reference| + 1e-300``
  (:data:`ATOL_MDP`, a floor for zeros), NaN equal to NaN and an infinity equal to itself only;
  every other column exactly. The reference's columns must be present with their types;
  columns only the new table has are listed in the report and not compared.

Besides the clauses, the cells must match: every cell of either table in the other, with the
same final iteration and the same seeds there (else the medians would not be like for like).

:func:`check` (run directories) and :func:`check_tables` (tables: synthetic ones in the tests)
list the failures, one line per failed clause naming the cell (or finding, or column), both
values and the tolerance; an empty list means equivalent. :func:`evaluate` and
:func:`evaluate_tables` return everything compared (:class:`Result`), and :func:`report` renders
it cell by cell for the CHANGELOG: each cell's clause and outcome, and which medians moved and
by how much. ``benchmarks/equivalence.py`` is the command line (it imports this module as its
sibling, ``import equivalence_rule``); ``tests/test_equivalence_rule.py`` checks the rule
(``from benchmarks import equivalence_rule``: pytest puts the repository root on ``sys.path``).
"""

import math
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from loopid.experiments.families.helicopter.findings import GOOD_FACTOR

#: Clause 1: a final median's relative change in a cell without diverged seeds.
RTOL_MEDIAN = 5e-4
#: Clause 2: how far the count of diverged seeds may move.
DIVERGED_SLACK = 1
#: Clause 4: the MDP table's float columns, relative, with an absolute floor for zeros.
RTOL_MDP = 1e-12
ATOL_MDP = 1e-300
#: The method whose final median is a panel's L.
EXPERT = "expert"
#: A cell's clause: no diverged seed in either table (clause 1), or some (clause 2).
SETTLED, DIVERGING = "settled", "diverging"
#: A findings function: ``findings(table, hover_panels)``, a list of objects with ``number``,
#: ``verdict`` and ``mean_verdict``.
FindingsFn = Callable[[pa.Table, set[str]], list]


class Final(NamedTuple):
    """A cell at its final iteration: the ``iteration``, its ``seeds`` (sorted), the ``median``
    test cost over them, and ``diverged``, how many of them have a diverged trajectory."""

    iteration: int
    seeds: tuple[int, ...]
    median: float
    diverged: int


class Cell(NamedTuple):
    """One (scenario, method) cell compared: its ``clause`` (:data:`SETTLED` or
    :data:`DIVERGING`; ``None`` when it is in one table only), its :class:`Final` in each table
    (``None`` where absent), each table's L in its scenario (NaN without an expert), and the
    failed clauses' lines."""

    scenario: str
    method: str
    clause: str | None
    ref: Final | None
    new: Final | None
    ref_L: float
    new_L: float
    failures: tuple[str, ...]

    @property
    def change(self) -> float:
        """The final median's relative change (NaN when the cell is in one table only)."""
        if self.ref is None or self.new is None:
            return math.nan
        return relative_change(self.new.median, self.ref.median)


class Verdict(NamedTuple):
    """One finding's verdicts, on medians and on means, in each table (``None``: absent)."""

    number: int
    ref: str | None
    new: str | None
    ref_mean: str | None
    new_mean: str | None

    @property
    def same(self) -> bool:
        return self.ref == self.new and self.ref_mean == self.new_mean


class Column(NamedTuple):
    """One MDP column compared: ``exact`` (not a float), how many rows differ beyond the
    tolerance (``off``), and the largest relative change over its rows (floats only; 0 when
    every row is equal, inf where a value moved off zero or off a non-finite value)."""

    name: str
    exact: bool
    off: int
    largest: float


class Result(NamedTuple):
    """Everything :func:`evaluate_tables` compared: the ``cells`` (reference order, then the new
    table's own), the findings' ``verdicts``, the MDP ``columns`` (``None``: no MDP table was
    compared), the new MDP table's columns the reference lacks (``extra``), and the
    ``failures``, one line each (empty: equivalent)."""

    cells: list[Cell]
    verdicts: list[Verdict]
    columns: list[Column] | None
    extra: list[str]
    failures: list[str]


def relative_change(new: float, ref: float) -> float:
    """``|new − ref| / |ref|``: 0 when equal (NaN equal to NaN), inf when one is non-finite and
    the other is not the same value, or when ``ref`` is 0 and ``new`` is not."""
    if new == ref or (math.isnan(new) and math.isnan(ref)):
        return 0.0
    if not (math.isfinite(new) and math.isfinite(ref)) or ref == 0:
        return math.inf
    return abs(new - ref) / abs(ref)


def close(new, ref, rtol: float, atol: float = 0.0) -> np.ndarray:
    """Elementwise ``|new − ref| <= rtol |ref| + atol`` (relative to the reference), NaN equal
    to NaN, an infinity equal to itself only."""
    new, ref = np.asarray(new, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    same = (new == ref) | (np.isnan(new) & np.isnan(ref))
    finite = np.isfinite(new) & np.isfinite(ref)
    with np.errstate(invalid="ignore", over="ignore"):
        near = finite & (np.abs(new - ref) <= rtol * np.abs(ref) + atol)
    return same | near


def finals(table: pa.Table) -> dict[tuple[str, str], Final]:
    """Each (scenario, method) cell of a results table at its final iteration, in table
    order."""
    scenario = np.asarray(table["scenario"].to_pylist(), dtype=object)
    method = np.asarray(table["method"].to_pylist(), dtype=object)
    seed = table["seed"].to_numpy()
    iteration = table["iteration"].to_numpy()
    cost = table["test_cost"].to_numpy()
    diverged = table["diverged"].to_numpy()
    out = {}
    for s, m in dict.fromkeys(zip(scenario.tolist(), method.tolist(), strict=True)):
        sel = (scenario == s) & (method == m)
        last = int(iteration[sel].max())
        sel &= iteration == last
        out[(s, m)] = Final(
            last,
            tuple(sorted(int(x) for x in seed[sel])),
            float(np.median(cost[sel])),
            int(np.sum(diverged[sel] > 0)),
        )
    return out


def _L(cells: dict[tuple[str, str], Final], scenario: str, expert: str) -> float:
    f = cells.get((scenario, expert))
    return f.median if f is not None else math.nan


def _good(median: float, L: float) -> bool:
    return median <= GOOD_FACTOR * L


def compare_cells(ref: pa.Table, new: pa.Table, expert: str = EXPERT) -> list[Cell]:
    """Clauses 1 and 2, cell by cell (module docstring), and that the cells match."""
    a, b = finals(ref), finals(new)
    cells = []
    for s, m in dict.fromkeys([*a, *b]):
        r, n = a.get((s, m)), b.get((s, m))
        rL, nL = _L(a, s, expert), _L(b, s, expert)
        name = f"{s} {m}"
        if r is None or n is None:
            where = "the reference" if r is not None else "the new table"
            cells.append(Cell(s, m, None, r, n, rL, nL, (f"{name}: only in {where}",)))
            continue
        fails = []
        if n.iteration != r.iteration:
            fails.append(f"{name}: final iteration {n.iteration}, reference {r.iteration}")
        if n.seeds != r.seeds:
            fails.append(
                f"{name}: seeds at the final iteration {list(n.seeds)}, reference {list(r.seeds)}"
            )
        if r.diverged == 0 and n.diverged == 0:
            clause = SETTLED
            change = relative_change(n.median, r.median)
            if not close(n.median, r.median, RTOL_MEDIAN):
                fails.append(
                    f"{name} (no diverged seed): final median {n.median!r}, reference "
                    f"{r.median!r}: relative change {change:.3g} > {RTOL_MEDIAN:g}"
                )
        else:
            clause = DIVERGING
            if abs(n.diverged - r.diverged) > DIVERGED_SLACK:
                fails.append(
                    f"{name}: {n.diverged} seeds with a diverged trajectory, reference "
                    f"{r.diverged} (within ±{DIVERGED_SLACK})"
                )
            if math.isnan(rL) or math.isnan(nL):
                fails.append(f"{name}: no {expert!r} cell in {s}, so no L to judge 'good' by")
            elif _good(n.median, nL) != _good(r.median, rL):
                fails.append(
                    f"{name}: final median {n.median!r} "
                    f"{'<=' if _good(n.median, nL) else '>'} {GOOD_FACTOR:g} L = "
                    f"{GOOD_FACTOR * nL!r}, reference {r.median!r} "
                    f"{'<=' if _good(r.median, rL) else '>'} {GOOD_FACTOR:g} L = "
                    f"{GOOD_FACTOR * rL!r} (the same side of good)"
                )
        cells.append(Cell(s, m, clause, r, n, rL, nL, tuple(fails)))
    return cells


def packaged_hover_panels(scenarios: Iterable[str]) -> set[str]:
    """Of ``scenarios``, those that are packaged helicopter panels whose task is a hover."""
    from loopid.experiments.families.helicopter.scenario import SCENARIOS
    from loopid.systems.helicopter.tasks import is_hover

    return {s for s in scenarios if s in SCENARIOS and is_hover(SCENARIOS[s].task)}


def run_hover_panels(run_dir) -> set[str] | None:
    """The hover panels of a run directory as its report reads them (its ``config.toml``'s
    scenarios whose task is a hover); ``None`` without a ``config.toml``."""
    from loopid.experiments.execute import run_family
    from loopid.systems.helicopter.tasks import is_hover

    family, configs = run_family(run_dir)
    if family is None:
        return None
    return {name for name, s in configs.items() if is_hover(s.task)}


def compare_findings(
    ref: pa.Table,
    new: pa.Table,
    hover_panels: set[str] | None = None,
    findings: FindingsFn | None = None,
) -> list[Verdict]:
    """Clause 3: each finding's verdicts in both tables, by number. ``findings`` defaults to
    the paper's (:func:`loopid.experiments.families.helicopter.findings.findings`);
    ``hover_panels`` to :func:`packaged_hover_panels` of the reference's scenarios."""
    if findings is None:
        from loopid.experiments.families.helicopter.findings import findings
    if hover_panels is None:
        hover_panels = packaged_hover_panels(set(ref["scenario"].to_pylist()))
    a = {f.number: f for f in findings(ref, set(hover_panels))}
    b = {f.number: f for f in findings(new, set(hover_panels))}
    out = []
    for k in dict.fromkeys([*a, *b]):
        r, n = a.get(k), b.get(k)
        out.append(
            Verdict(
                k,
                r.verdict if r else None,
                n.verdict if n else None,
                r.mean_verdict if r else None,
                n.mean_verdict if n else None,
            )
        )
    return out


def _verdict_failures(verdicts: list[Verdict]) -> list[str]:
    fails = []
    for v in verdicts:
        if v.ref != v.new:
            fails.append(f"finding {v.number}: verdict {v.new!r}, reference {v.ref!r} (equal)")
        if v.ref_mean != v.new_mean:
            fails.append(
                f"finding {v.number}: verdict on means {v.new_mean!r}, reference "
                f"{v.ref_mean!r} (equal)"
            )
    return fails


def _row_name(table: pa.Table, i: int) -> str:
    ident = [c for c in ("scenario", "method", "seed", "iteration") if c in table.column_names]
    return " ".join(str(table[c][i].as_py()) for c in ident) or f"row {i}"


def compare_mdp(ref: pa.Table, new: pa.Table) -> tuple[list[Column], list[str], list[str]]:
    """Clause 4: ``(columns, extra, failures)``: each reference column compared (module
    docstring), the new table's columns the reference lacks, and one failure line per column
    that differs (its worst row, both values, the tolerance) or is missing or retyped."""
    fails = []
    extra = [c for c in new.column_names if c not in ref.column_names]
    if ref.num_rows != new.num_rows:
        fails.append(f"MDP table: {new.num_rows} rows, reference {ref.num_rows}")
    columns = []
    for field in ref.schema:
        c = field.name
        if c not in new.column_names:
            fails.append(f"MDP table: column {c!r} missing (reference {field.type})")
            continue
        if new.schema.field(c).type != field.type:
            fails.append(
                f"MDP table: column {c!r} of type {new.schema.field(c).type}, reference "
                f"{field.type}"
            )
            continue
        if ref.num_rows != new.num_rows:
            continue
        if pa.types.is_floating(field.type):
            a = np.asarray(new[c].to_numpy(zero_copy_only=False), dtype=np.float64)
            b = np.asarray(ref[c].to_numpy(zero_copy_only=False), dtype=np.float64)
            ok = close(a, b, RTOL_MDP, ATOL_MDP)
            rel = np.array([relative_change(x, y) for x, y in zip(a, b, strict=True)])
            largest = float(rel.max()) if rel.size else 0.0
            bad = np.flatnonzero(~ok)
            if bad.size:
                i = int(bad[np.argmax(rel[bad])])
                fails.append(
                    f"MDP table: {c} differs in {bad.size} rows, most at {_row_name(ref, i)}: "
                    f"{a[i].item()!r}, reference {b[i].item()!r} (relative change "
                    f"{rel[i]:.3g} > {RTOL_MDP:g}, floor {ATOL_MDP:g})"
                )
            columns.append(Column(c, False, int(bad.size), largest))
        else:
            a, b = new[c].to_pylist(), ref[c].to_pylist()
            bad = [i for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y]
            if bad:
                i = bad[0]
                fails.append(
                    f"MDP table: {c} differs in {len(bad)} rows, first at {_row_name(ref, i)}: "
                    f"{a[i]!r}, reference {b[i]!r} (exactly)"
                )
            columns.append(Column(c, True, len(bad), math.nan))
    return columns, extra, fails


def evaluate_tables(
    ref_table: pa.Table,
    new_table: pa.Table,
    ref_mdp: pa.Table | None = None,
    new_mdp: pa.Table | None = None,
    *,
    hover_panels: set[str] | None = None,
    findings: FindingsFn | None = None,
    expert: str = EXPERT,
) -> Result:
    """The rule on two helicopter results tables and (when both are given) two MDP tables; one
    MDP table without the other fails. ``hover_panels`` and ``findings``: as
    :func:`compare_findings`."""
    cells = compare_cells(ref_table, new_table, expert)
    failures = [f for cell in cells for f in cell.failures]
    verdicts = compare_findings(ref_table, new_table, hover_panels, findings)
    failures += _verdict_failures(verdicts)
    columns, extra = None, []
    if ref_mdp is not None and new_mdp is not None:
        columns, extra, fails = compare_mdp(ref_mdp, new_mdp)
        failures += fails
    elif ref_mdp is not None or new_mdp is not None:
        failures.append(
            f"MDP table: only in {'the reference' if ref_mdp is not None else 'the new run'}"
        )
    return Result(cells, verdicts, columns, extra, failures)


def check_tables(
    ref_table: pa.Table,
    new_table: pa.Table,
    ref_mdp: pa.Table | None = None,
    new_mdp: pa.Table | None = None,
    **kw,
) -> list[str]:
    """The failed clauses of :func:`evaluate_tables`, one line each; empty: equivalent."""
    return evaluate_tables(ref_table, new_table, ref_mdp, new_mdp, **kw).failures


def evaluate(reference_dir, new_dir) -> Result:
    """The rule on two ``loopid reproduce`` run directories: ``results.parquet`` and
    ``mdp/results.parquet`` of each (a missing MDP table fails); the hover panels from the
    reference's ``config.toml`` (:func:`run_hover_panels`), else the packaged ones."""
    ref_dir, new_dir = Path(reference_dir), Path(new_dir)
    ref_table = pq.read_table(ref_dir / "results.parquet")
    new_table = pq.read_table(new_dir / "results.parquet")
    mdp = [d / "mdp" / "results.parquet" for d in (ref_dir, new_dir)]
    ref_mdp, new_mdp = (pq.read_table(p) if p.is_file() else None for p in mdp)
    hover = run_hover_panels(ref_dir)
    result = evaluate_tables(ref_table, new_table, ref_mdp, new_mdp, hover_panels=hover)
    missing = [f"{p} does not exist" for p in mdp if not p.is_file()]
    if len(missing) == 2:  # evaluate_tables compared no MDP table and did not say so
        return result._replace(failures=[*result.failures, *missing])
    return result


def check(reference_dir, new_dir) -> list[str]:
    """The failed clauses of :func:`evaluate`, one line each; empty: equivalent."""
    return evaluate(reference_dir, new_dir).failures


def _g(x: float | None) -> str:
    return "" if x is None else f"{x:.6g}"


def _side(median: float, L: float) -> str:
    if math.isnan(L):
        return "no L"
    return "good" if _good(median, L) else "not good"


def report(result: Result) -> list[str]:
    """Markdown lines: every cell's clause, final medians (reference, new, relative change),
    diverged counts and outcome; the largest relative change of a settled cell's median; the
    findings' verdicts; the MDP table's columns; the verdict and the failures."""
    lines = [
        "## Cells (final iteration, medians over seeds)",
        "",
        f"Clause 1 ({SETTLED}: no seed diverged in either table): the median to "
        f"{RTOL_MEDIAN:g} relative. Clause 2 ({DIVERGING}): diverged seeds within "
        f"±{DIVERGED_SLACK}, the median on the same side of good ({GOOD_FACTOR:g} L).",
        "",
        "| scenario | method | clause | iteration | median (reference) | median (new) | "
        "relative change | diverged seeds | good | outcome |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in result.cells:
        r, n = c.ref, c.new
        it = "" if (r or n) is None else str((r or n).iteration)
        div = f"{r.diverged} → {n.diverged}" if r and n else ""
        sides = (
            f"{_side(r.median, c.ref_L)} → {_side(n.median, c.new_L)}"
            if r and n and c.clause == DIVERGING
            else ""
        )
        change = f"{c.change:.3g}" if r and n else ""
        outcome = "fails" if c.failures else "passes"
        lines.append(
            f"| {c.scenario} | {c.method} | {c.clause or 'unmatched'} | {it} | "
            f"{_g(r.median if r else None)} | {_g(n.median if n else None)} | {change} | "
            f"{div} | {sides} | {outcome} |"
        )
    settled = [c for c in result.cells if c.clause == SETTLED]
    if settled:
        worst = max(settled, key=lambda c: c.change)
        lines += [
            "",
            f"Largest relative change of a settled cell's final median: {worst.change:.3g} "
            f"({worst.scenario} {worst.method}); {sum(c.change > 0 for c in settled)} of "
            f"{len(settled)} settled medians moved.",
        ]
    moved = [c for c in result.cells if c.clause == DIVERGING and c.change > 0]
    if moved:
        lines.append(
            f"{len(moved)} diverging cells' medians moved, by up to "
            f"{max(c.change for c in moved):.3g} relative."
        )
    lines += [
        "",
        "## The findings' verdicts (on medians; on means)",
        "",
        "| finding | reference | new | outcome |",
        "|---|---|---|---|",
    ]
    for v in result.verdicts:
        lines.append(
            f"| {v.number} | {v.ref}; {v.ref_mean} | {v.new}; {v.new_mean} | "
            f"{'passes' if v.same else 'fails'} |"
        )
    lines += ["", "## The MDP table", ""]
    if result.columns is None:
        lines.append("Not compared.")
    else:
        lines += [
            f"Floats to {RTOL_MDP:g} relative (floor {ATOL_MDP:g}), other columns exactly.",
            "",
            "| column | compared | rows off | largest relative change |",
            "|---|---|---|---|",
        ]
        for col in result.columns:
            how = "exactly" if col.exact else f"{RTOL_MDP:g}"
            largest = "" if col.exact else f"{col.largest:.3g}"
            lines.append(f"| {col.name} | {how} | {col.off} | {largest} |")
        if result.extra:
            lines += ["", f"Only in the new table, not compared: {', '.join(result.extra)}."]
    lines += ["", "## Verdict", ""]
    if result.failures:
        lines.append(f"Not equivalent: {len(result.failures)} failed clauses.")
        lines += ["", *[f"- {f}" for f in result.failures]]
    else:
        lines.append("Equivalent: every clause holds.")
    return lines
