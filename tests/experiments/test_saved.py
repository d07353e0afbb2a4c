"""Saved models and controllers (issue 17): every finished cell keeps each seed's final policy
and model; reloaded, they reproduce the run's own numbers exactly."""

import functools
import json

import gymnasium
import jax
import numpy as np
import pytest

import loopid
from loopid.algorithms.keys import seed_keys
from loopid.experiments import artifacts
from loopid.experiments.execute import run_cells
from loopid.experiments.families import gym, helicopter, mdp
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.models.linear_offset import predict
from loopid.systems import helicopter as h

HOVER = scenario("hover", iterations=3, seeds=2, test_trajectories=4)
METHODS = ["dagger-t", "expert", "pg"]


@pytest.fixture(scope="module")
def hover_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("saved") / "hover"
    return out, run_cells(out, [HOVER], METHODS)


@functools.cache
def jitted(fn):
    """``jax.jit(fn)``, one per plant method: called eagerly, a plant's evaluation retraces and
    recompiles its scan at every call (about 10 s each on 2 busy cores), jitted it compiles once
    per shape."""
    return jax.jit(fn)


def final_costs(table, method: str) -> dict[int, float]:
    rows = table.to_pylist()
    last = max(r["iteration"] for r in rows)
    return {
        r["seed"]: r["test_cost"] for r in rows if r["method"] == method and r["iteration"] == last
    }


@pytest.mark.parametrize("method", METHODS)
def test_a_reloaded_helicopter_controller_gives_the_recorded_costs_exactly(hover_run, method):
    out, table = hover_run
    plant = helicopter.setup(HOVER).plant
    _, cell = helicopter.loop_program(HOVER)
    for seed, recorded in final_costs(table, method).items():
        saved = loopid.load(out, "hover", method, seed)
        noise = cell.noise(seed_keys([seed])).test  # the run's own test noise for this seed
        costs, _ = jitted(plant.eval_seeds)(saved.controller.K[None], noise)
        # the same costs; their mean to the last bits (NumPy sums in another order than XLA)
        assert float(np.mean(costs)) == pytest.approx(recorded, rel=1e-15)


def test_a_cell_that_tested_its_best_policy_reloads_those_gains(hover_run):
    """Under ``test_policy = "best"`` a cell saves ``best_K``, the gains it tested, beside the
    last ``K``: what the reloaded controller flies."""
    out, _ = hover_run
    _, arrays = artifacts.read(out / "cells", "hover", "dagger-t")
    one = artifacts.for_seed(arrays, 0, "hover/dagger-t")
    best = {**one, "best_K": one["K"] + 1.0}
    _, controller = helicopter.load(HOVER, "dagger-t", best)
    np.testing.assert_array_equal(controller.K, best["best_K"])
    _, controller = helicopter.load(HOVER, "dagger-t", one)
    np.testing.assert_array_equal(controller.K, one["K"])


def test_the_saved_model_predicts_as_the_learner_did(hover_run):
    out, _ = hover_run
    trace = helicopter.run("dagger-t", HOVER)  # the same seeds again: the in-memory model
    nominal = helicopter.setup(HOVER).nominal
    rng = np.random.default_rng(0)
    dx = np.concatenate([rng.normal(size=(5, h.N_STATE - 1)), np.ones((5, 1))], axis=1)
    du = rng.normal(size=(5, h.N_ACTION))
    for i, seed in enumerate(trace.seeds):
        saved = loopid.load(out, "hover", "dagger-t", int(seed))
        np.testing.assert_array_equal(saved.model.W, trace.final["W"][i])
        expected = np.asarray(predict(nominal, trace.final["W"][i], dx, du))
        np.testing.assert_array_equal(saved.model.predict(dx, du), expected)
        # as a nominal with no offsets it predicts the same (to rounding: Â = A + W[:n]ᵀ first)
        again = np.asarray(predict(saved.model.as_nominal(), 0 * saved.model.W, dx, du))
        np.testing.assert_allclose(again, expected, rtol=1e-12, atol=1e-12)
        # and it is not the nominal model: the learner moved it
        assert np.abs(expected - np.asarray(predict(nominal, 0 * saved.model.W, dx, du))).max() > 0


def test_the_controller_is_the_loops_affine_policy_and_flies_the_gymnasium_env(hover_run):
    out, table = hover_run
    saved = loopid.load(out, "hover", "expert", 1)
    target = np.asarray(helicopter.setup(HOVER).plant.task.target)
    x = np.asarray(target[0]) + 0.01
    expected = -saved.controller.K[7] @ np.asarray(h.to_error(x, target[7]))
    np.testing.assert_allclose(saved.controller(x, 7), expected, rtol=0, atol=1e-15)
    env = gymnasium.make("loopid/HelicopterHover-v0")
    policy = saved.controller.as_gymnasium_policy(env.action_space)
    obs, _ = env.reset(seed=3)
    policy.reset()
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        total -= reward
        done = terminated or truncated
    total += info["next_state_cost"]
    recorded = np.mean(list(final_costs(table, "expert").values()))
    assert 0.5 * recorded < total < 2.0 * recorded  # the same controller, other noise


def test_artifacts_are_described_and_a_corrupt_one_is_named(hover_run, tmp_path):
    out, _ = hover_run
    info = json.loads((out / "cells" / "hover__dagger-t.json").read_text())
    assert info["family"] == "helicopter" and info["seeds"] == [0, 1]
    assert info["arrays"]["K"]["shape"] == [2, 400, 4, 21]
    assert info["config"]["task"] == "hover" and info["config"]["delay_mode"] == "latency"
    assert info["arrays"]["shared.A"]["shape"] == [21, 21]  # the nominal the offsets add to
    expert = json.loads((out / "cells" / "hover__expert.json").read_text())
    assert set(expert["arrays"]) == {"K"}  # no model: nothing else
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    (broken / "cells" / "hover__pg.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match=r"hover__pg\.npz") as e:
        loopid.load(broken, "hover", "pg", 0)
    assert "\n" not in str(e.value)
    (broken / "cells" / "hover__expert.json").unlink()
    with pytest.raises(ValueError, match=r"hover__expert\.json.*missing"):
        loopid.load(broken, "hover", "expert", 0)
    with pytest.raises(ValueError, match="seed 7"):
        loopid.load(out, "hover", "expert", 7)
    with pytest.raises(ValueError, match="funnel"):
        loopid.load(out, "funnel", "expert", 0)
    with pytest.raises(ValueError, match=r"no config\.toml"):
        loopid.load(tmp_path, "hover", "expert", 0)


def test_a_reloaded_mdp_policy_gives_the_recorded_exact_cost(tmp_path):
    s = mdp.MDP_SCENARIOS["mdp-trap"].replace(iterations=3, seeds=2)
    table = run_cells(tmp_path, [s], ["dagger", "batch"])
    plant = mdp.mdp_setup(s).plant
    for method in ("dagger", "batch"):
        for seed, recorded in final_costs(table, method).items():
            saved = loopid.load(tmp_path, "mdp-trap", method, seed)
            J, _ = plant.eval_one(saved.controller.K, None)
            assert float(J) == pytest.approx(recorded, rel=1e-15)
            n_actions = saved.controller.K.shape[1]
            assert saved.controller(0) in range(n_actions)
            assert saved.model.T_hat.shape[1] == n_actions
            np.testing.assert_allclose(saved.model.T_hat.sum(-1), 1.0, atol=1e-12)


@pytest.mark.slow
def test_a_reloaded_gym_controller_gives_the_recorded_costs_exactly(tmp_path):
    from loopid.algorithms.gym_loop import test_episodes
    from loopid.cli import scenario_from_options

    example = __import__("pathlib").Path(__file__).resolve().parents[2] / "examples"
    _, s, _ = scenario_from_options("gym", example / "pendulum.toml", {"seeds": 2,
                                    "iterations": 2, "test_trajectories": 3}, [])  # fmt: skip
    table = run_cells(tmp_path, [s], ["dagger"])
    with gym.gym_setup(s) as setup:
        system, test_cost = setup.system, setup.test_cost
        for seed, recorded in final_costs(table, "dagger").items():
            saved = loopid.load(tmp_path, "gym", "dagger", seed)
            costs, _ = test_episodes(system, saved.controller.K[None], [seed], 3, test_cost,
                                     s.termination, s.cost_cap)  # fmt: skip
            assert float(np.mean(costs)) == pytest.approx(recorded, rel=1e-15)
            env = gymnasium.make("Pendulum-v1")
            obs, _ = env.reset(seed=0, options={"x_init": 0.3, "y_init": 0.5})
            policy = saved.controller.as_gymnasium_policy(env.action_space)
            costs = []
            for _ in range(200):
                obs, reward, *_ = env.step(policy(obs))
                costs.append(-reward)
            assert np.mean(costs[-50:]) < 0.01  # it holds the pendulum up


def test_artifact_shapes_are_checked(tmp_path):
    with pytest.raises(ValueError, match=r"not \[2, \.\.\.\]"):
        artifacts.write(tmp_path, "s", "m", "helicopter", [0, 1], {"K": np.zeros((3, 2))})


@pytest.mark.slow
def test_loopid_evaluate_reports_the_recorded_cost_within_its_standard_error(tmp_path, capsys):
    """``loopid run hover --seeds 2 --iterations 5`` (every method), then ``loopid evaluate``:
    on 100 fresh test episodes per seed, each saved controller's mean cost differs from the
    run's recorded one (new noise) by at most 4 standard errors of the difference,
    ``√(se_new² + se_run²)``, ``se_run`` from the run's own 100 costs (re-flown on the run's
    noise, which gives the recorded mean exactly). A row per cell and seed in evaluate.parquet.
    (Capped diverging trajectories make costs nearly two-valued, 0-1e8: at these seeds the
    largest difference is 3.0 such errors, abbeel at seed 1.)"""
    import pyarrow.parquet as pq

    from loopid.cli import main

    out = tmp_path / "hover"
    for args in (["run", "hover", "--seeds", "2", "--iterations", "5", "--workers", "1",
                  "--quiet", "--out", str(out)], ["evaluate", str(out)]):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(args)
        assert e.value.code == 0
    rows = pq.read_table(out / "evaluate.parquet").to_pylist()
    assert len(rows) == 9 * 2 and all(r["episodes"] == 100 for r in rows)
    s = scenario("hover", seeds=2, iterations=5)
    plant, (_, cell) = helicopter.setup(s).plant, helicopter.loop_program(s)
    worst = 0.0
    for r in rows:
        saved = loopid.load(out, "hover", r["method"], r["seed"])
        run_costs, _ = jitted(plant.eval_seeds)(
            saved.controller.K[None], cell.noise(seed_keys([r["seed"]])).test
        )
        run_costs = np.asarray(run_costs)[0]
        assert run_costs.mean() == pytest.approx(r["recorded"], rel=1e-15)  # the run's noise
        se_run = run_costs.std(ddof=1) / np.sqrt(run_costs.size)
        assert r["mean"] != r["recorded"], r  # fresh noise
        z = abs(r["mean"] - r["recorded"]) / max(np.hypot(r["se"], se_run), 1e-12)
        worst = max(worst, z)
        assert z <= 4.0, (r, z)
    printed = capsys.readouterr().out
    assert "hover / expert / seed 1:" in printed and "+-" in printed
    with pytest.raises(SystemExit) as e:  # one cell and seed, appended
        main(["evaluate", str(out), "--method", "expert", "--seed", "0", "--episodes", "10"])
    assert e.value.code == 0
    assert pq.read_table(out / "evaluate.parquet").num_rows == 9 * 2 + 1
    capsys.readouterr()
    for bad, needle in ((["--method", "nope"], "'nope'"), (["--seed", "9"], "seed 9"),
                        (["--episodes", "0"], "--episodes"), (["--env", "Pendulum-v1"], "--env"),
                        (["--scenario", "funnel"], "'funnel'")):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(["evaluate", str(out), *bad])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], err
    (out / "cells" / "hover__pg.npz").write_bytes(b"\x00" * 64)  # a corrupt artifact
    with pytest.raises(SystemExit) as e:
        main(["evaluate", str(out), "--method", "pg"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hover__pg.npz" in err[0] and "Traceback" not in err[0], err


@pytest.mark.parametrize("delay_mode", ["fifo", "latency"])
def test_the_flown_path_costs_what_the_plant_charged(delay_mode):
    """flights.fly keeps the states of the plant's own test trajectory: its cost, recomputed
    from those states, is the plant's test cost of the same policy and noise (an independent
    recomputation: SPEC §4.1's sum, not the plant's scan)."""
    from loopid.experiments.families.helicopter.flights import fly
    from loopid.systems.base import trajectory_cost

    s = scenario("hover-delay", delay_mode=delay_mode)
    st = helicopter.setup(s)
    task, K = st.plant.task, np.asarray(st.K_expert)
    noise = st.plant.eval_noise(__import__("jax").random.key(5), 1)[0]
    X = fly(task, K, noise, delay_mode)
    target = np.asarray(task.target)
    dX = np.stack([np.asarray(h.to_error(x, xs)) for x, xs in zip(X, target, strict=True)])
    T, d = K.shape[0], task.delay
    if delay_mode == "fifo":  # the commanded changes
        dU = np.stack([-K[t] @ dX[t] for t in range(T)])
    else:  # the applied ones: the policy acts on the error of d steps earlier
        dU = np.stack([-K[t - d] @ dX[t - d] if t >= d else np.zeros(4) for t in range(T)])
    cost = float(trajectory_cost(dX, dU, task.Q, task.R))
    expected, _ = st.plant.eval_costs(K, noise[None])
    np.testing.assert_allclose(cost, float(expected[0]), rtol=1e-9)


def test_trajectories_fly_the_saved_gains_without_building_a_setup(
    hover_run, tmp_path, monkeypatch
):
    """A run whose cells ran in worker processes draws trajectories.png in the command's own
    process: flying saved gains needs the scenario's plant, not its Setup (the expert's gains,
    the model, the loop program), which that process would otherwise build and compile again."""
    from loopid.experiments.families.helicopter import assembly, saved

    out, _ = hover_run
    assert assembly.setup(HOVER).plant is assembly.scenario_plant(HOVER)

    def no_setup(key):
        raise AssertionError(f"built the Setup of {key.task}")

    monkeypatch.setattr(assembly, "_setup", no_setup)
    saved.trajectories(out, {HOVER.name: HOVER}, tmp_path / "t.png")
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(AssertionError, match="built the Setup"):
        assembly.setup(HOVER)  # the patch is in place: the test would catch a Setup


@pytest.mark.slow
def test_trajectories_png_and_animate(hover_run, tmp_path, capsys):
    from loopid.cli import main
    from loopid.experiments.execute import write_outputs

    out, table = hover_run
    write_outputs(out, table)
    assert (out / "trajectories.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    gif = tmp_path / "a.gif"
    with pytest.raises(SystemExit) as e:
        main(["animate", str(out), "--method", "expert,pg", "--seed", "1", "--out", str(gif)])
    assert e.value.code == 0
    from PIL import Image

    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames >= 50
    capsys.readouterr()
    for bad, needle in ((["--method", "nope"], "'nope'"),
                        (["--method", "expert", "--seed", "9"], "seed 9"),
                        (["--method", "expert", "--scenario", "funnel"], "'funnel'")):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(["animate", str(out), "--out", str(tmp_path / "b.gif"), *bad])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], err
