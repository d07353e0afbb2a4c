"""The README's swing-up figure: DAgger and Batch with the feature model against the linear model
on Pendulum-v1 started hanging down, and the true-model iLQR as the reference line.

    python examples/pendulum_swingup.py [--seeds 16] [--out docs/pendulum_swingup.png]

Every run is ``examples/pendulum_swingup.toml`` (a degree-4 polynomial feature model, FTRL,
iLQR seeded by an MPC episode on the learned model, the best policy so far tested); the linear
runs set ``[model] kind = "linear"`` and ``[planner] kind = "lqr"`` (the paper's agent), all
else equal. The reference is the same planner on the true dynamics
(:mod:`loopid.systems.pendulum`), flown on the real env. Prints each curve's final costs per
seed: the tested (best) policy's and the last policy's.
"""

import argparse
from pathlib import Path

import matplotlib
import numpy as np

from loopid import control
from loopid.algorithms.gym_loop import test_episodes
from loopid.experiments.families import gym
from loopid.systems import pendulum

matplotlib.use("Agg")
import matplotlib.pyplot as plt

CONFIG = Path(__file__).with_name("pendulum_swingup.toml")


def reference_cost(s: gym.GymScenario) -> float:
    """The true-model plan (as the example plans on its learned model), flown on the env."""
    dyn = lambda params, dx, du, t: pendulum.step_obs(dx, du, t)  # noqa: E731
    sol = control.plan(
        dyn, control.Penalized(pendulum.cost_obs, 2.0), pendulum.to_error(np.array([np.pi, 0.0])),
        np.full((s.horizon, 1), 0.2), iterations=s.planner_iterations,
        seed_horizon=s.planner_horizon, seed_alternatives=np.asarray(s.planner_alternatives),
    )  # fmt: skip
    system = gym.make_system(s)
    try:
        K = np.asarray(control.as_gains(sol))[None]
        return float(test_episodes(system, K, [0], 1, "reward")[0][0, 0])
    finally:
        system.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--out", default="docs/pendulum_swingup.png")
    args = ap.parse_args()
    fields, _ = gym.read_file(CONFIG)
    features = gym.build("gym", {**fields, "seeds": args.seeds, "test_trajectories": 1})
    linear = features.replace(model_kind="linear", planner_kind="lqr")
    ref = reference_cost(features)
    print(f"true-model iLQR: {ref:.1f}")
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for s, label, color in ((features, "features + iLQR", "C0"), (linear, "linear + LQR", "C1")):
        for method, style in (("dagger", "-"), ("batch", "--")):
            trace = gym.run(method, s)
            costs = trace.rows.test_cost  # [S, N], the tested policy's
            system = gym.make_system(s)
            try:  # the last policy, flown on the same test episode
                seeds = list(range(args.seeds))
                last = test_episodes(system, trace.final["K"], seeds, 1, "reward")[0][:, 0]
            finally:
                system.close()
            print(f"{label}, {method}: final costs {np.round(costs[:, -1], 1).tolist()}")
            print(f"{label}, {method}: last policy {np.round(last, 1).tolist()}")
            it = np.arange(1, costs.shape[1] + 1)
            mean = costs.mean(axis=0)
            se = costs.std(axis=0, ddof=1) / np.sqrt(costs.shape[0])
            ax.plot(it, mean, style, color=color, marker="o", ms=3, label=f"{method}, {label}")
            ax.fill_between(it, mean - se, mean + se, color=color, alpha=0.15)
    ax.axhline(ref, color="k", ls=":", lw=1.2, label=f"true-model iLQR ({ref:.0f})")
    title = f"Pendulum-v1 swing-up from hanging, {args.seeds} seeds (mean ± s.e.)"
    ax.set(xlabel="iteration (400 transitions each)",
           ylabel="best policy so far: test cost (Pendulum's own)",
           title=title)  # fmt: skip
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
