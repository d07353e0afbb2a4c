"""The paper's five findings (what its Figure 2 shows, section 6), each computed from a results
table and given a verdict; ``report.md`` of a helicopter run and ``study.md`` show them.

The statistics, per panel (scenario) and method, are over seeds of the test cost at the method's
**final** iteration (``final``), or at iteration 2 (``first``, the first policy fitted to data).
Two kinds of judgement make a finding:

- **comparisons** "A below B" (findings 1, 3 and 4) are paired over seeds, since the same seeds
  see the same noise (:mod:`loopid.experiments.paired`): a two-sided Wilcoxon signed-rank test on
  the per-seed differences, each comparison reading ``holds``, ``does not hold``, ``tie`` or
  ``too few seeds``;
- **thresholds** (findings 2 and 5) on the statistic over seeds, ``holds`` or ``does not hold``.

A finding's verdict over them is :func:`loopid.experiments.paired.combine`'s: ``holds``,
``holds with ties``, ``does not hold``, ``tie``, ``too few seeds`` or ``not measured``. Each
finding is judged on **medians** over seeds (a few diverging seeds, capped at ``cost_cap``,
dominate means; for comparisons: the signed-rank test) and, beside it, on means (for comparisons:
the paired t-test). Nothing is tuned to make a finding hold.

"Good performance" (findings 2 and 5) is a fixed threshold chosen before looking at any result:
a final cost at most :data:`GOOD_FACTOR` times the linearised expert L's in the same panel.
"Only small improvement" (finding 5) is a fixed bound :data:`SMALL_IMPROVEMENT` on how much the
policy gradient lowers its first policy's cost, read from the paper's words; it was written down
when 20-seed runs of the policy gradient under both readings of its step were already known,
so reports show the finding under both (it does not hold under ``pg_update = conservative``).
"""

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from loopid.experiments.final_costs import Costs, significant
from loopid.experiments.paired import (
    FAILS,
    HOLDS,
    VERDICT_WORDS,
    Comparison,
    below,
    combine,
)

#: "Good performance": final cost at most this multiple of the expert's (findings 2 and 5).
GOOD_FACTOR = 2.0
#: The paper on the policy gradient in hover: "100 samples per iteration were insufficient to
#: get good gradient estimates and lead to only small improvement". "Only small improvement"
#: means the policy gradient at most halves its first policy's median cost (log10 2 ≈ 0.3
#: decades on Figure 2's log axis): 1 < improvement factor (cost at iteration 1 / final cost) <=
#: this. A policy gradient that gets worse shows no improvement at all: the finding does not hold.
SMALL_IMPROVEMENT = 2.0
NUS = ("t", "e", "en")
STATS: dict[str, Callable[[np.ndarray], float]] = {"median": np.median, "mean": np.mean}


class Finding(NamedTuple):
    """One of the paper's five findings: ``verdict`` on medians, ``mean_verdict`` on means (each
    ``holds``, ``holds with ties``, ``does not hold``, ``tie``, ``too few seeds`` or
    ``not measured``), how it was computed, the numbers (``details``), and each comparison's or
    threshold's outcome in the order of the details (``outcomes`` on medians, ``mean_outcomes``
    on means)."""

    number: int
    claim: str
    how: str
    verdict: str
    mean_verdict: str
    details: list[str]
    outcomes: tuple[str, ...] = ()
    mean_outcomes: tuple[str, ...] = ()


#: What a finding's check returns, per detail line: the outcomes it judges, and the line.
Lines = list[tuple[tuple[str, ...], str]]


def _judge(number: int, claim: str, how: str, check: Callable[[str], Lines]) -> Finding:
    """Run ``check(on)`` (``on``: ``"median"`` or ``"mean"``) on medians and on means; the
    details are the median lines, each followed by its mean line where an outcome differs."""
    med, mean = check("median"), check("mean")
    lines = [
        d if o == om else f"{d}; on means: {dm}" for (o, d), (om, dm) in zip(med, mean, strict=True)
    ]
    outcomes = tuple(x for o, _ in med for x in o)
    mean_outcomes = tuple(x for o, _ in mean for x in o)
    return Finding(
        number, claim, how, combine(list(outcomes)), combine(list(mean_outcomes)), lines,
        outcomes, mean_outcomes,
    )  # fmt: skip


def _ok(b: bool) -> str:
    return HOLDS if b else FAILS


def findings(table: pa.Table, hover_panels: set[str] | None = None) -> list[Finding]:
    """The paper's five findings computed from ``table``.

    ``hover_panels``: the scenarios whose task is a hover (findings 3 and 5; none when not
    given).
    """
    c = Costs(table)
    hover_panels = hover_panels or set()
    hover = [s for s in c.scenarios if s in hover_panels]

    def cmp(on: str, s: str, a: str, b: str, it_a=None, it_b=None) -> Comparison:
        return below(*c.paired(s, a, b, it_a, it_b), on=on)

    def f1(on: str) -> Lines:
        stat, out = STATS[on], []
        for s in c.scenarios:
            for nu in NUS:
                d, b = f"dagger-{nu}", f"batch-{nu}"
                if c.has(s, d) and c.has(s, b):
                    r = cmp(on, s, d, b)
                    dv, bv = stat(c.at(s, d)), stat(c.at(s, b))
                    line = f"{s} ν_{nu}: D {significant(dv)}, B {significant(bv)}: {r.text()}"
                    out.append(((r.outcome,), line))
        return out

    def good(stat, s, m):
        return stat(c.at(s, m)) <= GOOD_FACTOR * stat(c.at(s, "expert"))

    def f2(on: str) -> Lines:
        stat, out = STATS[on], []
        for s in c.scenarios:
            ds = [f"dagger-{nu}" for nu in NUS if c.has(s, f"dagger-{nu}")]
            bs = [f"batch-{nu}" for nu in NUS if c.has(s, f"batch-{nu}")]
            if not c.has(s, "expert") or len(ds) < 3 or len(bs) < 3:
                continue
            d_good = [m for m in ds if good(stat, s, m)]
            b_good = [m for m in bs if good(stat, s, m)]
            line = (
                f"{s}: good DAgger {len(d_good)}/3 ({', '.join(d_good) or 'none'}), "
                f"good Batch {len(b_good)}/3 ({', '.join(b_good) or 'none'}); "
                f"L {significant(stat(c.at(s, 'expert')))}"
            )
            out.append(((_ok(len(d_good) == 3 and len(b_good) == 1),), line))
        return out

    def f3(on: str) -> Lines:
        stat, out = STATS[on], []
        for s in hover:
            if not c.has(s, "expert"):
                continue
            L = stat(c.at(s, "expert"))
            for nu in NUS:
                d = f"dagger-{nu}"
                if c.has(s, d):
                    r = cmp(on, s, d, "expert")
                    dv = significant(stat(c.at(s, d)))
                    line = f"{s} D_{nu} {dv}, L {significant(L)}: {r.text()}"
                    out.append(((r.outcome,), line))
        return out

    def f4(on: str) -> Lines:
        stat, out = STATS[on], []
        for s in c.scenarios:
            ds = [f"dagger-{nu}" for nu in NUS if c.has(s, f"dagger-{nu}")]
            if not c.has(s, "abbeel") or not ds or c.last_iteration(s, "abbeel") < 2:
                continue
            first, final = stat(c.at(s, "abbeel", 2)), stat(c.at(s, "abbeel"))
            best = min(ds, key=lambda m: stat(c.at(s, m)))
            improves = cmp(on, s, "abbeel", "abbeel", None, 2)
            above = cmp(on, s, best, "abbeel")
            line = (
                f"{s}: A first {significant(first)} -> final {significant(final)}, "
                f"improves: {improves.text()}; "
                f"best DAgger {best} {significant(stat(c.at(s, best)))} below A: {above.text()}"
            )
            out.append(((improves.outcome, above.outcome), line))
        return out

    def factor(stat, s: str) -> float:
        return stat(c.at(s, "pg", 1)) / stat(c.at(s, "pg"))

    def f5(on: str) -> Lines:
        stat, out = STATS[on], []
        for s in hover:
            if not c.has(s, "pg") or not c.has(s, "expert"):
                continue
            final, L = stat(c.at(s, "pg")), stat(c.at(s, "expert"))
            ok = 1 < factor(stat, s) <= SMALL_IMPROVEMENT and final > GOOD_FACTOR * L
            line = (
                f"{s}: improvement from iteration 1 x{factor(stat, s):.3g} (small: above x1, at "
                f"most x{SMALL_IMPROVEMENT:g}); "
                f"PG {significant(stat(c.at(s, 'pg', 1)))} -> {significant(final)}, "
                f"{final / L:.3g} x L"
            )
            out.append(((_ok(ok),), line))
        return out

    good_txt = f"'good' = final cost <= {GOOD_FACTOR:g} x L's in the same panel"
    paired_txt = "paired over seeds (signed-rank test)"
    return [
        _judge(
            1,
            "For every ν and in all panels, DAgger ends below Batch with the same ν.",
            f"For each panel and ν in {{t, e, en}}: final(dagger-ν) below final(batch-ν), "
            f"{paired_txt}; holds if every comparison does.",
            f1,
        ),
        _judge(
            2,
            "DAgger reaches good performance with every ν; Batch does with only one ν per panel.",
            f"{good_txt}. Holds if, in every panel, all three DAgger curves are good and exactly "
            "one Batch curve is.",
            f2,
        ),
        _judge(
            3,
            "In hover (both delays) DAgger ends below the linearised expert L.",
            f"For each hover panel and ν: final(dagger-ν) below final(expert), {paired_txt}; "
            "holds if every comparison does.",
            f3,
        ),
        _judge(
            4,
            "Abbeel's algorithm improves on its first policy, then plateaus above DAgger.",
            f"For each panel, {paired_txt}: final(abbeel) below first(abbeel) (iteration 2, the "
            "policy fitted to the expert's data), and the best final(dagger-ν) below "
            "final(abbeel); holds if both do in every panel.",
            f4,
        ),
        _judge(
            5,
            "The policy-gradient baseline improves little with 100 samples per iteration (hover).",
            "For each hover panel: the improvement factor cost(pg, iteration 1) / final(pg) is "
            f"above 1 and at most {SMALL_IMPROVEMENT:g} ('only small improvement': it improves, "
            f"and at most halves its first policy's cost) and PG does not reach good performance "
            f"({good_txt}).",
            f5,
        ),
    ]


def findings_section(table: pa.Table, hover_panels: set[str] | None = None) -> list[str]:
    """``report.md``'s section on the findings: each verdict, how it was computed, the numbers."""
    L = [
        "## The paper's findings",
        "",
        "Verdicts on medians over seeds (a few diverging seeds dominate means); the "
        "verdict on means follows, and a line whose outcome differs on means says so. "
        "`final(m)` is the test cost at method m's last iteration; numbers are medians, "
        "`shift` the estimated per-seed difference A − B (Hodges–Lehmann; on means, the mean).",
        "",
        VERDICT_WORDS,
        "",
    ]
    seeds = len(np.unique(np.asarray(table.column("seed"))))
    if seeds < 20:
        L += [
            f"*A small run ({seeds} seeds): the findings are claims about the protocol scale "
            "(20 seeds, as in the paper); here they are computed the same way but say little.*",
            "",
        ]
    for f in findings(table, hover_panels):
        L += [
            f"{f.number}. **{f.claim}** — **{f.verdict}** (on means: {f.mean_verdict})",
            f"   - computed: {f.how}",
            *[f"   - {d}" for d in f.details],
        ]
    return [*L, ""]
