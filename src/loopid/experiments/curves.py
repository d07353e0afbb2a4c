"""Learning curves drawn from a results table alone: one panel per scenario (in the table's
order), and in each, for every method, the mean test cost over seeds against the samples
collected so far (x linear, from 0: iteration 1 is the initial model, with no data), with a band
of ± one standard error of that mean, y on a log axis. A fixed policy (``expert``) is a flat line
at its mean over seeds. Means over seeds are what the paper plots; a few diverging seeds (capped
at the cost cap) dominate early means, which is why reports also give medians. Matplotlib's Agg
backend: no display needed.
"""

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa

from loopid.files import write_atomic_bytes


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


def figure(
    table: pa.Table,
    path: Path,
    *,
    styles: Mapping[str, tuple[str, str, str]] | None = None,
    titles: Mapping[str, str] | None = None,
) -> Path:
    """Draw the learning curves of ``table`` into ``path`` (PNG, written atomically); return
    ``path``. ``styles``: ``{method: (label, colour, line style)}`` (a method without one gets
    its own name and a colour of its own); ``titles``: ``{scenario: panel title}`` (default the
    scenario's name). A method named ``expert`` is a flat line at its mean."""
    styles = styles or {}
    titles = titles or {}
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
            label, color, ls = styles.get(m, (m, f"C{(k + 5) % 10}", "-"))
            x, mean, se = curves(table, s, m)
            if m == "expert":
                line = ax.axhline(mean.mean(), color=color, ls=ls, lw=1.2, label=label)
            else:
                (line,) = ax.plot(x, mean, color=color, ls=ls, lw=1.4, label=label)
                low = np.maximum(mean - se, mean * 1e-2)  # log axis: keep the band positive
                ax.fill_between(x, low, mean + se, color=color, alpha=0.15, lw=0)
            handles.setdefault(label, line)
        ax.set_yscale("log")
        ax.set_title(titles.get(s, s))
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
