"""Paired comparisons over seeds: is method A's cost below method B's?

Two methods run on the same seeds see the same noise, so their costs are compared seed by seed:
the costs are aligned by seed (:func:`pair`) and the test runs on the per-seed differences
``d = a - b`` (:func:`below`). On **medians**, the test is the two-sided Wilcoxon signed-rank
test (``scipy.stats.wilcoxon``) and the direction is the sign of the Hodges–Lehmann estimate of
the shift (the median of the pairwise averages ``(d_i + d_j) / 2``, ``i <= j``): the signed-rank
statistic counts the positive pairwise averages, so this sign is the statistic's own direction.
On **means**, the test is the two-sided paired t-test (``scipy.stats.ttest_rel``) and the
direction is the sign of the mean difference. Both at level :data:`ALPHA`. The signed-rank test
drops zero differences (scipy's default), so seeds on which both methods cost the same add no
evidence either way.

A comparison reads (:class:`Comparison`'s ``outcome``):

- ``holds``: significant, in the claimed direction (A below B);
- ``does not hold``: significant, the other way;
- ``tie``: not significant, or every difference zero;
- ``too few seeds``: fewer than :data:`MIN_SEEDS` paired seeds (``loopid reproduce --quick``
  runs 2), not tested.

A finding's verdict over its comparisons (:func:`combine`): ``not measured`` (no comparison),
``does not hold`` (any fails), ``too few seeds`` (every one has too few seeds), ``holds`` (every
one holds), ``holds with ties`` (none fails, at least one holds, the others tie or have too few
seeds), ``tie`` (none fails and none holds: the data decide nothing). A comparison with too few
seeds next to decided ones counts as undecided, like a tie.
"""

import warnings
from typing import NamedTuple

import numpy as np

#: Level of the two-sided paired tests: a comparison is significant when its p-value is below.
ALPHA = 0.05
#: Fewest paired seeds a comparison is tested on. With 5 pairs the two-sided exact signed-rank
#: test's smallest p-value is 2 / 2**5 = 0.0625 > :data:`ALPHA`, so it could never decide;
#: 6 pairs is the first count where it can (2 / 2**6 = 0.031).
MIN_SEEDS = 6

HOLDS = "holds"
FAILS = "does not hold"
TIE = "tie"
TOO_FEW = "too few seeds"
HOLDS_WITH_TIES = "holds with ties"
NOT_MEASURED = "not measured"

#: What the verdict words mean, for the reports (one paragraph).
VERDICT_WORDS = (
    'Each comparison "A below B" is paired over seeds (the same seeds see the same noise): a '
    f"two-sided Wilcoxon signed-rank test on the per-seed differences A − B at level "
    f"{ALPHA:.0%} (on means: a paired t-test) reads *{HOLDS}* (significant, A below B), "
    f"*{FAILS}* (significant, A above B), *{TIE}* (not significant) or *{TOO_FEW}* (fewer than "
    f"{MIN_SEEDS} paired seeds, too few for the test to reach {ALPHA:.0%}); thresholds read "
    f"*{HOLDS}* or *{FAILS}*. A finding *{HOLDS}* when every comparison does, *{HOLDS_WITH_TIES}* "
    f"when none fails and the rest tie (or have too few seeds), *{FAILS}* when any fails, "
    f"*{TIE}* when none is decided, *{TOO_FEW}* when every comparison has too few seeds."
)


class Comparison(NamedTuple):
    """One paired comparison "a below b": ``outcome`` (``holds``, ``does not hold``, ``tie``,
    ``too few seeds``), the number of paired ``seeds``, the two-sided p-value ``p`` (nan when
    not tested) and ``shift``, the estimate of ``a - b`` (Hodges–Lehmann on medians, the mean
    difference on means)."""

    outcome: str
    seeds: int
    p: float
    shift: float

    def text(self) -> str:
        """``holds (p 0.0078, 8 seeds, shift -5)``; ``too few seeds (2 seeds)``."""
        if self.outcome == TOO_FEW:
            return f"{TOO_FEW} ({self.seeds} seeds)"
        return f"{self.outcome} (p {self.p:.2g}, {self.seeds} seeds, shift {self.shift:.4g})"


def pair(
    seeds_a: np.ndarray, a: np.ndarray, seeds_b: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The costs ``a`` and ``b`` of the seeds both have, aligned, in seed order."""
    _, ia, ib = np.intersect1d(seeds_a, seeds_b, return_indices=True)
    return np.asarray(a, float)[ia], np.asarray(b, float)[ib]


def hodges_lehmann(d: np.ndarray) -> float:
    """The median of the pairwise (Walsh) averages ``(d_i + d_j) / 2``, ``i <= j``, over the
    nonzero differences (those the signed-rank test ranks; 0 when there are none)."""
    d = d[d != 0]
    if not len(d):
        return 0.0
    i, j = np.triu_indices(len(d))
    return float(np.median((d[i] + d[j]) / 2))


def below(a: np.ndarray, b: np.ndarray, on: str = "median") -> Comparison:
    """Is ``a`` below ``b``? Paired: ``a[k]`` and ``b[k]`` are the same seed's costs (see
    :func:`pair`). ``on``: ``"median"`` (signed-rank test) or ``"mean"`` (paired t-test)."""
    from scipy import stats

    d = np.asarray(a, float) - np.asarray(b, float)
    n = len(d)
    if on not in ("median", "mean"):
        raise ValueError(f"on must be 'median' or 'mean', not {on!r}")
    shift = (hodges_lehmann(d) if on == "median" else float(np.mean(d))) if n else np.nan
    if n < MIN_SEEDS:
        return Comparison(TOO_FEW, n, np.nan, shift)
    if not np.any(d):  # scipy returns nan or 1 here (or warns): no difference at all, a tie
        return Comparison(TIE, n, 1.0, 0.0)
    with warnings.catch_warnings():  # near-constant differences: precision warnings, not errors
        warnings.simplefilter("ignore")
        if on == "median":
            p = float(stats.wilcoxon(d, alternative="two-sided").pvalue)
        else:
            p = float(stats.ttest_rel(a, b, alternative="two-sided").pvalue)
    if not np.isfinite(p) or p >= ALPHA or shift == 0:
        return Comparison(TIE, n, p, shift)
    return Comparison(HOLDS if shift < 0 else FAILS, n, p, shift)


def combine(outcomes: list[str]) -> str:
    """A finding's verdict over its comparisons' (and thresholds') outcomes (module
    docstring)."""
    if not outcomes:
        return NOT_MEASURED
    if FAILS in outcomes:
        return FAILS
    if all(o == TOO_FEW for o in outcomes):
        return TOO_FEW
    if all(o == HOLDS for o in outcomes):
        return HOLDS
    return HOLDS_WITH_TIES if HOLDS in outcomes else TIE
