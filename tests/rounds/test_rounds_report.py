"""round.md: the next round's split by method, the model-class check, and the episodes (a
controller that falls on every episode is said to, from the ``episode`` column)."""

import numpy as np
import pyarrow as pa
import pytest
from rounds_helpers import transitions, write_config, write_round

from loopid import rounds
from loopid.rounds import read_config
from loopid.rounds.data import RoundData
from loopid.rounds.episodes import sentence, summary
from loopid.rounds.report import HIGH, check, split


def test_split_follows_the_method(tmp_path):
    def config(method):
        path = tmp_path / f"{method}.toml"
        return read_config(write_config(path, samples=9, rounds=f'method = "{method}"'))

    dagger, batch, abbeel = (config(m) for m in ("dagger", "batch", "abbeel"))
    assert [split(dagger, n) for n in (1, 2, 5)] == [(4, 5), (4, 5), (4, 5)]  # round(4.5) = 4
    assert [split(batch, n) for n in (1, 2, 5)] == [(0, 9)] * 3
    assert [split(abbeel, n) for n in (1, 2, 5)] == [(0, 9), (9, 0), (9, 0)]


def row(relative, cost):
    return {"relative": relative, "policy_cost": cost}


def test_the_model_class_check():
    assert check([row(1.0, 5.0)]).startswith("Too early")
    poor = check([row(2 * HIGH, 5.0), row(3 * HIGH, 5.0)])
    assert poor.startswith("**The model class looks too poor.**") and "richer model class" in poor
    assert check([row(2 * HIGH, 5.0), row(3 * HIGH, 4.0)]).startswith("The aggregate loss is high")
    assert check([row(HIGH / 2, 5.0), row(HIGH / 3, 5.0)]).startswith("The model class fits")


def _falling_round(rng, policy, rows=40):
    """Half the rows from whole episodes of ``policy`` on an unstable pendulum that falls past
    |tilt| = 0.2 (the last episode cut to fit), half from ν; with ``episode`` and ``t``."""
    F, G = np.array([[1.0, 0.05], [0.3155, 0.98]]), np.array([0.0, 0.05])
    cols = {k: [] for k in ("p", "v", "f", "next_p", "next_v", "source", "episode", "t")}
    e = 0
    while len(cols["p"]) < rows // 2:
        x = np.array([rng.uniform(0.1, 0.15), 0.0])
        for t in range(30):
            if len(cols["p"]) == rows // 2 or abs(x[0]) > 0.2:
                break
            u = float(policy.action(x, t)[0])
            xn = F @ x + G * u
            for k, v in zip(
                cols, (x[0], x[1], u, xn[0], xn[1], "policy", f"pi-{e}", t), strict=True
            ):
                cols[k].append(v)
            x = xn
        e += 1
    nu = transitions(rng, rows // 2)
    for k in ("p", "v", "f", "next_p", "next_v"):
        cols[k] += list(nu[k])
    cols["source"] += ["nu"] * (rows // 2)
    cols["episode"] += [f"nu-{i}" for i in range(rows // 2)]
    cols["t"] += [0] * (rows // 2)
    return cols


def test_round_md_says_when_every_episode_fell(tmp_path):
    rng = np.random.default_rng(8)
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml"))  # controller 1: A = I, B = 0, K = 0
    cols = _falling_round(rng, rounds.controller(root))
    done = rounds.update(root, write_round(tmp_path / "r.parquet", cols))
    ep = done.row["episodes"]
    policy = [i for i, s in enumerate(cols["source"]) if s == "policy"]
    labels = list(dict.fromkeys(cols["episode"][i] for i in policy))
    assert ep["episodes"] == len(labels) > 1 and ep["ended_early"] == ep["episodes"]
    for label, length, cost in zip(labels, ep["lengths"], ep["costs"], strict=True):
        mine = [i for i in policy if cols["episode"][i] == label]
        assert length == max(cols["t"][i] for i in mine) + 1 < 30
        e = np.array([[cols["p"][i] - 0.5, cols["v"][i]] for i in mine])  # o − o*
        d = np.array([cols["f"][i] - 0.1 for i in mine])  # a − a_op
        assert cost == pytest.approx(np.sum(e**2 @ [1.0, 0.1] + 0.01 * d**2), rel=1e-12)
    text = (root / "round.md").read_text()
    k = ep["episodes"]
    assert f"| 1 | {k} | {k} |" in text
    assert f"**Controller 1 ended every one of its {k} episodes early**" in text


def test_episodes_to_the_horizon_or_marked_terminated(tmp_path):
    config = read_config(write_config(tmp_path / "c.toml", samples=4))
    x = np.tile([0.5, 0.0], (4, 1))
    table = pa.table({"t": [0, 29, 3, 0]})

    def data(terminated):
        return RoundData(
            x, np.zeros((4, 1)) + 0.1, x, np.array([True, True, True, False]),
            np.zeros(4, np.int64), "", table, np.array(["a", "a", "b", "c"]), terminated,
        )  # fmt: skip

    ep = summary(config, data(None))
    assert ep["lengths"] == [30, 4] and ep["ended_early"] == 1 and ep["costs"] == [0.0, 0.0]
    assert sentence(ep, 2, 30) == "Controller 2 ended 1 of its 2 episodes early (a fall)."
    ep = summary(config, data(np.array([False, True, False, False])))  # a fell; b was cut
    assert ep["ended_early"] == 1 and ep["lengths"] == [30, 4]
    ep = summary(config, data(np.array([True, False, True, False])))
    assert ep["ended_early"] == 2 and sentence(ep, 2, 30).startswith("**Controller 2 ended every")
    assert summary(config, data(None)._replace(episode=None)) is None
