"""Nonlinear model classes and planners in the loop (issue 19): the pendulum swing-up, the MLP,
and one-line refusals of bad [model]/[planner] settings."""

import re
from pathlib import Path

import numpy as np
import pytest

from conftest import cli
from loopid import control
from loopid.algorithms.gym_loop import test_episodes as flown_episodes
from loopid.experiments.families import gym
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.systems import pendulum
from loopid.systems.gym_slots import Slot

SWINGUP = Path(__file__).resolve().parents[2] / "examples" / "pendulum_swingup.toml"


def swingup(**changes) -> gym.GymScenario:
    fields, _ = gym.read_file(SWINGUP)
    return gym.build("gym", {**fields, **changes})


@pytest.fixture(scope="module")
def reference() -> float:
    """The true-model iLQR's Gym cost of the swing-up, planned as the example plans (Pendulum's
    own cost with the torque penalty, a 200-step plan seeded by an MPC episode of 60-step plans
    trying ±2) and flown on the real env as gains: 295.4 (measured)."""
    dyn = lambda params, dx, du, t: pendulum.step_obs(dx, du, t)  # noqa: E731
    x0 = pendulum.to_error(np.array([np.pi, 0.0]))
    sol = control.plan(
        dyn, control.Penalized(pendulum.cost_obs, 2.0), x0, np.full((200, 1), 0.2),
        iterations=100, seed_horizon=60, seed_alternatives=[[2.0], [-2.0]],
    )  # fmt: skip
    return float(fly(swingup(), np.asarray(control.as_gains(sol))[None])[0][0])


def fly(s: gym.GymScenario, K, rollouts: bool = False):
    """Gym costs [S] and angles θ [S, 200] of the gains ``K [S, 200, 1, 4]`` flown once each on
    the real hanging pendulum (its reward as the cost), and with ``rollouts`` the flights."""
    system = gym.make_system(s)
    try:
        costs, _ = flown_episodes(system, K, list(range(len(K))), 1, "reward")
        slots = [Slot(0, i, 0, 0.0, False) for i in range(len(K))]
        r = system.rollouts([system.linear_policy(K)], slots)
    finally:
        system.close()
    out = costs[:, 0], np.arctan2(r.x[..., 1], r.x[..., 0])
    return (*out, r) if rollouts else out


@pytest.mark.science
def test_dagger_swings_the_pendulum_up_with_features_and_the_linear_model_cannot(reference):
    """examples/pendulum_swingup.toml at 16 seeds (degree-4 features, 12 iterations of 400
    transitions, the best policy so far tested): DAgger's tested policy swings the pendulum up
    from hanging and holds it upright (|θ| < 0.1) for the final quarter of the episode within
    1.5x the true-model iLQR's cost (295.4) on at least 14 of 16 seeds (measured 15 on one CPU:
    Gym costs 295.4-315.1, seed 8 at 1,228.7; 14 on another, an AMD EPYC with AVX2 and no
    AVX-512: seed 3 at 457.1 and not upright, seed 12 at 1,183.8).

    Why 16 seeds, and 14 of them: which seeds swing up at a given iteration is decided at
    rounding level. Three computations of the model's Jacobian that agree to ~2e-16 give 15 of
    16 (the analytic derivative, ``FeatureMap.jacobian``, what runs), 15 (``jax.jacfwd``
    through the features) and 16 (``jax.jacrev``) for the tested policy on the first CPU, and
    14, 12 and 16 for the last policy (``analysis/swingup_seeds/swingup_seeds.py``): a model that
    swung up can lose it at the next iteration, and the best policy so far keeps what it found. XLA
    compiles for the CPU's own vector instructions, so another CPU rounds differently and moves the
    count the same way (the analytic Jacobian's 15 is 14 on the EPYC). The test asks for the lowest
    count measured, not the best.

    The linear model with LQR, the same data and ν, swings up on none of 3 seeds (measured:
    every seed's policies stay near the bottom, costs above 1,000). Batch (ν's data only) is
    in the guide's figure: its model fits ν's data but not its own policy's, and it fails."""
    assert 280 < reference < 320
    s = swingup(seeds=16, test_trajectories=1)
    assert s.test_policy == "best"
    trace = gym.run("dagger", s)
    costs, theta, flights = fly(s, trace.final["best_K"], rollouts=True)
    upright = np.all(np.abs(theta[:, 150:]) < 0.1, axis=1)
    assert np.sum(upright & (costs <= 1.5 * reference)) >= 14, (costs, reference)
    np.testing.assert_allclose(trace.rows.test_cost[:, -1], costs, rtol=1e-6)
    assert np.all(np.diff(trace.rows.test_cost, axis=1) <= 0)  # one test episode: the running min

    # the last saved model of the first seed that swung up, reloaded (loopid.load's path, whose
    # controller flies the tested gains), predicts the real pendulum along the tested policy's
    # flight: one-step error below 1% of the nominal's (Δx' = Δx).
    i = int(np.argmax(upright))
    shared = {f"shared.{k}": v for k, v in gym.shared(s, "dagger").items()}
    arrays = {"K": trace.final["K"][i], "best_K": trace.final["best_K"][i],
              "W_features": trace.final["W_features"][i], **shared}  # fmt: skip
    model, controller = gym.load(s, "dagger", arrays)
    np.testing.assert_array_equal(controller.K, trace.final["best_K"][i])  # the tested gains
    keep = flights.mask[i]
    dx, du, dx_next = flights.dx[i][keep], flights.du[i][keep], flights.dx_next[i][keep]
    error = np.mean(np.sum((model.predict(dx, du) - dx_next) ** 2, axis=1))
    assert error < 1e-2 * np.mean(np.sum((dx - dx_next) ** 2, axis=1)), error

    linear = swingup(seeds=3, test_trajectories=1, model_kind="linear", planner_kind="lqr",
                     iterations=4)  # fmt: skip
    costs, theta = fly(linear, gym.run("dagger", linear).final["best_K"])
    assert not np.any(np.all(np.abs(theta[:, 150:]) < 0.1, axis=1)), costs
    assert np.all(costs > 1.5 * reference), costs


@pytest.mark.slow
def test_mpc_on_the_learned_model_swings_up_from_random_starts(reference):
    """[planner] kind = "mpc" (40-step plans re-planned every 2 steps, 10 iLQR iterations, each
    also trying ±2) on the degree-3 feature model, started at θ = π ± U(0.1): the gains of
    one plan cannot fly such starts (measured: ~1,300), MPC re-plans on the learned model as it
    flies. DAgger, 2 seeds, 3 iterations: both seeds' final mean test cost (2 episodes) within
    1.5x the true-model iLQR's (measured 364.9 and 334.6; the true-model MPC itself costs
    344-375 from such starts), and so is every episode of ``loopid evaluate``'s (fresh starts,
    MPC on the saved models)."""
    s = swingup(
        seeds=2, iterations=3, test_trajectories=2, planner_kind="mpc", planner_horizon=40,
        planner_every=2, planner_iterations=10, env_kwargs={"noise": 0.1}, model_degree=3,
        test_policy="last",
    )  # fmt: skip
    trace = gym.run("dagger", s)
    rows = trace.rows
    assert np.all(rows.test_cost[:, -1] <= 1.5 * reference), rows.test_cost
    assert np.all(rows.test_cost[:, 0] > 3 * reference), rows.test_cost

    # loopid evaluate's path: fresh starts, MPC re-planning on each seed's saved model (the
    # saved gains of one plan would cost ~1,300 from such starts)
    saved = {k: np.asarray(v) for k, v in trace.final.items()}
    costs = gym.evaluate(s, saved, np.arange(2), 2)
    assert np.all(costs <= 1.5 * reference), costs


@pytest.mark.slow
def test_the_mlp_learns_online_and_its_plan_beats_the_first_policy():
    """The MLP model (two hidden layers of 32, 100 Adam steps per update) on the swing-up, DAgger,
    2 seeds, 4 iterations: the model's loss on ν's fresh draws (before each update) falls over
    iterations (measured 0.039 -> 0.0048 and 0.077 -> 0.0089 from iteration 2 to 4) and the
    last policy's test cost is below the first policy's on every seed (1974 -> 1112 and 1302;
    it does not swing up in 4 iterations). Non-convex: no regret claim, only the online loss is
    reported."""
    s = swingup(seeds=2, iterations=4, test_trajectories=1, model_kind="mlp", model_hidden=32,
                model_steps=100, planner_iterations=30, test_policy="last")  # fmt: skip
    rows = gym.run("dagger", s).rows
    assert np.all(rows.loss_nu[:, -1] < rows.loss_nu[:, 1]), rows.loss_nu
    assert np.all(rows.test_cost[:, -1] < rows.test_cost[:, 0]), rows.test_cost


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"model_kind": "gaussian-process"}, "model_kind"),
        ({"model_kind": "features", "model_features": "wavelet"}, "model_features"),
        ({"model_degree": 0}, "model_degree"),
        ({"model_count": -5}, "model_count"),
        ({"model_bandwidth": 0.0}, "model_bandwidth"),
        ({"model_hidden": 0}, "model_hidden"),
        ({"planner_kind": "rrt"}, "planner_kind"),
        ({"planner_kind": "ilqr", "planner_iterations": 0}, "planner_iterations"),
        ({"planner_kind": "ilqr", "planner_horizon": 601}, "planner_horizon"),
        ({"planner_kind": "ilqr", "planner_horizon": 5, "planner_every": 6}, "planner_every"),
        ({"model_kind": "features"}, "planner_kind 'lqr'"),
        ({"planner_kind": "mpc", "test_policy": "best"}, "test_policy"),
        ({"planner_kind": "mpc", "task": "hover-delay", "delay_mode": "latency"}, "latency"),
        ({"planner_alternatives": [2.0]}, "planner_alternatives"),
    ],
)
def test_bad_model_and_planner_settings_are_named(changes, named):
    """On the helicopter (its horizon is checked when the agent is built, 400 for the hover)."""
    from loopid.experiments.families.helicopter import agent

    with pytest.raises(ValueError, match=re.escape(named)) as err:
        agent(scenario("hover", **changes))
    assert "\n" not in str(err.value)


def test_bad_settings_on_the_command_line_are_one_line_exit_2(cache, tmp_path):
    """A user's bad [model]/[planner] values through `loopid run`: one line, exit 2, no run
    directory (a planner horizon longer than the gym task's 200 steps; an unknown kind)."""
    for args in (
        ["gym", "--config", SWINGUP, "--set", "planner_horizon=500"],
        ["hover", "--set", "model_kind=gp"],
    ):
        out = tmp_path / "run"
        done = cli("run", *args, "--out", out, cache=cache)
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and ("planner_horizon" in lines[0] or "model_kind" in lines[0])
        assert not out.exists()


def test_the_report_says_which_model_class_makes_a_regret_claim():
    """report.md's note per scenario (model_planner.describe): the MLP's rows make no regret
    claim, the feature model's and the linear model's are convex online learning."""
    from loopid.settings.model_planner import describe

    assert "no regret claim" in describe(swingup(model_kind="mlp"))
    assert "degree 4" in describe(swingup()) and "regret guarantee holds" in describe(swingup())
    assert describe(scenario("hover")) == (
        "Model: the linear offset model, learned by FTRL; planner: LQR."
    )
