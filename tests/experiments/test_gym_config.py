"""``loopid run gym --config FILE``: the Pendulum example end to end, reproducibility, bad files."""

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from loopid.experiments.gym_config import load_config, run_gym_config
from loopid.experiments.rundir import to_toml

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pendulum.toml"


def write(tmp_path: Path, name: str, change=None, drop=()) -> Path:
    """The example with a small budget, ``change`` ({table: {key: value}}) applied and the
    ``(table, key)`` pairs in ``drop`` removed; returns the new file."""
    cfg = tomllib.loads(EXAMPLE.read_text())
    small = {
        "env": {"horizon": 100, "num_envs": 4},
        "run": {"iterations": 3, "seeds": [0, 1], "samples": 100, "test_trajectories": 4},
    }
    for extra in (small, change or {}):
        for table, values in extra.items():
            cfg.setdefault(table, {}).update(values)
    for table, key in drop:
        cfg[table].pop(key)
    path = tmp_path / name
    path.write_text(to_toml(cfg))
    return path


def by_method(table, method: str) -> np.ndarray:
    """test_cost [seeds, iterations] of one method."""
    rows = [r for r in table.to_pylist() if r["method"] == method]
    seeds = sorted({r["seed"] for r in rows})
    its = sorted({r["iteration"] for r in rows})
    cost = {(r["seed"], r["iteration"]): r["test_cost"] for r in rows}
    return np.array([[cost[s, i] for i in its] for s in seeds])


@pytest.mark.slow
def test_the_pendulum_example_runs_and_dagger_improves_on_its_first_policy(tmp_path):
    out = tmp_path / "run"
    table = run_gym_config(write(tmp_path, "p.toml"), out, quiet=True)
    for name in ("config.toml", "results.parquet", "figure.png", "cells/gym__dagger.parquet"):
        assert (out / name).exists(), name
    assert pq.read_table(out / "results.parquet").equals(table)
    assert set(table.column("method").to_pylist()) == {"dagger", "batch"}
    assert table.num_rows == 2 * 2 * 3
    dagger = by_method(table, "dagger")
    # the first policy (A = I, B = 0: it does not act) lets the pendulum fall; DAgger's last
    # one keeps it up: Pendulum's own cost per episode drops by far more than 10x on every seed
    assert (dagger[:, -1] < 0.1 * dagger[:, 0]).all()
    assert set(table.column("scenario").to_pylist()) == {"gym"}
    written = tomllib.loads((out / "config.toml").read_text())
    assert written["env"]["id"] == "Pendulum-v1" and written["run"]["seeds"] == [0, 1]
    # a rerun into the same directory resumes (nothing to do) and gives the same table
    assert run_gym_config(write(tmp_path, "p.toml"), out, quiet=True).equals(table)


@pytest.mark.slow
def test_same_configuration_and_seed_give_the_same_table(tmp_path):
    change = {"run": {"iterations": 2, "seeds": [3], "methods": ["dagger"]}}
    path = write(tmp_path, "p.toml", change)
    first = run_gym_config(path, tmp_path / "a", quiet=True)
    second = run_gym_config(path, tmp_path / "b", quiet=True)
    assert first.equals(second)


BAD = [
    ({"env": {"id": "CartPole-v1"}}, "Discrete"),
    ({"cost": {"Q": [1.0, 1.0, 0.1]}}, "Q must be 2x2"),
    ({"cost": {"R": [1.0, 2.0]}}, "R must be 1x1"),
    ({"env": {"id": "NoSuchEnv-v3"}}, "NoSuchEnv"),
    ({"cost": {"target": [0.0, 0.0, 0.0]}}, "target must be 2"),
    ({"exploration": {"gain": [[1.0, 2.0, 3.0, 4.0]]}}, "exploration.gain"),
    ({"model": {"A": np.eye(5).tolist()}}, "model A"),
    ({"run": {"methods": ["dagger-t"]}}, "dagger-t"),
    ({"env": {"colour": "red"}}, "env.colour"),
    ({"run": {"iterations": 0}}, "run.iterations"),
]


@pytest.mark.parametrize(("change", "match"), BAD, ids=[m for _, m in BAD])
def test_bad_configurations_raise_one_line(tmp_path, change, match):
    with pytest.raises(ValueError, match=match) as err:
        run_gym_config(write(tmp_path, "bad.toml", change), tmp_path / "out", quiet=True)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()  # nothing written


def test_missing_keys_and_tables(tmp_path):
    with pytest.raises(ValueError, match=r"missing key cost\.Q"):
        load_config(write(tmp_path, "a.toml", drop=[("cost", "Q")]))
    with pytest.raises(ValueError, match=r"missing key env\.id"):
        load_config(write(tmp_path, "b.toml", drop=[("env", "id")]))
    with pytest.raises(ValueError, match="exactly one of gain, policy, nominal"):
        load_config(write(tmp_path, "c.toml", drop=[("exploration", "gain")]))
    with pytest.raises(ValueError, match="does not exist"):
        load_config(tmp_path / "nothing.toml")


def test_the_command_line_exits_2_with_one_line(tmp_path):
    from loopid import cli

    source = Path(cli.__file__).read_text()
    if "gym_config" not in source:
        pytest.skip("loopid run gym --config is not wired into the CLI yet")
    path = write(tmp_path, "bad.toml", {"env": {"id": "CartPole-v1"}})
    cmd = [sys.executable, "-m", "loopid", "run", "gym", "--config", str(path)]
    cmd += ["--out", str(tmp_path / "out")]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Discrete" in lines[0]
