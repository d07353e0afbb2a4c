"""Play the engineer: identify a cart you cannot step from Python, one round at a time.

The cart (:class:`Rig`) stands for a real machine: this script may only run a controller on it
for whole episodes and read the log, as a person at a test bench would. Each round it

1. reads ``round.md``'s plan (how many rows from the current controller, how many from ν),
2. runs episodes of the current controller and of ν (a weak hand-tuned gain with noise),
   draws that many transitions uniformly among their steps, and logs them to Parquet,
3. calls ``loopid round update`` (the Python API, or the command with ``--cli``),

and prints each controller's cost on the rig. Run:  python examples/rounds/engineer.py [--cli]
(``--config examples/rounds/rig_features.toml``: the richer model class ``round.md`` suggests).
"""

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from loopid import rounds
from loopid.rounds.report import split

HERE = Path(__file__).resolve().parent
STATES, ACTIONS = ("position", "velocity"), ("force",)
Q, R, TARGET = np.diag([1.0, 0.1]), np.diag([0.01]), np.array([2.0, 0.0])


class Rig:
    """The machine: a cart with drag, a motor of unknown gain and a slope pulling it (a constant
    push the engineer does not know about), 0.1 s steps. Only ``run`` is available."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def step(self, x, u):
        pos, vel = x
        force = 3.0 * np.tanh(u[0] / 3.0)  # the motor saturates at 3 N
        acc = 0.8 * force - 0.5 * vel * abs(vel) - 0.6 + 0.05 * self.rng.standard_normal()
        return np.array([pos + 0.1 * vel, vel + 0.1 * acc])

    def run(self, act, horizon: int):
        """One episode from the start distribution: states [T+1, 2], actions [T, 1]."""
        x = self.rng.uniform([-1.0, -0.5], [1.0, 0.5])
        X, U = [x], []
        for t in range(horizon):
            u = act(x, t)
            x = self.step(x, u)
            X.append(x)
            U.append(u)
        return np.array(X), np.array(U)


def episode_cost(X, U) -> float:
    """The design cost of an episode, about the target (2 m, at rest)."""
    E = X[:-1] - TARGET
    return float(np.einsum("ti,ij,tj->", E, Q, E) + np.einsum("ti,ij,tj->", U, R, U))


def collect(rig: Rig, act, rows: int, horizon: int, source: str, rng, tag: str = "") -> dict:
    """``rows`` transitions drawn uniformly among the steps of enough episodes of ``act``,
    with the optional ``episode`` (labelled ``SOURCE-TAG-K``), ``t`` and ``terminated`` columns."""
    episodes = [rig.run(act, horizon) for _ in range(max(1, -(-2 * rows // horizon)))]
    X = np.concatenate([e[0][:-1] for e in episodes])
    Xn = np.concatenate([e[0][1:] for e in episodes])
    U = np.concatenate([e[1] for e in episodes])
    pick = rng.choice(X.shape[0], size=rows, replace=False)
    cols = {s: X[pick, i] for i, s in enumerate(STATES)}
    cols |= {a: U[pick, i] for i, a in enumerate(ACTIONS)}
    cols |= {f"next_{s}": Xn[pick, i] for i, s in enumerate(STATES)}
    # which episode and step each row comes from; the cart never ends an episode early, which
    # `terminated` says (rows drawn among the steps may miss an episode's last step)
    episode, t = np.divmod(pick, horizon)
    cols |= {"episode": [f"{source}-{tag}-{e}" for e in episode], "t": t}
    return cols | {"terminated": np.zeros(rows, bool), "source": [source] * rows}


def nu(rng):
    """The exploration distribution: a weak gain with Gaussian noise on the force."""
    return lambda x, t: np.array([-2.0 * x[0] - 0.5 * x[1] + 0.05 * rng.standard_normal()])


def main(argv=None) -> list[float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--cli", action="store_true", help="call the loopid command")
    parser.add_argument("--dir", type=Path, default=None, help="round directory (default: temp)")
    parser.add_argument("--config", type=Path, default=HERE / "rig.toml", help="round config")
    args = parser.parse_args(argv)
    root = args.dir or Path(tempfile.mkdtemp()) / "rig"
    if root.exists():
        shutil.rmtree(root)
    rounds.init(root, args.config)
    config = rounds.read_config(args.config)
    rig, rng = Rig(seed=0), np.random.default_rng(1)
    test = Rig(seed=2)  # the same 20 test episodes for every controller
    costs = []
    for n in range(1, args.rounds + 2):
        policy = rounds.controller(root)
        test.rng = np.random.default_rng(2)
        costs.append(np.mean([episode_cost(*test.run(policy.action, 50)) for _ in range(20)]))
        print(f"controller {n}: mean cost {costs[-1]:9.3f} over 20 test runs")
        if n > args.rounds:
            break
        pol, from_nu = split(config, n)
        parts = (
            [collect(rig, policy.action, pol, config.horizon, "policy", rng, f"{n}")] if pol else []
        )
        parts += (
            [collect(rig, nu(rng), from_nu, config.horizon, "nu", rng, f"{n}")] if from_nu else []
        )
        table = pa.concat_tables([pa.table(p) for p in parts])
        path = root.parent / f"round-{n}.parquet"
        pq.write_table(table, path)
        if args.cli:
            cmd = [sys.executable, "-m", "loopid", "round", "update", str(root), str(path)]
            subprocess.run(cmd, check=True, stderr=subprocess.DEVNULL)
        else:
            rounds.update(root, path)
    header = rounds.export(root, "c")
    print(f"controller {n} as C: {header}")
    print((root / "round.md").read_text().split("## Model-class check")[1].strip())
    return costs


if __name__ == "__main__":
    main()
