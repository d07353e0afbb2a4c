"""The equivalence rule (``benchmarks/equivalence_rule.py``) on synthetic tables: it fails each
kind of change it is meant to catch and passes what it is meant to allow (no JAX run)."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from benchmarks import equivalence_rule as E

from loopid.experiments.families.helicopter.findings import findings

ROOT = Path(__file__).resolve().parent.parent
SEEDS = 20
ITERATIONS = (1, 2, 3)
L = 10.0  # each panel's expert median
#: Per method: (final median over seeds, seeds with a diverged trajectory at the final iteration).
#: In each panel the three DAgger curves and Batch-ν_t are good (at most 2 L), Batch-ν_e and
#: Batch-ν_en are not and diverge: finding 2 holds, on medians and on means.
CELLS = {
    "expert": (L, 0),
    "dagger-t": (12.0, 0),
    "dagger-e": (13.0, 0),
    "dagger-en": (14.0, 0),
    "batch-t": (18.0, 0),
    "batch-e": (1e5, 5),
    "batch-en": (1e6, 12),
}
SCENARIOS = ("hover", "funnel")


def _costs(median: float) -> np.ndarray:
    """20 costs, one per seed, whose median is ``median`` (to rounding): ``median × (1 + d)``,
    ``d`` symmetric about 0, within ±9.5 %."""
    return median * (1 + 0.01 * (np.arange(SEEDS) - (SEEDS - 1) / 2))


def table(cells=None) -> pa.Table:
    """A results table: every scenario × method of ``cells`` (default :data:`CELLS`), 20 seeds,
    three iterations, the final one's costs of the cell's median and the cell's count of
    diverged seeds (the highest-cost seeds), earlier iterations 3 × as costly."""
    cells = cells or {s: dict(CELLS) for s in SCENARIOS}
    cols = {k: [] for k in ("scenario", "method", "seed", "iteration", "samples")}
    cols |= {"test_cost": [], "test_cost_median": [], "diverged": []}
    for s, methods in cells.items():
        for m, (median, diverged) in methods.items():
            costs = _costs(median)
            for it in ITERATIONS:
                final = it == ITERATIONS[-1]
                for seed in range(SEEDS):
                    cols["scenario"].append(s)
                    cols["method"].append(m)
                    cols["seed"].append(seed)
                    cols["iteration"].append(it)
                    cols["samples"].append(100 * it)
                    cost = costs[seed] * (1 if final else 3)
                    cols["test_cost"].append(float(cost))
                    cols["test_cost_median"].append(float(cost))
                    cols["diverged"].append(int(final and seed >= SEEDS - diverged) * 2)
    types = {"scenario": pa.string(), "method": pa.string(), "test_cost": pa.float64()}
    types["test_cost_median"] = pa.float64()
    return pa.table({k: pa.array(v, types.get(k, pa.int64())) for k, v in cols.items()})


def _keys(t: pa.Table, columns) -> list[tuple]:
    return list(zip(*(t[c].to_pylist() for c in columns), strict=True))


def changed(t: pa.Table, scenario, method, column, f, *, seeds=None, final=True) -> pa.Table:
    """``t`` with ``f(value)`` in ``column`` of the cell's rows (its final iteration's, and
    only ``seeds`` when given)."""
    last = max(ITERATIONS)
    rows = _keys(t, ("scenario", "method", "seed", "iteration"))
    values = t[column].to_pylist()
    for i, (s, m, seed, it) in enumerate(rows):
        if (s, m) == (scenario, method) and (not final or it == last):
            if seeds is None or seed in seeds:
                values[i] = f(values[i])
    j = t.column_names.index(column)
    return t.set_column(j, t.schema.field(j), pa.array(values, t.schema.field(j).type))


def scaled(t, scenario, method, factor, **kw):
    return changed(t, scenario, method, "test_cost", lambda x: x * factor, **kw)


def diverging(t, scenario, method, by: int):
    """The cell with ``by`` more seeds diverged (fewer if negative), by its final costs' rank."""
    d = t["diverged"].to_pylist()
    final = (scenario, method, max(ITERATIONS))
    rows = [i for i, k in enumerate(_keys(t, ("scenario", "method", "iteration"))) if k == final]
    if by > 0:
        for i in [i for i in reversed(rows) if d[i] == 0][:by]:
            d[i] = 1
    else:
        for i in [i for i in rows if d[i] > 0][:-by]:
            d[i] = 0
    j = t.column_names.index("diverged")
    return t.set_column(j, "diverged", pa.array(d, pa.int64()))


@pytest.fixture(scope="module")
def ref():
    return table()


def test_the_synthetic_table_reads_as_built(ref):
    finals = E.finals(ref)
    assert len(finals) == len(SCENARIOS) * len(CELLS)
    for (_, m), f in finals.items():
        median, diverged = CELLS[m]
        assert f.iteration == 3 and f.seeds == tuple(range(SEEDS))
        assert math.isclose(f.median, median, rel_tol=1e-12) and f.diverged == diverged
    verdicts = {f.number: (f.verdict, f.mean_verdict) for f in findings(ref, {"hover"})}
    assert verdicts[2] == ("holds", "holds")


def test_a_table_is_equivalent_to_itself(ref):
    result = E.evaluate_tables(ref, ref, mdp_table(), mdp_table())
    assert result.failures == []
    clauses = {(c.scenario, c.method): c.clause for c in result.cells}
    assert clauses[("hover", "expert")] == E.SETTLED
    assert clauses[("funnel", "batch-en")] == E.DIVERGING
    text = "\n".join(E.report(result))
    assert "Equivalent: every clause holds." in text
    assert "Largest relative change of a settled cell's final median: 0" in text


# ---- clause 1: cells without a diverged seed ----------------------------------------------------


@pytest.mark.parametrize("method", ["dagger-e", "expert"])
def test_a_settled_median_may_move_by_1e_4(ref, method):
    new = scaled(ref, "hover", method, 1 + 1e-4)
    result = E.evaluate_tables(ref, new)
    assert result.failures == []
    cell = next(c for c in result.cells if (c.scenario, c.method) == ("hover", method))
    assert cell.clause == E.SETTLED and cell.change == pytest.approx(1e-4, rel=1e-6)
    text = "\n".join(E.report(result))
    assert f"0.0001 (hover {method})" in text


@pytest.mark.parametrize("factor", [1 + 1e-3, 1 - 1e-3])
def test_a_settled_median_moved_by_1e_3_fails(ref, factor):
    failures = E.check_tables(ref, scaled(ref, "funnel", "dagger-t", factor))
    assert len(failures) == 1
    assert failures[0].startswith("funnel dagger-t (no diverged seed): final median ")
    assert "relative change 0.001 > 0.0005" in failures[0]


def test_a_settled_cell_with_a_seed_diverging_goes_to_clause_2(ref):
    """One seed diverging in the new table only: the cell is judged by clause 2, which allows
    one seed and a median moved by more than 5e-4 on the same side of good."""
    new = scaled(diverging(ref, "hover", "dagger-t", 1), "hover", "dagger-t", 1.2)
    result = E.evaluate_tables(ref, new)
    assert result.failures == []
    cell = next(c for c in result.cells if (c.scenario, c.method) == ("hover", "dagger-t"))
    assert cell.clause == E.DIVERGING
    assert (cell.ref.diverged, cell.new.diverged) == (0, 1)
    # two seeds diverging: the count fails
    failures = E.check_tables(ref, diverging(ref, "hover", "dagger-t", 2))
    assert failures == [
        "hover dagger-t: 2 seeds with a diverged trajectory, reference 0 (within ±1)"
    ]


def test_nan_and_inf_in_a_median():
    """NaN equals NaN and an infinity itself, in a median as in the MDP table."""
    assert E.relative_change(math.nan, math.nan) == 0.0
    assert E.relative_change(math.inf, math.inf) == 0.0
    assert E.relative_change(-math.inf, math.inf) == math.inf
    assert E.relative_change(1.0, math.nan) == math.inf
    assert E.relative_change(1e-300, 0.0) == math.inf
    assert E.close(
        [math.nan, math.inf, 1.0, 1e308], [math.nan, math.inf, math.inf, math.inf], 1e-3
    ).tolist() == [True, True, False, False]
    nan = {s: dict(CELLS) for s in SCENARIOS}
    nan["hover"]["dagger-t"] = (math.nan, 0)
    t = table(nan)
    assert math.isnan(E.finals(t)[("hover", "dagger-t")].median)
    assert E.check_tables(t, t, findings=lambda *_: []) == []
    failures = E.check_tables(t, table(), findings=lambda *_: [])
    assert failures == [
        "hover dagger-t (no diverged seed): final median 12.0, reference nan: relative change "
        "inf > 0.0005"
    ]


# ---- clause 2: cells with a diverged seed -------------------------------------------------------


@pytest.mark.parametrize("by", [1, -1])
def test_a_diverged_count_may_move_by_one(ref, by):
    new = scaled(diverging(ref, "hover", "batch-e", by), "hover", "batch-e", 1.5)
    assert E.check_tables(ref, new) == []


@pytest.mark.parametrize("by", [2, -2])
def test_a_diverged_count_moved_by_two_fails(ref, by):
    failures = E.check_tables(ref, diverging(ref, "funnel", "batch-en", by))
    assert failures == [
        f"funnel batch-en: {12 + by} seeds with a diverged trajectory, reference 12 (within ±1)"
    ]


def test_a_diverging_median_crossing_2L_fails(ref):
    """Batch-ν_e's median from 1e5 to 19 (below 2 L = 20): clause 2 fails, and so does finding
    2 (two good Batch curves in the panel), on medians and on means."""
    new = scaled(ref, "hover", "batch-e", 19.0 / 1e5)
    failures = E.check_tables(ref, new)
    assert len(failures) == 3
    assert failures[0].startswith("hover batch-e: final median 19.0")
    assert "<= 2 L = 20.0" in failures[0] and "> 2 L = 20.0 (the same side of good)" in failures[0]
    assert failures[1:] == [
        "finding 2: verdict 'does not hold', reference 'holds' (equal)",
        "finding 2: verdict on means 'does not hold', reference 'holds' (equal)",
    ]


def test_the_side_of_good_is_judged_against_each_tables_own_L(ref):
    """A diverging cell and the panel's expert scaled alike keep their side; the expert alone
    moved by 1e-4 (its own clause passes) leaves a diverging median near 2 L on its side."""
    near = {s: dict(CELLS) for s in SCENARIOS}
    near["hover"]["batch-e"] = (2 * L * (1 + 1e-3), 5)
    t = table(near)
    assert E.check_tables(t, scaled(t, "hover", "expert", 1 + 1e-4)) == []
    failures = E.check_tables(t, scaled(t, "hover", "expert", 1 + 2e-3))
    assert any("hover batch-e: final median" in f and "same side of good" in f for f in failures)


# ---- clause 3: the findings' verdicts -----------------------------------------------------------


def test_a_findings_verdict_flipping_on_means_fails(ref):
    """One settled seed at 1e6 (above the median, so the median does not move): clause 1 holds,
    but on means finding 2 flips (Batch-ν_t's mean is no longer good) and finding 1 too (the
    paired t-test of DAgger-ν_t against Batch-ν_t ties, swamped by the one seed)."""
    new = scaled(ref, "funnel", "batch-t", 1e6 / 18.0, seeds={SEEDS - 1})
    cell = ("funnel", "batch-t")
    assert E.finals(new)[cell].median == E.finals(ref)[cell].median
    failures = E.check_tables(ref, new)
    assert failures == [
        "finding 1: verdict on means 'holds with ties', reference 'holds' (equal)",
        "finding 2: verdict on means 'does not hold', reference 'holds' (equal)",
    ]


def test_a_findings_verdict_flipping_within_the_cells_tolerance_fails():
    """A settled Batch-ν_e just above 2 L, moved down by 1e-4 (clause 1 holds) to just below:
    finding 2's verdict (on medians and on means) flips, and the rule fails on it alone."""
    near = {s: dict(CELLS) for s in SCENARIOS}
    near["hover"]["batch-e"] = (2 * L * (1 + 5e-5), 0)
    t = table(near)
    failures = E.check_tables(t, scaled(t, "hover", "batch-e", 1 - 1e-4))
    assert failures == [
        "finding 2: verdict 'does not hold', reference 'holds' (equal)",
        "finding 2: verdict on means 'does not hold', reference 'holds' (equal)",
    ]


class _Finding:
    def __init__(self, number, verdict, mean_verdict):
        self.number, self.verdict, self.mean_verdict = number, verdict, mean_verdict


def test_the_verdicts_are_compared_finding_by_finding(ref):
    """An injected findings function (the default is the paper's): each verdict and each
    verdict on means compared by number; a finding in one table only fails."""

    def fake(t, hover):
        assert hover == {"hover"}  # the packaged hover panels among the table's scenarios
        moved = not t["test_cost"].equals(ref["test_cost"])
        return [
            _Finding(1, "holds", "holds"),
            _Finding(2, "tie" if moved else "holds", "holds"),
            *([_Finding(3, "holds", "holds")] if not moved else []),
        ]

    assert E.check_tables(ref, ref, findings=fake) == []
    new = changed(ref, "hover", "dagger-t", "test_cost", lambda x: x * 1.0001, final=False)
    assert E.check_tables(ref, new, findings=fake) == [
        "finding 2: verdict 'tie', reference 'holds' (equal)",
        "finding 3: verdict None, reference 'holds' (equal)",
        "finding 3: verdict on means None, reference 'holds' (equal)",
    ]


def test_the_default_findings_are_the_papers(ref):
    """Without ``findings``, the rule's verdicts are those of the paper's findings function."""
    verdicts = E.compare_findings(ref, ref)
    assert [(v.number, v.ref, v.ref_mean) for v in verdicts] == [
        (f.number, f.verdict, f.mean_verdict) for f in findings(ref, {"hover"})
    ]


# ---- the cells must match ------------------------------------------------------------------------


def test_a_missing_cell_or_other_seeds_fail(ref):
    with_abbeel = table({s: {**CELLS, "abbeel": (50.0, 0)} for s in SCENARIOS})
    failures = E.check_tables(with_abbeel, ref)
    assert "hover abbeel: only in the reference" in failures
    assert "funnel abbeel: only in the reference" in failures
    fewer = ref.filter(pa.array([seed != 7 for seed in ref["seed"].to_pylist()]))
    failures = E.check_tables(ref, fewer)
    assert "hover expert: seeds at the final iteration [0, 1, 2, 3, 4, 5, 6, 8" in failures[0]


# ---- clause 4: the MDP table ---------------------------------------------------------------------


def mdp_table() -> pa.Table:
    n = 8
    return pa.table(
        {
            "scenario": pa.array(["mdp-trap"] * n, pa.string()),
            "method": pa.array(["dagger", "batch"] * (n // 2), pa.string()),
            "seed": pa.array(range(n), pa.int64()),
            "iteration": pa.array([1] * n, pa.int64()),
            "test_cost": pa.array([0.5, 1.25, 3e-7, 0.0, 2.0, 7.5, 1e3, 0.1], pa.float64()),
            "bound": pa.array([1.0, math.nan, math.inf, -math.inf, 0.0, 2.5, 3.0, 4.0]),
            "solver_converged": pa.array([True] * n, pa.bool_()),
        }
    )


def _mdp_set(t: pa.Table, column: str, row: int, value) -> pa.Table:
    values = t[column].to_pylist()
    values[row] = value
    j = t.column_names.index(column)
    return t.set_column(j, t.schema.field(j), pa.array(values, t.schema.field(j).type))


MDP_PASSES = {
    "itself": lambda t: t,
    "a float by 1e-13 relative": lambda t: _mdp_set(t, "test_cost", 1, 1.25 * (1 + 1e-13)),
    "every float by 1e-13": lambda t: t.set_column(
        4, "test_cost", pa.array(np.asarray(t["test_cost"]) * (1 + 1e-13))
    ),
    "NaN as NaN": lambda t: _mdp_set(t, "bound", 1, math.nan),
    "a zero at 1e-310": lambda t: _mdp_set(t, "test_cost", 3, 1e-310),
    "a column added": lambda t: t.append_column("extra", pa.array([1.0] * t.num_rows)),
}

MDP_FAILS = {
    "a float by 1e-11 relative": (
        lambda t: _mdp_set(t, "test_cost", 1, 1.25 * (1 + 1e-11)),
        "test_cost differs in 1 rows, most at mdp-trap batch 1 1",
    ),
    "a tiny float by 1e-11 relative": (
        lambda t: _mdp_set(t, "test_cost", 2, 3e-7 * (1 - 1e-11)),
        "test_cost differs in 1 rows",
    ),
    "a zero at 1e-200": (lambda t: _mdp_set(t, "test_cost", 3, 1e-200), "relative change inf"),
    "NaN as a number": (lambda t: _mdp_set(t, "bound", 1, 1.0), "bound differs"),
    "a number as NaN": (lambda t: _mdp_set(t, "bound", 0, math.nan), "bound differs"),
    "inf as -inf": (lambda t: _mdp_set(t, "bound", 2, -math.inf), "bound differs"),
    "inf as the largest float": (lambda t: _mdp_set(t, "bound", 2, 1.7e308), "bound differs"),
    "a number as inf": (lambda t: _mdp_set(t, "bound", 5, math.inf), "bound differs"),
    "an int": (lambda t: _mdp_set(t, "seed", 4, 40), "seed differs in 1 rows, first at"),
    "a bool": (lambda t: _mdp_set(t, "solver_converged", 0, False), "solver_converged"),
    "a string": (lambda t: _mdp_set(t, "method", 0, "batch"), "method differs"),
    "rows in another order": (lambda t: pa.concat_tables([t.slice(1), t.slice(0, 1)]), "seed"),
    "a row missing": (lambda t: t.slice(1), "7 rows, reference 8"),
    "a column missing": (lambda t: t.drop_columns(["bound"]), "column 'bound' missing"),
    "a column retyped": (
        lambda t: t.set_column(2, "seed", t["seed"].cast(pa.int32())),
        "column 'seed' of type int32",
    ),
}


@pytest.mark.parametrize("change", MDP_PASSES.values(), ids=MDP_PASSES.keys())
def test_the_mdp_table_passes_within_1e_12(ref, change):
    mdp = mdp_table()
    result = E.evaluate_tables(ref, ref, mdp, change(mdp))
    assert result.failures == []


@pytest.mark.parametrize(("change", "needle"), MDP_FAILS.values(), ids=MDP_FAILS.keys())
def test_the_mdp_table_fails_beyond_1e_12(ref, change, needle):
    mdp = mdp_table()
    failures = E.check_tables(ref, ref, mdp, change(mdp))
    assert failures and all(f.startswith("MDP table: ") for f in failures)
    assert any(needle in f for f in failures), failures


def test_one_mdp_table_without_the_other_fails(ref):
    assert E.check_tables(ref, ref, mdp_table(), None) == ["MDP table: only in the reference"]
    result = E.evaluate_tables(ref, ref)
    assert result.columns is None and result.failures == []


def test_the_report_lists_the_mdp_columns(ref):
    mdp = mdp_table()
    new = _mdp_set(mdp.append_column("extra", pa.array([0.0] * 8)), "test_cost", 1, 1.25 + 1e-9)
    text = "\n".join(E.report(E.evaluate_tables(ref, ref, mdp, new)))
    assert "| test_cost | 1e-12 | 1 | 8e-10 |" in text
    assert "| seed | exactly | 0 |  |" in text
    assert "Only in the new table, not compared: extra." in text
    assert "Not equivalent: 1 failed clauses." in text


# ---- run directories and the command line -------------------------------------------------------


def _run_dir(path: Path, results: pa.Table, mdp: pa.Table | None) -> Path:
    (path / "mdp").mkdir(parents=True)
    pq.write_table(results, path / "results.parquet")
    if mdp is not None:
        pq.write_table(mdp, path / "mdp" / "results.parquet")
    return path


def test_run_directories(ref, tmp_path):
    a = _run_dir(tmp_path / "a", ref, mdp_table())
    b = _run_dir(tmp_path / "b", scaled(ref, "hover", "dagger-e", 1 + 2e-4), mdp_table())
    assert E.check(a, b) == []
    c = _run_dir(tmp_path / "c", ref, None)
    assert E.check(a, c) == ["MDP table: only in the reference"]
    d = _run_dir(tmp_path / "d", ref, None)
    assert E.check(c, d) == [f"{p / 'mdp' / 'results.parquet'} does not exist" for p in (c, d)]


def _run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=120)


def test_the_command_line(ref, tmp_path):
    """``benchmarks/equivalence.py REFERENCE NEW``: the report, exit 0 when equivalent, 1 when
    not; without arguments (as ``make bench`` runs it) its usage, exit 0."""
    a = _run_dir(tmp_path / "a", ref, mdp_table())
    b = _run_dir(tmp_path / "b", scaled(ref, "funnel", "expert", 1 + 1e-3), mdp_table())
    script = ROOT / "benchmarks" / "equivalence.py"
    ok = _run(script, a, a)
    assert ok.returncode == 0, ok.stderr
    assert "Equivalent: every clause holds." in ok.stdout
    bad = _run(script, a, b)
    assert bad.returncode == 1, bad.stderr
    assert "- funnel expert (no diverged seed): final median" in bad.stdout
    assert "| funnel | expert | settled | 3 | 10 | 10.01 | 0.001 |" in bad.stdout
    bare = _run(script)
    assert bare.returncode == 0 and "Nothing to compare" in bare.stdout
