"""The paper's Figure 2, drawn from a results table alone (``loopid plot DIR``).

One panel per scenario in the table (in the table's order; the paper's three are hover, hover
with delay 1, nose-in funnel, top to bottom). In each: for every method, the mean test cost over
seeds against the samples collected so far (x linear, from 0: iteration 1 is the initial model,
with no data), a band of ± one standard error of that mean, y on a log axis. The linearised
expert L is a flat line (its mean over seeds). Means over seeds are what the paper plots; a few
diverging seeds (capped at ``cost_cap``) dominate early means, which is why the report also gives
medians. Matplotlib's Agg backend: no display needed.
"""

from pathlib import Path

import numpy as np
import pyarrow as pa

from loopid.experiments.results import read_table
from loopid.files import write_atomic_bytes

#: Label, colour and line style per method (the paper's legend names).
STYLE = {
    "dagger-t": ("$D_t$", "C0", "-"),
    "dagger-e": ("$D_e$", "C1", "-"),
    "dagger-en": ("$D_{en}$", "C2", "-"),
    "batch-t": ("$B_t$", "C0", "--"),
    "batch-e": ("$B_e$", "C1", "--"),
    "batch-en": ("$B_{en}$", "C2", "--"),
    "abbeel": ("$A$", "C3", "-."),
    "expert": ("$L$", "black", "-"),
    "pg": ("PG", "C4", ":"),
    # the reading study's other readings of the policy gradient
    "pg (transitions)": ("PG, transitions", "C5", "-"),
    "pg (descent)": ("PG, descent", "C6", "-"),
}
TITLES = {"hover": "Hover", "hover-delay": "Hover, delay 1", "funnel": "Nose-in funnel"}


def _in_order(values) -> list[str]:
    return list(dict.fromkeys(values))


def curves(table: pa.Table, scenario: str, method: str):
    """``(samples [N], mean [N], se [N])`` of one cell: test cost over seeds per iteration."""
    cols = table.select(["scenario", "method", "seed", "iteration", "samples", "test_cost"])
    mask = (np.asarray(cols.column("scenario")) == scenario) & (
        np.asarray(cols.column("method")) == method
    )
    it = np.asarray(cols.column("iteration"))[mask]
    cost = np.asarray(cols.column("test_cost"))[mask]
    samples = np.asarray(cols.column("samples"))[mask]
    its = np.unique(it)
    per = [cost[it == i] for i in its]
    mean = np.array([c.mean() for c in per])
    se = np.array([c.std(ddof=1) / np.sqrt(c.size) if c.size > 1 else 0.0 for c in per])
    x = np.array([samples[it == i][0] for i in its])
    return x, mean, se


def figure(table: pa.Table, path: Path) -> Path:
    """Draw the figure of ``table`` into ``path`` (PNG, written atomically); return ``path``."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import io

    import matplotlib.pyplot as plt

    if table.num_rows == 0:
        raise ValueError("the results table is empty: nothing to plot")
    scenarios = _in_order(table.column("scenario").to_pylist())
    methods = _in_order(table.column("method").to_pylist())
    fig, axes = plt.subplots(
        len(scenarios), 1, figsize=(7.0, 3.0 * len(scenarios)), squeeze=False, layout="constrained"
    )
    handles = {}
    for ax, s in zip(axes[:, 0], scenarios, strict=True):
        present = set(np.asarray(table.column("method"))[np.asarray(table.column("scenario")) == s])
        for k, m in enumerate(methods):
            if m not in present:
                continue
            label, color, ls = STYLE.get(m, (m, f"C{(k + 5) % 10}", "-"))
            x, mean, se = curves(table, s, m)
            if m == "expert":
                line = ax.axhline(mean.mean(), color=color, ls=ls, lw=1.2, label=label)
            else:
                (line,) = ax.plot(x, mean, color=color, ls=ls, lw=1.4, label=label)
                low = np.maximum(mean - se, mean * 1e-2)  # log axis: keep the band positive
                ax.fill_between(x, low, mean + se, color=color, alpha=0.15, lw=0)
            handles.setdefault(label, line)
        ax.set_yscale("log")
        ax.set_title(TITLES.get(s, s))
        ax.set_ylabel("mean test cost")
        ax.grid(True, which="major", alpha=0.3)
    axes[-1, 0].set_xlabel("samples collected")
    fig.legend(handles.values(), handles.keys(), loc="outside right center")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    path = Path(path)
    write_atomic_bytes(buf.getvalue(), path)
    return path


def load_results(run_dir: Path) -> pa.Table:
    """``run_dir/results.parquet``; a missing or unreadable table raises ValueError."""
    run_dir = Path(run_dir)
    results = run_dir / "results.parquet"
    if not results.is_file():
        raise ValueError(f"{str(run_dir)!r} holds no results.parquet")
    try:
        return read_table(results)
    except (pa.ArrowException, OSError) as e:
        raise ValueError(f"{str(results)!r} is not a readable Parquet table ({e})") from None


def plot_dir(run_dir: Path) -> Path:
    """Remake ``run_dir/figure.png`` from ``run_dir/results.parquet`` alone; return its path."""
    return figure(load_results(run_dir), Path(run_dir) / "figure.png")
