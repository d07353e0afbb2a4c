"""The paper's five findings (what its Figure 2 shows, section 6), each computed from a results
table and marked *holds* / *does not hold*; ``report.md`` of a helicopter run and ``study.md``
show them.

The statistics, per panel (scenario) and method, are over seeds of the test cost at the method's
**final** iteration (``final``), or at iteration 2 (``first``, the first policy fitted to data).
Each finding is judged on **medians** over seeds (a few diverging seeds, capped at ``cost_cap``,
dominate means) and, for comparison, on means. Nothing is tuned to make a finding hold.

"Good performance" (findings 2 and 5) is a fixed threshold chosen before looking at any result:
a final cost at most :data:`GOOD_FACTOR` times the linearised expert L's in the same panel.
"""

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import pyarrow as pa

#: "Good performance": final cost at most this multiple of the expert's (findings 2 and 5).
GOOD_FACTOR = 2.0
NUS = ("t", "e", "en")
STATS: dict[str, Callable[[np.ndarray], float]] = {"median": np.median, "mean": np.mean}


class Finding(NamedTuple):
    """One of the paper's five findings: ``verdict`` on medians, ``mean_verdict`` on means (each
    ``holds``, ``does not hold`` or ``not measured``), how it was computed, and the numbers."""

    number: int
    claim: str
    how: str
    verdict: str
    mean_verdict: str
    details: list[str]


class Costs:
    """Per-seed test costs of a table, by (scenario, method, iteration)."""

    def __init__(self, table: pa.Table):
        self.scenario = np.asarray(table.column("scenario").to_pylist(), dtype=object)
        self.method = np.asarray(table.column("method").to_pylist(), dtype=object)
        self.iteration = np.asarray(table.column("iteration"))
        self.cost = np.asarray(table.column("test_cost"))
        self.diverged = np.asarray(table.column("diverged"))
        self.scenarios = list(dict.fromkeys(self.scenario))
        self.methods = list(dict.fromkeys(self.method))

    def has(self, s: str, m: str) -> bool:
        return bool(np.any((self.scenario == s) & (self.method == m)))

    def last_iteration(self, s: str, m: str) -> int:
        return int(self.iteration[(self.scenario == s) & (self.method == m)].max())

    def at(self, s: str, m: str, iteration: int | None = None) -> np.ndarray:
        """``[seeds]`` test costs at ``iteration`` (default: the final one)."""
        it = self.last_iteration(s, m) if iteration is None else iteration
        return self.cost[(self.scenario == s) & (self.method == m) & (self.iteration == it)]

    def diverged_seeds(self, s: str, m: str) -> int:
        """Seeds with at least one diverged test trajectory at the final iteration."""
        sel = (self.scenario == s) & (self.method == m)
        sel &= self.iteration == self.last_iteration(s, m)
        return int(np.sum(self.diverged[sel] > 0))


def _g(x: float) -> str:
    return f"{x:.4g}"


def _verdict(results: list[bool]) -> str:
    if not results:
        return "not measured"
    return "holds" if all(results) else "does not hold"


def _judge(number, claim, how, check) -> Finding:
    """Run ``check(stat) -> (list of bools, detail lines)`` on medians and on means; the details
    are the median lines, each followed by its mean line where the outcome differs."""
    ok_med, details = check(STATS["median"])
    ok_mean, mean_details = check(STATS["mean"])
    lines = []
    for a, b, d, dm in zip(ok_med, ok_mean, details, mean_details, strict=False):
        lines.append(d if a == b else f"{d}; on means: {dm}")
    lines += details[len(ok_med) :]  # lines that judge nothing (none at present)
    return Finding(number, claim, how, _verdict(ok_med), _verdict(ok_mean), lines)


def findings(table: pa.Table, hover_panels: set[str] | None = None) -> list[Finding]:
    """The paper's five findings computed from ``table``.

    ``hover_panels``: the scenarios whose task is a hover (finding 3; none when not given).
    """
    c = Costs(table)
    hover_panels = hover_panels or set()
    hover = [s for s in c.scenarios if s in hover_panels]

    def f1(stat):
        ok, out = [], []
        for s in c.scenarios:
            for nu in NUS:
                d, b = f"dagger-{nu}", f"batch-{nu}"
                if c.has(s, d) and c.has(s, b):
                    dv, bv = stat(c.at(s, d)), stat(c.at(s, b))
                    ok.append(dv < bv)
                    out.append(f"{s} ν_{nu}: D {_g(dv)} {'<' if dv < bv else '>='} B {_g(bv)}")
        return ok, out

    def good(stat, s, m):
        return stat(c.at(s, m)) <= GOOD_FACTOR * stat(c.at(s, "expert"))

    def f2(stat):
        ok, out = [], []
        for s in c.scenarios:
            ds = [f"dagger-{nu}" for nu in NUS if c.has(s, f"dagger-{nu}")]
            bs = [f"batch-{nu}" for nu in NUS if c.has(s, f"batch-{nu}")]
            if not c.has(s, "expert") or len(ds) < 3 or len(bs) < 3:
                continue
            d_good = [m for m in ds if good(stat, s, m)]
            b_good = [m for m in bs if good(stat, s, m)]
            ok.append(len(d_good) == 3 and len(b_good) == 1)
            out.append(
                f"{s}: good DAgger {len(d_good)}/3 ({', '.join(d_good) or 'none'}), "
                f"good Batch {len(b_good)}/3 ({', '.join(b_good) or 'none'}); "
                f"L {_g(stat(c.at(s, 'expert')))}"
            )
        return ok, out

    def f3(stat):
        ok, out = [], []
        for s in hover:
            if not c.has(s, "expert"):
                continue
            L = stat(c.at(s, "expert"))
            for nu in NUS:
                d = f"dagger-{nu}"
                if c.has(s, d):
                    v = stat(c.at(s, d))
                    ok.append(v < L)
                    out.append(f"{s} D_{nu} {_g(v)} {'<' if v < L else '>='} L {_g(L)}")
        return ok, out

    def f4(stat):
        ok, out = [], []
        for s in c.scenarios:
            ds = [f"dagger-{nu}" for nu in NUS if c.has(s, f"dagger-{nu}")]
            if not c.has(s, "abbeel") or not ds or c.last_iteration(s, "abbeel") < 2:
                continue
            first, final = stat(c.at(s, "abbeel", 2)), stat(c.at(s, "abbeel"))
            best = min(ds, key=lambda m: stat(c.at(s, m)))
            bv = stat(c.at(s, best))
            ok.append(final < first and final > bv)
            out.append(
                f"{s}: A first {_g(first)} -> final {_g(final)} "
                f"({'improves' if final < first else 'no improvement'}); "
                f"best DAgger {best} {_g(bv)} ({'A above' if final > bv else 'A not above'})"
            )
        return ok, out

    def f5(stat):
        ok, out = [], []
        for s in c.scenarios:
            if not c.has(s, "pg") or not c.has(s, "expert"):
                continue
            first, final = stat(c.at(s, "pg", 1)), stat(c.at(s, "pg"))
            L = stat(c.at(s, "expert"))
            ok.append(final > GOOD_FACTOR * L)
            out.append(
                f"{s}: PG {_g(first)} -> {_g(final)} (x{first / final:.3g} better), "
                f"{final / L:.3g} x L"
            )
        return ok, out

    good_txt = f"'good' = final cost <= {GOOD_FACTOR:g} x L's in the same panel"
    return [
        _judge(
            1,
            "For every ν and in all panels, DAgger ends below Batch with the same ν.",
            "For each panel and ν in {t, e, en}: final(dagger-ν) < final(batch-ν); "
            "holds if every comparison does.",
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
            "For each hover panel and ν: final(dagger-ν) < final(expert); holds if every one does.",
            f3,
        ),
        _judge(
            4,
            "Abbeel's algorithm improves on its first policy, then plateaus above DAgger.",
            "For each panel: final(abbeel) < first(abbeel) (iteration 2, the policy fitted to "
            "the expert's data) and final(abbeel) > the best final(dagger-ν); holds if both do "
            "in every panel.",
            f4,
        ),
        _judge(
            5,
            "The policy-gradient baseline improves little with 100 samples per iteration.",
            f"For each panel: PG does not reach good performance ({good_txt}): final(pg) > "
            f"{GOOD_FACTOR:g} x final(expert); the improvement from iteration 1 is shown.",
            f5,
        ),
    ]


def findings_section(table: pa.Table, hover_panels: set[str] | None = None) -> list[str]:
    """``report.md``'s section on the findings: each verdict, how it was computed, the numbers."""
    L = [
        "## The paper's findings",
        "",
        "Verdicts on medians over seeds (a few diverging seeds dominate means); the "
        "verdict on means follows, and a comparison whose outcome differs on means says so. "
        "`final(m)` is the test cost at method m's last iteration; numbers are medians.",
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
