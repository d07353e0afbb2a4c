"""The gym family through the one pipeline: the Pendulum example end to end with workers and
Ray, resume after a kill, the common options, bad files (one line, nothing written)."""

import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from conftest import cli
from loopid.cli import scenario_from_options
from loopid.experiments.execute import check_cells
from loopid.experiments.families import gym
from loopid.experiments.rundir import to_toml

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pendulum.toml"


def write(tmp_path: Path, name: str, change=None, drop=()) -> Path:
    """The example with a small budget, ``change`` ({table: {key: value}}) applied and the
    ``(table, key)`` pairs in ``drop`` removed; returns the new file."""
    cfg = tomllib.loads(EXAMPLE.read_text())
    small = {"env": {"horizon": 100, "num_envs": 4}, "run": {"samples": 100,
             "test_trajectories": 4}}  # fmt: skip
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
def test_pendulum_with_workers_and_ray_gives_one_table(tmp_path, cache):
    """``loopid run gym --config FILE --seeds 2 --iterations 3 --workers 2`` writes the four
    files; ``--workers 1`` and ``--executor ray`` give the same table."""
    path = write(tmp_path, "p.toml", {"run": {"methods": ["dagger", "batch", "abbeel"]}})
    args = ["run", "gym", "--config", path, "--seeds", "2", "--iterations", "3", "--quiet"]
    r = cli(*args, "--workers", "2", "--out", tmp_path / "two", cache=cache)
    assert r.returncode == 0, r.stderr
    for name in ("config.toml", "results.parquet", "figure.png", "report.md", "trajectories.png"):
        assert (tmp_path / "two" / name).exists(), name
    for method in ("dagger", "batch", "abbeel"):  # each cell's saved policies and models
        assert (tmp_path / "two" / "cells" / f"gym__{method}.npz").is_file()
    table = pq.read_table(tmp_path / "two" / "results.parquet")
    assert table.num_rows == 3 * 2 * 3 and set(table["scenario"].to_pylist()) == {"gym"}
    written = tomllib.loads((tmp_path / "two" / "config.toml").read_text())
    assert written["run"]["family"] == "gym" and written["run"]["seeds"] == 2
    assert written["scenario"]["gym"]["iterations"] == 3  # the option won over the file's 10
    assert "| dagger |" in (tmp_path / "two" / "report.md").read_text()
    # the first policy (A = I, B = 0: it does not act) lets the pendulum fall; DAgger's third
    # one keeps it up: Pendulum's own cost per episode drops more than 10x on every seed
    dagger = by_method(table, "dagger")
    assert (dagger[:, -1] < 0.1 * dagger[:, 0]).all()
    r = cli(*args, "--workers", "1", "--out", tmp_path / "one", cache=cache)
    assert r.returncode == 0, r.stderr
    assert pq.read_table(tmp_path / "one" / "results.parquet").equals(table)
    pytest.importorskip("ray")
    r = cli(*args, "--executor", "ray", "--out", tmp_path / "ray", cache=cache)
    assert r.returncode == 0, r.stderr
    assert pq.read_table(tmp_path / "ray" / "results.parquet").equals(table)


@pytest.mark.slow
def test_killed_gym_run_resumes_to_the_same_table(tmp_path, cache):
    path = write(tmp_path, "p.toml", {"run": {"iterations": 3, "seeds": [3, 5]}})
    args = ["run", "gym", "--config", path, "--workers", "1", "--quiet"]
    r = cli(*args, "--out", tmp_path / "whole", cache=cache)
    assert r.returncode == 0, r.stderr
    expected = pq.read_table(tmp_path / "whole" / "results.parquet")
    killed = tmp_path / "killed"
    p = cli(*args, "--out", killed, cache=cache, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not list(killed.glob("cells/*.parquet")) and p.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert [f.name for f in killed.glob("cells/*.parquet")] == ["gym__dagger.parquet"]
    r = cli(*args, "--out", killed, cache=cache)
    assert r.returncode == 0, r.stderr
    assert pq.read_table(killed / "results.parquet").equals(expected)


def build(path, options=None, sets=()):
    family, s, methods = scenario_from_options("gym", path, options or {}, list(sets))
    check_cells([s], methods or family.default_methods(s), None)
    return s, methods


def test_options_and_set_win_over_the_file(tmp_path):
    s, methods = build(write(tmp_path, "p.toml"), {"seeds": 3}, ["action_std=0.25"])
    assert (s.seeds, s.action_std, s.iterations, methods) == (3, 0.25, 10, ["dagger", "batch"])
    assert s.reset_options == gym.GymScenario(**s.to_dict()).reset_options  # round trip
    assert gym.GymScenario(**s.to_dict()) == s and hash(s) == hash(gym.GymScenario(**s.to_dict()))


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
    ({"run": {"iterations": 0}}, "iterations"),
    ({"env": {"vectorization": "threads"}}, "vectorization"),
    ({"run": {"test_policy": "mixture"}}, "test_policy"),
    (
        {"run": {"test_policy": "best"}, "model": {"kind": "features"}, "planner": {"kind": "mpc"}},
        "flies the last policy only",
    ),
]


@pytest.mark.parametrize(("change", "match"), BAD, ids=[m for _, m in BAD])
def test_bad_configurations_raise_one_line(tmp_path, change, match):
    with pytest.raises(ValueError, match=match) as err:
        build(write(tmp_path, "bad.toml", change))
    assert "\n" not in str(err.value)


def test_missing_keys_and_tables(tmp_path):
    with pytest.raises(ValueError, match=r"missing key cost\.Q"):
        build(write(tmp_path, "a.toml", drop=[("cost", "Q")]))
    with pytest.raises(ValueError, match=r"missing key env\.id"):
        build(write(tmp_path, "b.toml", drop=[("env", "id")]))
    with pytest.raises(ValueError, match="exactly one of gain, policy, nominal"):
        build(write(tmp_path, "c.toml", drop=[("exploration", "gain")]))
    with pytest.raises(ValueError, match="cannot read"):
        build(tmp_path / "nothing.toml")
    with pytest.raises(ValueError, match="needs --config"):
        build(None)


def test_the_command_line_exits_2_with_one_line_and_writes_nothing(tmp_path):
    path = write(tmp_path, "bad.toml", {"env": {"id": "CartPole-v1"}})
    cmd = [sys.executable, "-m", "loopid", "run", "gym", "--config", str(path)]
    cmd += ["--out", str(tmp_path / "out")]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Discrete" in lines[0]
    assert not (tmp_path / "out").exists()


def test_animate_a_gym_run_from_the_envs_own_frames(tmp_path, capsys):
    """``loopid animate`` on a gym run: the env's rgb_array frames, the methods side by side."""
    pytest.importorskip("pygame")
    from PIL import Image

    from loopid.cli import main

    path = write(tmp_path, "p.toml", {"run": {"iterations": 2, "seeds": [0]}})
    out = tmp_path / "run"
    gif = str(tmp_path / "a.gif")
    for args in (["run", "gym", "--config", str(path), "--workers", "1", "--quiet",
                  "--out", str(out)],
                 ["animate", str(out), "--method", "dagger,batch", "--out", gif]):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(args)
        assert e.value.code == 0
    with Image.open(tmp_path / "a.gif") as im:
        width, height = im.size
        assert im.format == "GIF" and width == 2 * height  # two square Pendulum frames
    assert (out / "trajectories.png").is_file()
    info = __import__("json").loads((out / "cells" / "gym__dagger.json").read_text())
    assert info["config"]["observe"] == [1, 2] and info["config"]["target"] == [0.0, 0.0]
    # the saved controllers on another env id (transfer): here Pendulum-v1 itself, by name
    with pytest.raises(SystemExit) as e:
        main(["evaluate", str(out), "--env", "Pendulum-v1", "--episodes", "3"])
    assert e.value.code == 0
    rows = pq.read_table(out / "evaluate.parquet").to_pylist()
    assert {r["env"] for r in rows} == {"Pendulum-v1"} and len(rows) == 2
    assert all(r["mean"] < 1.0 for r in rows)  # both hold the pendulum up on fresh episodes


def test_every_entry_point_builds_the_env_once_and_closes_it(tmp_path, monkeypatch):
    """``run``, ``check``, ``shared``, ``load`` and ``evaluate`` each open one env (the
    scenario's :class:`~loopid.experiments.families.gym.setup.Setup`) and close it."""
    from loopid.experiments.families.gym import env as gym_env

    opened, closed = [], []

    class Counted(gym_env.GymSystem):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            opened.append(self)

        def close(self):
            closed.append(self)
            super().close()

    monkeypatch.setattr(gym_env, "GymSystem", Counted)
    small = {"seeds": 1, "iterations": 2, "samples": 50, "test_trajectories": 1}
    _, s, _ = scenario_from_options("gym", write(tmp_path, "p.toml"), small, [])
    T, m, n = s.horizon, 1, 3
    calls = [
        lambda: gym.run("dagger", s),
        lambda: gym.check(s),
        lambda: gym.shared(s, "dagger"),
        lambda: gym.load(s, "dagger", {"K": np.zeros((T, m, n))}),
        lambda: gym.evaluate(s, {"K": np.zeros((1, T, m, n))}, [0], 1),
    ]
    for k, call in enumerate(calls, start=1):
        call()
        assert len(opened) == k and closed == opened
