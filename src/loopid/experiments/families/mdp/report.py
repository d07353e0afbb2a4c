"""A finite-MDP run's figure, report section and ``trajectories.png``, from its saved results.

``figure.png`` (:func:`mdp_figure`): per scenario, J against samples (mean ``j_policy`` per
method, min-max over seeds shaded, J*) beside the true gap ``j_best − J*`` and the bound's gap
``bound − J*``. ``report.md`` (:func:`report`): the final exact quantities per scenario and
method and whether ``J(best) <= bound`` held on every row. ``trajectories.png``
(:func:`trajectories`): each method's saved final policy's exact discounted state occupancy
``D_{μ,π}(s)``, with the optimal policy's.
"""

from pathlib import Path

import jax
import numpy as np

from loopid.experiments.families.mdp.scenario import MDP_METHODS, scenario_mdp

_LABEL = {"dagger": "DAgger", "batch": "Batch", "abbeel": "Abbeel"}
_COLOR = {"dagger": "C0", "batch": "C3", "abbeel": "C2"}


def _column(table, name) -> np.ndarray:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False))


def mdp_figure(table, path) -> Path:
    """Plot J against samples per MDP scenario in ``table`` (a results ``pyarrow.Table``).

    Left panel per scenario: mean ``j_policy`` per method (shaded: min-max over seeds) and
    J*. Right panel: the true gap ``j_best − J*`` (solid) beside the bound's gap ``bound − J*``
    (dashed) per method, log scale (a zero gap is drawn at 1e-6; an infinite bound as a
    triangle at the top edge). Saves to
    ``path`` (format from its suffix) and returns the path.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    needed = ("scenario", "method", "samples", "j_policy", "j_best", "j_optimal", "bound")
    missing = [c for c in needed if c not in table.column_names]
    if missing:
        raise ValueError(f"table has no MDP diagnostics column(s) {missing}")
    cols = {c: _column(table, c) for c in needed}
    keep = ~np.isnan(cols["j_policy"].astype(np.float64))
    cols = {c: v[keep] for c, v in cols.items()}
    scenarios = sorted(set(cols["scenario"]))
    if not scenarios:
        raise ValueError("table holds no MDP rows")
    fig, axes = plt.subplots(len(scenarios), 2, figsize=(10, 3.6 * len(scenarios)), squeeze=False)
    for row, name in enumerate(scenarios):
        ax_j, ax_gap = axes[row]
        in_s = cols["scenario"] == name
        j_star = float(np.mean(cols["j_optimal"][in_s]))
        top = 1.0
        for method in sorted(set(cols["method"][in_s])):
            sel = in_s & (cols["method"] == method)
            x = np.unique(cols["samples"][sel])

            def per_x(v, reduce, sel=sel, x=x):
                return np.array([reduce(v[sel & (cols["samples"] == xi)]) for xi in x])

            color, label = _COLOR.get(method, "k"), _LABEL.get(method, method)
            j = cols["j_policy"]
            ax_j.plot(x, per_x(j, np.mean), color=color, label=label)
            ax_j.fill_between(x, per_x(j, np.min), per_x(j, np.max), color=color, alpha=0.2)
            gap = np.maximum(per_x(cols["j_best"], np.mean) - j_star, 1e-6)
            bound = per_x(cols["bound"], np.mean) - j_star
            finite = np.isfinite(bound)
            top = max(top, float(np.max(bound[finite], initial=1.0)), float(gap.max()))
            ax_gap.plot(x, gap, color=color, label=f"{label}: J(best) − J*")
            ax_gap.plot(
                x[finite], bound[finite], color=color, ls="--", label=f"{label}: bound − J*"
            )
            if (~finite).any():
                ax_gap.plot(
                    x[~finite], np.full((~finite).sum(), top), color=color, ls="", marker="^"
                )
        ax_j.axhline(j_star, color="k", ls=":", label="J*")
        ax_j.set(title=f"{name}: J of the learnt policy", xlabel="samples", ylabel="J_μ(π)")
        ax_gap.set(title=f"{name}: gap and bound", xlabel="samples", ylabel="gap", yscale="log")
        ax_j.legend(fontsize=8)
        ax_gap.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def report(table, configs=None) -> list[str]:
    """``report.md``'s section of an MDP run: per scenario and method, the final mean J of the
    learnt policy, of the best policy so far, J* and the bound (means over seeds), and whether
    J(best) <= bound held on every row."""
    lines = ["## Exact quantities", ""]
    lines += [
        "Exact quantities (no sampling in the evaluation): J_μ(π) of the learnt policy,",
        "J of the best policy so far, the optimum J* and the right-hand side of the",
        "paper's bound for π' = π* (Theorem 3.1 while only ν data was seen, Lemma 4.1",
        "once a policy contributed). Means over seeds at the last iteration.",
        "",
    ]
    lines += [
        "| scenario | method | J(π_N) | J(best) | J* | bound | j_best ≤ bound, all rows |",
        "|---|---|---|---|---|---|---|",
    ]
    cols = {
        c: _column(table, c)
        for c in ("scenario", "method", "iteration", "j_policy", "j_best", "j_optimal", "bound")
    }
    for name in sorted(set(cols["scenario"])):
        for method in sorted(set(cols["method"][cols["scenario"] == name])):
            sel = (cols["scenario"] == name) & (cols["method"] == method)
            last = sel & (cols["iteration"] == cols["iteration"][sel].max())
            holds = bool(np.all(cols["j_best"][sel] <= cols["bound"][sel] + 1e-9))
            vals = [
                float(np.mean(cols[c][last])) for c in ("j_policy", "j_best", "j_optimal", "bound")
            ]
            lines.append(
                f"| {name} | {method} | "
                + " | ".join(f"{v:.4g}" for v in vals)
                + f" | {'yes' if holds else 'NO'} |"
            )
    return [*lines, ""]


def trajectories(run_dir, configs, path) -> None:
    """``trajectories.png`` of a finite MDP run: where each method's saved final policy (first
    seed) goes, its exact discounted state occupancy ``D_{μ,π}(s)`` (a finite MDP has no path in
    space; this is the distribution its episodes visit), one panel per scenario, with the
    optimal policy's for reference."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from loopid.control.value_iteration import occupancy, value_iteration
    from loopid.experiments import artifacts
    from loopid.files import write_atomic_bytes

    cells = Path(run_dir) / "cells"
    panels = [(n, s) for n, s in configs.items() if list(cells.glob(f"{n}__*.json"))]
    if not panels:
        return
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * len(panels)), squeeze=False,
                             layout="constrained")  # fmt: skip
    for ax, (name, s) in zip(axes[:, 0], panels, strict=True):
        mdp = scenario_mdp(s)  # the MDP alone, not its loop program
        optimal = value_iteration(mdp.P, mdp.C, mdp.gamma, tol=1e-12, max_iter=100_000).policy
        policies = {"optimal": np.asarray(optimal)}
        for m in MDP_METHODS:
            if (cells / f"{name}__{m}.json").is_file():
                _, arrays = artifacts.read(cells, name, m)
                policies[m] = arrays["K"][0]
        width = 0.8 / len(policies)
        states = np.arange(mdp.n_states)
        for k, (label, K) in enumerate(policies.items()):
            d = np.asarray(occupancy(mdp.P, mdp.mu, mdp.gamma, jax.numpy.asarray(K))).sum(axis=1)
            ax.bar(states + (k - (len(policies) - 1) / 2) * width, d / d.sum(), width,
                   color="k" if label == "optimal" else f"C{k - 1}", label=label)  # fmt: skip
        ax.set(xlabel="state", ylabel="D_μ,π(s)", title=f"{name}: where the final policies go")
        ax.legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    write_atomic_bytes(buf.getvalue(), path)
