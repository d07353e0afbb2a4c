"""report.md and figure.png from synthetic tables: each finding's computation, the figure's
curves, ``loopid plot`` from a table alone."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from loopid.experiments import curves, report
from loopid.experiments.families.helicopter import findings
from loopid.experiments.families.helicopter.report import figure as figure2
from loopid.experiments.results import SCHEMA, read_table

PANELS = ("hover", "hover-delay", "funnel")
HOVER = {"hover", "hover-delay"}


def table_of(costs: dict[tuple[str, str], np.ndarray], samples: int = 100) -> pa.Table:
    """A results table from ``{(scenario, method): test_cost [seeds, iterations]}``."""
    cols = {f.name: [] for f in SCHEMA}
    for (s, m), c in costs.items():
        S, N = c.shape
        for seed in range(S):
            for n in range(N):
                row = dict.fromkeys(cols, 0)
                row.update(scenario=s, method=m, seed=seed, iteration=n + 1,
                           samples=n * samples, test_cost=float(c[seed, n]),
                           test_cost_median=float(c[seed, n]), diverged=int(c[seed, n] >= 1e8),
                           loss_nu=0.0, loss_policy=0.0, online_loss=0.0,
                           spectral_radius=0.5, solver_converged=True)  # fmt: skip
                for k, v in row.items():
                    cols[k].append(v)
    return pa.table({f.name: pa.array(cols[f.name], type=f.type) for f in SCHEMA}, schema=SCHEMA)


def curve(first: float, last: float, seeds: int = 5, n: int = 6, spread: float = 0.01):
    """``[seeds, n]`` costs falling geometrically from ``first`` to ``last``, seeds spread."""
    base = np.geomspace(first, last, n)
    return base[None, :] * (1 + spread * np.arange(seeds))[:, None]


def paper_like() -> dict:
    """Every finding holds: DAgger ends below L (hover) and below Batch; one good Batch; Abbeel
    improves from iteration 2 then sits above DAgger; PG stays far from L."""
    costs = {}
    for s in PANELS:
        L = 50.0
        costs[(s, "expert")] = curve(L, L)
        for nu in ("t", "e", "en"):
            costs[(s, f"dagger-{nu}")] = curve(2.6e6, 45.0 if s != "funnel" else 55.0)
        costs[(s, "batch-t")] = curve(2.6e6, 1e7)
        costs[(s, "batch-e")] = curve(2.6e6, 1.5e4)
        costs[(s, "batch-en")] = curve(2.6e6, 60.0)
        a = curve(2.6e6, 120.0)
        a[:, 1] = 1e6  # iteration 2: the first policy fitted to the expert's data
        costs[(s, "abbeel")] = a
        costs[(s, "pg")] = curve(2.6e6, 1.5e6)
    return costs


def verdicts(costs) -> list[str]:
    return [f.verdict for f in findings.findings(table_of(costs), HOVER)]


def test_a_five_seed_table_tests_the_thresholds_and_leaves_the_paired_findings_untested():
    found = findings.findings(table_of(paper_like()), HOVER)
    assert [f.number for f in found] == [1, 2, 3, 4, 5]
    # 5 seeds: the paired findings (1, 3, 4) are not tested; tests/experiments/test_findings.py
    assert [f.verdict for f in found] == ["too few seeds", "holds", *["too few seeds"] * 2, "holds"]
    assert [f.mean_verdict for f in found] == [f.verdict for f in found]


def test_medians_and_means_judged_separately():
    """Finding 1 on one ν: DAgger's median is lower but one diverging seed drags its mean above
    Batch's: holds on medians, not on means, and the detail line says so."""
    costs = paper_like()
    d = curve(2.6e6, 45.0)
    d[0, -1] = 1e8  # one seed diverges (capped)
    costs[("hover", "dagger-t")] = d
    costs[("hover", "batch-t")] = curve(2.6e6, 1e6)
    f1 = findings.findings(table_of(costs), HOVER)[0]
    assert (f1.verdict, f1.mean_verdict) == ("too few seeds", "too few seeds")  # 5 seeds
    assert any("hover ν_t" in line and "too few seeds (5 seeds)" in line for line in f1.details)


def test_missing_methods_are_not_measured():
    costs = {k: v for k, v in paper_like().items() if k[1] in ("expert", "dagger-t")}
    assert verdicts(costs) == ["not measured", "not measured", "too few seeds", "not measured",
                               "not measured"]  # fmt: skip


def test_curves_are_means_and_standard_errors_over_seeds():
    rng = np.random.default_rng(0)
    c = rng.uniform(1.0, 100.0, (7, 5))
    table = table_of({("hover", "dagger-t"): c}, samples=30)
    x, mean, se = curves.curves(table, "hover", "dagger-t")
    np.testing.assert_array_equal(x, [0, 30, 60, 90, 120])
    np.testing.assert_allclose(mean, c.mean(axis=0), rtol=1e-14)
    np.testing.assert_allclose(se, c.std(axis=0, ddof=1) / np.sqrt(7), rtol=1e-12)


def test_plot_and_report_from_a_saved_table_alone(tmp_path, monkeypatch, capsys):
    import loopid.experiments.executors as executors
    from loopid.cli import main

    monkeypatch.setattr(executors, "compile_cache", lambda path=None: "")
    table = table_of(paper_like())
    pq.write_table(table, tmp_path / "results.parquet")
    with pytest.raises(SystemExit) as e:
        main(["plot", str(tmp_path)])
    assert e.value.code == 0
    png = (tmp_path / "figure.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    text = (tmp_path / "report.md").read_text()
    assert text.count("— **holds**") == 2 and text.count("— **too few seeds**") == 3
    assert "no `config.toml`" in text
    assert read_table(tmp_path / "results.parquet").equals(table)  # the table is untouched
    # a table with more panels (say, later scenarios) gets one panel each
    more = table_of(paper_like() | {("mdp-trap", "dagger-t"): curve(10.0, 1.0)})
    figure2(more, tmp_path / "more.png")
    assert (tmp_path / "more.png").stat().st_size > 0


def test_final_cost_table_in_the_report():
    table = table_of(paper_like())
    sections = report.final_cost_sections(table)
    text = report.report_text(table, sections, config_text="[run]\nseeds = [0]\n")
    assert "### hover-delay" in text and "| batch-t | " in text
    assert "```toml\n[run]\nseeds = [0]\n```" in text
