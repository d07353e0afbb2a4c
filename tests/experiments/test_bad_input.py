"""Bad input raises ValueError naming the bad value, before any simulation (issue 5, 8)."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.collect import policy_samples
from loopid.algorithms.contracts import LoopSpec
from loopid.algorithms.exploration import make_nu, nu_expert, nu_trajectory
from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop import run_fixed_policy, run_learning
from loopid.algorithms.loop_program import make_loop_program
from loopid.algorithms.plant import make_plant
from loopid.algorithms.transitions import draw
from loopid.experiments.families.helicopter import methods as M
from loopid.experiments.families.helicopter import run
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.systems.linear import linear_dynamics, linear_task

HOVER = scenario("hover", iterations=2, seeds=1, test_trajectories=2)


@pytest.fixture(scope="module")
def plant():
    task = linear_task(np.eye(1), np.eye(1), np.ones(1), 4)
    return make_plant(task, linear_dynamics(np.eye(1), np.eye(1)))


def test_unknown_method():
    with pytest.raises(ValueError, match="'daggr-t'"):
        run("daggr-t", HOVER)
    with pytest.raises(ValueError, match="'DAgger'"):
        M.check_method("DAgger")
    with pytest.raises(ValueError, match="'expert'"):
        M.policy_fractions("expert", 3)
    with pytest.raises(ValueError, match=re.escape("1.5")):
        M.policy_fractions("dagger-t", 3, dagger_fraction=1.5)


def test_unknown_scenario():
    with pytest.raises(ValueError, match="'hovr'"):
        scenario("hovr")


@pytest.mark.parametrize("seeds", [[-1], [0, -3], [0.5], [], [[0, 1]]])
def test_bad_seeds(seeds):
    with pytest.raises(ValueError, match="seeds"):
        seed_keys(seeds)


def test_negative_seed_through_run():
    with pytest.raises(ValueError, match="-2"):
        run("expert", HOVER, seeds=[0, -2])


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("iterations", 0),
        ("iterations", 2.5),
        ("iterations", True),
        ("samples", -1),
        ("test_trajectories", 0),
        ("seeds", 0),
        ("noise_std", -1.0),
        ("noise_std", float("nan")),
        ("delay", -1),
        ("sampling", "uniform"),
        ("gamma", 1.0),
        ("gamma", 0.0),
        ("dagger_fraction", 1.5),
        ("stop_norm", 0.0),
        ("nu_pending", "keep"),
        ("nu_state_var", -0.1),
        ("ftrl_lambda", float("inf")),
        ("test_policy", "first"),
        ("cost_cap", -5.0),
        ("pg_horizon", 0),
        ("pg_sigma", 0.0),
        ("pg_step", -1.0),
        ("task", "loop"),
    ],
)
def test_bad_scenario_field(field, value):
    with pytest.raises(ValueError, match=field) as info:
        scenario("hover", **{field: value})
    assert repr(value) in str(info.value) or str(value) in str(info.value)


def test_unknown_scenario_field():
    with pytest.raises(ValueError, match="colour"):
        scenario("hover", colour="red")


def test_bad_plant_and_loop_options(plant):
    task = plant.task
    dyn = plant.dynamics
    with pytest.raises(ValueError, match="'keep'"):
        make_plant(task, dyn, nu_pending="keep")
    with pytest.raises(ValueError, match="-1"):
        make_plant(task, dyn, stop_norm=-1.0)
    with pytest.raises(ValueError, match="0"):
        make_plant(task, dyn, cost_cap=0.0)
    K = jnp.zeros((plant.horizon, 1, 2))
    with pytest.raises(ValueError, match="'sideways'"):
        policy_samples(plant, K, jax.random.key(0), 3, mode="sideways")
    with pytest.raises(ValueError, match="'worst'"):
        make_loop_program(LoopSpec(plant, None, None, 1, 1, test_policy="worst"), 2)
    with pytest.raises(ValueError, match=re.escape("1.2")):
        run_learning(LoopSpec(plant, None, None, samples=1, n_test=1), [0.0, 1.2], [0])
    with pytest.raises(ValueError, match="iterations"):
        run_learning(LoopSpec(plant, None, None, samples=1, n_test=1), [], [0])
    with pytest.raises(ValueError, match="-1"):
        run_fixed_policy(plant, K, [-1], iterations=1, samples=1, n_test=1)
    tr = plant.rollout(K, jax.random.key(0))
    with pytest.raises(ValueError, match="n=5"):
        draw(tr, jax.random.key(0), 5)


def test_bad_exploration(plant):
    with pytest.raises(ValueError, match="'tn'"):
        make_nu("tn", plant, np.zeros((plant.horizon, 1, 2)))
    with pytest.raises(ValueError, match=re.escape("-0.5")):
        nu_trajectory(plant, state_var=-0.5)
    with pytest.raises(ValueError, match=re.escape("-0.1")):
        nu_expert(plant, np.zeros((plant.horizon, 1, 2)), action_std=-0.1)
