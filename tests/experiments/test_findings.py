"""The paper's findings on synthetic tables: paired comparisons over seeds (a signed-rank test on
the per-seed differences), their outcomes and a finding's verdict over them, finding 5's bound
on the policy gradient's improvement in hover."""

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from scipy import stats

from loopid.experiments import paired
from loopid.experiments.families.helicopter import findings
from loopid.experiments.paired import (
    FAILS,
    HOLDS,
    HOLDS_WITH_TIES,
    NOT_MEASURED,
    TIE,
    TOO_FEW,
)
from loopid.experiments.results import SCHEMA

PANELS = ("hover", "hover-delay", "funnel")
HOVER = {"hover", "hover-delay"}
SEEDS = 8


def table_of(costs: dict[tuple[str, str], np.ndarray], seeds=None) -> pa.Table:
    """A results table (:data:`SCHEMA`) from ``{(scenario, method): test_cost [seeds,
    iterations]}``; ``seeds``: the seed numbers of the rows (default 0, 1, ...)."""
    cols = {f.name: [] for f in SCHEMA}
    for (s, m), c in costs.items():
        S, N = c.shape
        for k in range(S):
            for n in range(N):
                row = dict.fromkeys(cols, 0)
                row.update(scenario=s, method=m, seed=k if seeds is None else seeds[k],
                           iteration=n + 1, samples=n * 100, test_cost=float(c[k, n]),
                           test_cost_median=float(c[k, n]), diverged=int(c[k, n] >= 1e8),
                           loss_nu=0.0, loss_policy=0.0, online_loss=0.0,
                           spectral_radius=0.5, solver_converged=True)  # fmt: skip
                for key, v in row.items():
                    cols[key].append(v)
    return pa.table({f.name: pa.array(cols[f.name], type=f.type) for f in SCHEMA}, schema=SCHEMA)


def curve(first: float, last: float, seeds: int = SEEDS, n: int = 6, spread: float = 0.01):
    """``[seeds, n]`` costs falling geometrically from ``first`` to ``last``, seeds spread."""
    base = np.geomspace(first, last, n)
    return base[None, :] * (1 + spread * np.arange(seeds))[:, None]


def paper_like(seeds: int = SEEDS) -> dict:
    """Every finding holds: DAgger ends below L (hover) and below Batch; one good Batch; Abbeel
    improves from iteration 2 then sits above DAgger; PG improves x1.73 and stays far from L."""
    costs = {}
    for s in PANELS:
        costs[(s, "expert")] = curve(50.0, 50.0, seeds)
        for nu in ("t", "e", "en"):
            costs[(s, f"dagger-{nu}")] = curve(2.6e6, 45.0 if s != "funnel" else 55.0, seeds)
        costs[(s, "batch-t")] = curve(2.6e6, 1e7, seeds)
        costs[(s, "batch-e")] = curve(2.6e6, 1.5e4, seeds)
        costs[(s, "batch-en")] = curve(2.6e6, 60.0, seeds)
        a = curve(2.6e6, 120.0, seeds)
        a[:, 1] = 1e6  # iteration 2: the first policy fitted to the expert's data
        costs[(s, "abbeel")] = a
        costs[(s, "pg")] = curve(2.6e6, 1.5e6, seeds)
    return costs


def found(costs, seeds=None) -> list[findings.Finding]:
    return findings.findings(table_of(costs, seeds), HOVER)


def two(a: np.ndarray, b: np.ndarray, panel: str = "funnel") -> dict:
    """One panel, one ν: DAgger's final costs ``a`` against Batch's ``b`` (``[seeds]``)."""
    first = np.full_like(a, 1e6)
    return {
        (panel, "dagger-t"): np.stack([first, a], axis=1),
        (panel, "batch-t"): np.stack([first, b], axis=1),
    }


def test_every_finding_holds_on_a_paper_like_table():
    got = found(paper_like())
    assert [f.number for f in got] == [1, 2, 3, 4, 5]
    assert [f.verdict for f in got] == [HOLDS] * 5
    assert [f.mean_verdict for f in got] == [HOLDS] * 5
    # finding 1: 3 panels x 3 ν; finding 3: 2 hover panels x 3 ν; finding 4: 2 per panel
    assert [len(f.outcomes) for f in got] == [9, 3, 6, 6, 2]


@pytest.mark.parametrize(
    ("change", "broken"),
    [
        # finding 1: one ν in one panel where Batch ends below DAgger
        ({("funnel", "batch-en"): curve(2.6e6, 40.0)}, {1}),
        # finding 2: a second good Batch curve (and one DAgger curve never settles)
        ({("hover", "batch-e"): curve(2.6e6, 70.0)}, {2}),
        ({("hover-delay", "dagger-e"): curve(2.6e6, 1e8)}, {1, 2, 3}),
        # finding 3: DAgger approaches L from above in hover (the funnel does not count)
        ({("hover", "dagger-t"): curve(2.6e6, 52.0)}, {3}),
        ({("funnel", "dagger-t"): curve(2.6e6, 80.0)}, set()),
        # finding 4: Abbeel never improves on its first policy / ends below DAgger
        ({("hover", "abbeel"): curve(2.6e6, 3e6)}, {4}),
        ({("funnel", "abbeel"): curve(2.6e6, 20.0)}, {4}),
        # finding 5: PG reaches good performance in hover
        ({("hover", "pg"): curve(2.6e6, 90.0)}, {5}),
    ],
)
def test_each_finding_fails_when_its_claim_does(change, broken):
    got = [f.verdict for f in found(paper_like() | change)]
    assert {i + 1 for i, v in enumerate(got) if v != HOLDS} == broken
    assert {i + 1 for i, v in enumerate(got) if v == FAILS} == broken


def test_identical_methods_tie():
    a = np.geomspace(10.0, 1e4, SEEDS)
    assert paired.below(a, a.copy()) == paired.Comparison(TIE, SEEDS, 1.0, 0.0)
    assert paired.below(a, a.copy(), on="mean").outcome == TIE
    f1 = found(two(a, a.copy()))[0]
    assert (f1.outcomes, f1.mean_outcomes) == ((TIE,), (TIE,))
    assert (f1.verdict, f1.mean_verdict) == (TIE, TIE)  # nothing decided: not "holds with ties"


def test_worse_on_every_seed_does_not_hold():
    b = np.linspace(100.0, 200.0, SEEDS)
    a = b * 1.5 + 3.0  # DAgger above Batch on every seed
    f1 = found(two(a, b))[0]
    assert (f1.verdict, f1.mean_verdict) == (FAILS, FAILS)
    r = paired.below(a, b)
    assert r.outcome == FAILS and r.p < paired.ALPHA and r.shift > 0
    assert "does not hold (p 0.0078, 8 seeds" in f1.details[0]


def test_pairing_finds_a_shift_that_an_unpaired_test_calls_a_tie():
    """Seeds spread over three decades, DAgger a little below Batch on every one: the paired
    test decides, an unpaired one (Mann-Whitney) on the same numbers cannot."""
    b = np.geomspace(10.0, 1e4, SEEDS)
    a = b - (1.0 + 0.1 * np.arange(SEEDS))
    assert stats.mannwhitneyu(a, b, alternative="two-sided").pvalue > 0.5
    r = paired.below(a, b)
    assert r.outcome == HOLDS and r.p == pytest.approx(2 / 2**SEEDS)
    assert found(two(a, b))[0].verdict == HOLDS


def test_rows_are_paired_by_seed_not_by_row_order():
    """Batch's rows come in another seed order, and one seed of DAgger's is missing."""
    b = np.geomspace(10.0, 1e4, SEEDS + 1)
    a = b - 1.0  # below on every seed, paired
    order = np.arange(SEEDS + 1)[::-1]
    t = table_of(two(a[:SEEDS], b[:SEEDS]), seeds=list(range(SEEDS)))
    t_b = table_of({k: v[order] for k, v in two(a, b).items() if k[1] == "batch-t"}, order)
    costs = findings.Costs(pa.concat_tables([t.filter(pc.equal(t["method"], "dagger-t")), t_b]))
    x, y = costs.paired("funnel", "dagger-t", "batch-t")
    np.testing.assert_array_equal(x, a[:SEEDS])
    np.testing.assert_array_equal(y, b[:SEEDS])
    assert paired.below(x, y).outcome == HOLDS


def test_fewer_than_six_seeds_are_too_few():
    b = np.geomspace(10.0, 1e4, 6)
    a = b / 2
    assert paired.MIN_SEEDS == 6
    r = paired.below(a[:5], b[:5])
    assert (r.outcome, r.seeds) == (TOO_FEW, 5) and np.isnan(r.p)
    assert paired.below(a, b).outcome == HOLDS  # 6 seeds: the exact p-value is 2/64
    f1 = found(two(a[:5], b[:5]))[0]
    assert (f1.verdict, f1.mean_verdict) == (TOO_FEW, TOO_FEW)
    assert "too few seeds (5 seeds)" in f1.details[0]


def test_a_quick_run_of_two_seeds_decides_only_the_thresholds():
    got = found(paper_like(seeds=2))
    assert [f.verdict for f in got] == [TOO_FEW, HOLDS, TOO_FEW, TOO_FEW, HOLDS]


def test_one_tie_among_holds_is_holds_with_ties():
    costs = paper_like()
    costs[("funnel", "batch-en")] = costs[("funnel", "dagger-en")].copy()  # a tie
    f1 = found(costs)[0]
    assert f1.outcomes.count(TIE) == 1 and f1.outcomes.count(HOLDS) == 8
    assert (f1.verdict, f1.mean_verdict) == (HOLDS_WITH_TIES, HOLDS_WITH_TIES)


@pytest.mark.parametrize(
    ("outcomes", "verdict"),
    [
        ([], NOT_MEASURED),
        ([HOLDS, HOLDS], HOLDS),
        ([HOLDS, TIE], HOLDS_WITH_TIES),
        ([HOLDS, TOO_FEW], HOLDS_WITH_TIES),  # a comparison with too few seeds is undecided
        ([HOLDS, TIE, FAILS], FAILS),
        ([TOO_FEW, FAILS], FAILS),
        ([TOO_FEW, TOO_FEW], TOO_FEW),
        ([TIE, TOO_FEW], TIE),
        ([TIE], TIE),
    ],
)
def test_a_findings_verdict_over_its_comparisons(outcomes, verdict):
    assert paired.combine(outcomes) == verdict


def test_medians_and_means_judged_separately():
    """Finding 1 on one ν: DAgger is below Batch on 11 of 12 seeds, and one diverging seed
    (capped) is far above: the signed-rank test holds, the paired t-test on means ties, and
    the detail line says so."""
    costs = paper_like(seeds=12)
    d = curve(2.6e6, 45.0, seeds=12)
    d[0, -1] = 1e8  # one seed diverges (capped)
    costs[("hover", "dagger-t")] = d
    costs[("hover", "batch-t")] = curve(2.6e6, 1e6, seeds=12)
    f1 = found(costs)[0]
    assert (f1.verdict, f1.mean_verdict) == (HOLDS, HOLDS_WITH_TIES)
    assert any("hover ν_t" in line and "; on means: " in line for line in f1.details)


def pg_costs(panel: str, factor: float, final: float = 1.5e6) -> dict:
    c = curve(factor * final, final)
    return {(panel, "expert"): curve(50.0, 50.0), (panel, "pg"): c}


@pytest.mark.parametrize(
    ("factor", "final", "verdict"),
    [
        (1.9, 1.5e6, HOLDS),
        (2.1, 1.5e6, FAILS),  # more than halves its first policy's cost
        (1.5, 90.0, FAILS),  # small improvement, but good (<= 2 x L)
        (0.8, 1.5e6, FAILS),  # no improvement: it gets worse
        (1.0, 1.5e6, FAILS),  # no improvement at all
    ],
)
def test_finding_5_bounds_the_improvement_in_hover(factor, final, verdict):
    assert findings.SMALL_IMPROVEMENT == 2.0
    f5 = found(pg_costs("hover", factor, final))[4]
    assert (f5.verdict, f5.mean_verdict) == (verdict, verdict)
    assert f"x{factor:.3g} (small: above x1, at most x2)" in f5.details[0]


def test_finding_5_ignores_panels_that_are_not_hover():
    f5 = found(pg_costs("funnel", 10.0))[4]
    assert f5.verdict == NOT_MEASURED
    f5 = found(pg_costs("hover", 1.9) | pg_costs("funnel", 10.0, final=60.0))[4]
    assert f5.verdict == HOLDS and len(f5.details) == 1


def test_finding_3_pairs_dagger_with_the_expert_seed_by_seed():
    """L's costs spread over seeds more than DAgger's gap below it: paired, DAgger is below."""
    L = np.geomspace(40.0, 400.0, SEEDS)
    first = np.full(SEEDS, 1e6)
    costs = {("hover", "expert"): np.stack([L, L], axis=1)}
    for nu in ("t", "e", "en"):
        costs[("hover", f"dagger-{nu}")] = np.stack([first, L - 1.0], axis=1)
    f3 = found(costs)[2]
    assert f3.outcomes == (HOLDS,) * 3 and f3.verdict == HOLDS


def test_the_report_section_explains_the_verdict_words():
    text = "\n".join(findings.findings_section(table_of(paper_like()), HOVER))
    assert paired.VERDICT_WORDS in text
    for word in (HOLDS, FAILS, TIE, TOO_FEW, HOLDS_WITH_TIES):
        assert f"*{word}*" in paired.VERDICT_WORDS
    assert text.count("— **holds**") == 5
