"""A gym run's figures and report sections, read from its saved results only.

``figure.png``: mean test cost (± one standard error over seeds) against samples collected, one
line per method, log cost axis. ``trajectories.png``: each method's saved final policy at the
first seed flying that seed's first test episode, one panel per observed coordinate
(``o − o*`` against steps). ``report.md``: the final costs per method under the env's id.
"""

import io
from pathlib import Path

import numpy as np
import pyarrow as pa

from loopid.experiments.families.gym.scenario import METHODS
from loopid.experiments.report import final_cost_sections
from loopid.files import write_atomic_bytes
from loopid.settings import model_planner


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _write_png(fig, path, dpi: int) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    _pyplot().close(fig)
    write_atomic_bytes(buf.getvalue(), path)


def figure(table: pa.Table, path, configs) -> None:
    """Mean test cost (± one standard error over seeds) against samples, one line per method,
    log cost axis; written to ``path``."""
    plt = _pyplot()
    title = ", ".join(f"{s.env_id}: test cost" for s in configs.values())
    df = {name: np.asarray(table.column(name).to_pylist()) for name in table.column_names}
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, method in enumerate(dict.fromkeys(df["method"].tolist())):
        sel = df["method"] == method
        samples = np.unique(df["samples"][sel])
        costs = [df["test_cost"][sel & (df["samples"] == x)] for x in samples]
        mean = np.array([c.mean() for c in costs])
        se = np.array([c.std(ddof=1) / np.sqrt(c.size) if c.size > 1 else 0.0 for c in costs])
        style = ("-", "--", ":")[k % 3]  # dashes keep coinciding curves visible
        ax.plot(samples, mean, style, marker="o", ms=3, label=method)
        ax.fill_between(samples, np.maximum(mean - se, 1e-12), mean + se, alpha=0.25)
    ax.set_yscale("log")
    ax.set_xlabel("samples collected")
    ax.set_ylabel("mean test cost")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    _write_png(fig, path, dpi=120)


def report(table: pa.Table, configs) -> list[str]:
    """The final costs per method, under the env's id."""
    notes = {
        name: f"Env: `{s.env_id}`, horizon {s.horizon or 'the env limit'}, test cost "
        f"{s.test_cost}. {model_planner.describe(s)}"
        for name, s in configs.items()
    }
    return final_cost_sections(table, notes)


def trajectories(run_dir, configs, path) -> None:
    """``trajectories.png``: each method's saved final policy at the first seed flying that
    seed's first test episode (MPC where the cell flew MPC: :func:`.saved.saved_policy`); one
    panel per observed coordinate (``o − o*`` against steps). One gym scenario per run."""
    from loopid.algorithms.gym_loop import slot_seeds
    from loopid.algorithms.keys import HOST_TEST
    from loopid.experiments import artifacts
    from loopid.experiments.families.gym.saved import saved_policy
    from loopid.experiments.families.gym.setup import gym_setup
    from loopid.systems.gym_slots import Slot

    for name, s in configs.items():
        cells = Path(run_dir) / "cells"
        methods = [m for m in METHODS if (cells / f"{name}__{m}.json").is_file()]
        if not methods:
            continue
        flights = {}
        with gym_setup(s) as setup:
            target = np.asarray(setup.shape.target)
            for m in methods:
                _, arrays = artifacts.read(cells, name, m)
                seed = int(arrays["seeds"][0])
                slot = Slot(0, 0, slot_seeds(seed, 0, HOST_TEST, 1)[0], 0.0, False)
                first = {k: v if k.startswith("shared.") else v[:1] for k, v in arrays.items()}
                r = setup.system.rollouts([saved_policy(setup, first)], [slot])
                steps = int(r.mask[0].sum())
                flights[m] = setup.system.observed(r.x[0, :steps]) - target
        n_obs = setup.shape.n_obs
        plt = _pyplot()
        fig, axes = plt.subplots(n_obs, 1, figsize=(7, 2.2 * n_obs), squeeze=False,
                                 layout="constrained")  # fmt: skip
        for i, ax in enumerate(axes[:, 0]):
            for k, (m, o) in enumerate(flights.items()):
                ax.plot(o[:, i], color=f"C{k}", lw=1.0, label=m)
            ax.axhline(0.0, color="k", ls="--", lw=0.8)
            ax.set(ylabel=f"observed {i}: o − o*")
        axes[0, 0].set_title(f"{s.env_id}: seed {seed}'s first test episode")
        axes[-1, 0].set_xlabel("step")
        axes[0, 0].legend(fontsize=8)
        _write_png(fig, path, dpi=100)
        return
