"""Rounds do not depend on the log's units: the same physics logged in radians and in degrees
gives the same actions for the same physical states; the scale is recorded and shown; the
regulariser's pull is plain least squares' distance from the fit; an old directory keeps unit
scale."""

import json

import numpy as np
import pytest
from rounds_helpers import write_round

from loopid import rounds
from loopid.rounds import api
from loopid.rounds.api import controller_arrays
from loopid.rounds.model import PULL_WARN
from loopid.rounds.state import load_state, read_npz, save_state

DEG = 57.3
#: A small pendulum-like system near upright: tilt (rad, 0.01-0.05) and tilt rate.
F = np.array([[1.0, 0.05], [0.3155, 0.98]])
G = np.array([[0.0], [0.05]])

CONFIG = """
[system]
states = ["tilt", "rate"]
actions = ["torque"]
target = [{target}, 0.0]
horizon = 40
[cost]
Q = [{q}, 0.1]
R = [{r}]
[rounds]
samples = 40
{rounds}
"""


def physical_rounds(k: int) -> list[dict]:
    rng = np.random.default_rng(11)
    out = []
    for _ in range(k):
        x = np.stack([rng.uniform(-0.05, 0.05, 40), rng.normal(0, 0.05, 40)], 1)
        u = rng.normal(0, 0.02, (40, 1))
        xn = x @ F.T + u @ G.T + 1e-4 * rng.normal(size=(40, 2))
        out.append({"x": x, "u": u, "xn": xn})
    return out


def run(tmp_path, name: str, unit: float, scale: str, k: int = 3):
    """A round directory fed ``k`` rounds with the tilt in ``unit``s per radian (Q and the
    target to match)."""
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(
        CONFIG.format(r=0.01, target=0.01 * unit, q=1.0 / unit**2, rounds=f'scale = "{scale}"')
    )
    root = tmp_path / name
    rounds.init(root, cfg)
    for i, r in enumerate(physical_rounds(k)):
        x, xn = r["x"] * [unit, 1.0], r["xn"] * [unit, 1.0]
        cols = {"tilt": x[:, 0], "rate": x[:, 1], "torque": r["u"][:, 0]}
        cols |= {"next_tilt": xn[:, 0], "next_rate": xn[:, 1]}
        cols["source"] = ["policy" if j % 2 else "nu" for j in range(40)]
        rounds.update(root, write_round(tmp_path / f"{name}-{i}.parquet", cols))
    return root


def actions(root, states, unit: float) -> np.ndarray:
    policy = rounds.controller(root)
    return np.array([policy.action(o * [unit, 1.0]) for o in states])


def test_same_physics_in_two_units_gives_the_same_actions(tmp_path):
    states = np.random.default_rng(2).uniform(-0.06, 0.06, (200, 2))
    rad = actions(run(tmp_path, "rad", 1.0, "std"), states, 1.0)
    deg = actions(run(tmp_path, "deg", DEG, "std"), states, DEG)
    assert np.abs(rad).max() > 1e-3  # a controller that acts
    assert np.abs(deg - rad).max() <= 1e-9 * np.abs(rad).max()
    # without the scale, the absolute regulariser sees the two logs differently
    rad0 = actions(run(tmp_path, "rad0", 1.0, "none"), states, 1.0)
    deg0 = actions(run(tmp_path, "deg0", DEG, "none"), states, DEG)
    assert np.abs(deg0 - rad0).max() > 1e-3 * np.abs(rad0).max()


def test_model_in_the_log_units_and_the_scale_recorded(tmp_path):
    rad, deg = run(tmp_path, "rad", 1.0, "std", 1), run(tmp_path, "deg", DEG, "std", 1)
    a, b = controller_arrays(rad), controller_arrays(deg)
    D = np.diag([DEG, 1.0, 1.0])  # tilt in degrees; the constant entry unscaled
    np.testing.assert_allclose(b["A"], D @ a["A"] @ np.linalg.inv(D), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(b["B"], D @ a["B"], rtol=1e-12, atol=1e-15)
    first = physical_rounds(1)[0]
    meta = json.loads(str(read_npz(rad / "state.npz")["meta"]))
    np.testing.assert_allclose(meta["scale"]["states"], np.std(first["x"], axis=0), rtol=1e-14)
    np.testing.assert_allclose(meta["scale"]["actions"], np.std(first["u"], axis=0), rtol=1e-14)
    text = (deg / "round.md").read_text()
    assert f"| tilt | {DEG * np.std(first['x'][:, 0]):.6g} |" in text


def test_a_column_without_spread_keeps_unit_scale(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text(CONFIG.format(r=0.01, target=0.0, q=1.0, rounds=""))
    root = tmp_path / "dir"
    rounds.init(root, cfg)
    r = physical_rounds(1)[0]
    cols = {"tilt": r["x"][:, 0], "rate": r["x"][:, 1], "torque": np.zeros(40)}
    cols |= {"next_tilt": r["xn"][:, 0], "next_rate": r["xn"][:, 1]}
    cols["source"] = ["policy" if j % 2 else "nu" for j in range(40)]
    rounds.update(root, write_round(tmp_path / "r.csv", cols))
    meta = json.loads(str(read_npz(root / "state.npz")["meta"]))
    assert meta["scale"]["actions"] == [1.0] and meta["scale"]["flat"] == ["torque"]
    assert (
        "| torque | 1 (no spread in the first round: unit scale) |"
        in (root / "round.md").read_text()
    )


def test_the_pull_is_the_distance_from_plain_least_squares(tmp_path):
    root = run(tmp_path, "none", 1.0, "none", 1)
    r = physical_rounds(1)[0]
    dx = np.concatenate([r["x"] - [0.01, 0.0], np.ones((40, 1))], 1)
    Z = np.concatenate([dx, r["u"]], 1)
    Y = np.concatenate([r["xn"] - r["x"], np.zeros((40, 1))], 1)
    W_fit = np.linalg.solve(Z.T @ Z + 1e-3 * np.sqrt(40) * np.eye(4), Z.T @ Y)
    W_ls = np.linalg.lstsq(Z, Y, rcond=None)[0]
    fit, ls = (np.concatenate([np.eye(3) + W[:3].T, W[3:].T], 1)[:2] for W in (W_fit, W_ls))
    rel = np.abs(fit - ls) / np.maximum(np.abs(ls), 0.01 * np.abs(ls).max())
    pull = load_state(root, api._agent(api.load_config(root)).agent.init()).history[-1]["pull"]
    assert pull["pull"] == pytest.approx(rel.max(), rel=1e-6) and pull["pull"] > PULL_WARN
    assert "**The regulariser pulls the model.**" in (root / "round.md").read_text()
    scaled = load_state(
        run(tmp_path, "std", 1.0, "std", 1), api._agent(api.load_config(root)).agent.init()
    ).history[-1]["pull"]
    assert scaled["pull"] < pull["pull"] / 10  # the scale takes most of the bias away


def test_an_old_directory_keeps_unit_scale(tmp_path):
    """A state.npz saved before the scale existed, with data learned: unit scale, said so."""
    root = run(tmp_path, "old", 1.0, "none", 1)
    state = load_state(root, api._agent(api.load_config(root)).agent.init())
    save_state(root, state._replace(scale=None))
    (root / "config.toml").write_text(
        (root / "config.toml").read_text().replace('scale = "none"', "")
    )
    r = physical_rounds(2)[1]
    cols = {"tilt": r["x"][:, 0], "rate": r["x"][:, 1], "torque": r["u"][:, 0]}
    cols |= {
        "next_tilt": r["xn"][:, 0],
        "next_rate": r["xn"][:, 1],
        "source": ["policy" if j % 2 else "nu" for j in range(40)],
    }
    rounds.update(root, write_round(tmp_path / "r2.parquet", cols))
    assert controller_arrays(root)["scale_states"].tolist() == [1.0, 1.0]
    assert "started before rounds were scaled" in (root / "round.md").read_text()


def test_an_mpc_controller_acts_in_the_log_units(tmp_path):
    """Features + MPC: planned in the scaled coordinates, the same actions in either unit, with
    the tilt in degrees and the torque in N·mm (R to match); its JSON export carries the scale
    its model's parameters act in."""
    extra = '[model]\nkind = "features"\n[planner]\nkind = "mpc"\nhorizon = 5\niterations = 3'
    got = []
    for unit, torque in ((1.0, 1.0), (DEG, 1000.0)):
        cfg = tmp_path / f"{unit}.toml"
        text = CONFIG.format(r=0.01 / torque**2, target=0.01 * unit, q=1.0 / unit**2, rounds="")
        cfg.write_text(text.replace("[rounds]", extra + "\n[rounds]"))
        root = tmp_path / f"mpc-{unit}"
        rounds.init(root, cfg)
        r = physical_rounds(1)[0]
        x, xn = r["x"] * [unit, 1.0], r["xn"] * [unit, 1.0]
        cols = {"tilt": x[:, 0], "rate": x[:, 1], "torque": r["u"][:, 0] * torque}
        cols |= {
            "next_tilt": xn[:, 0],
            "next_rate": xn[:, 1],
            "source": ["policy" if j % 2 else "nu" for j in range(40)],
        }
        rounds.update(root, write_round(tmp_path / f"m{unit}.parquet", cols))
        obs = np.array([[0.03, 0.01], [-0.02, 0.04]]) * [unit, 1.0]
        got.append(np.asarray(rounds.controller(root).act(obs, [0, 0], [0, 1])) / torque)
        saved = json.loads(rounds.export(root, "json").read_text())
        arrays = controller_arrays(root)
        assert saved["scale_states"] == arrays["scale_states"].tolist()
        assert saved["scale_actions"] == arrays["scale_actions"].tolist()
    assert got[0].shape == (2, 1) and np.abs(got[0]).max() > 1e-4
    assert np.abs(got[1] - got[0]).max() <= 1e-9 * np.abs(got[0]).max()


def test_a_bad_scale_is_refused(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text(CONFIG.format(r=0.01, target=0.0, q=1.0, rounds='scale = "rms"'))
    with pytest.raises(ValueError, match="scale must be one of std, none, got 'rms'") as err:
        rounds.init(tmp_path / "dir", cfg)
    assert "\n" not in str(err.value) and not (tmp_path / "dir").exists()
