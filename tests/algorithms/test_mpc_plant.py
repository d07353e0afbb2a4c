"""MPC flown on the helicopter plant (:mod:`loopid.algorithms.mpc_plant`) against two references:
the gains of its one plan flown by the gains plant, and :func:`loopid.control.mpc_rollout` on
the simulator written in error coordinates; its training rollouts against its own test flight
and the restart rule; a seed's costs beside other seeds. The cell flying each seed's model
through the helicopter family is tested in ``tests/experiments/test_family_helicopter_mpc.py``."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid import control
from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop_program import eval_noise
from loopid.algorithms.mpc_plant import mpc_plant
from loopid.algorithms.planning_agent import feature_model
from loopid.algorithms.plant import quadratic_form
from loopid.algorithms.transitions import flatten
from loopid.learners import ftrl_least_squares
from loopid.models.feature_maps import polynomial
from loopid.models.linear_offset import hover_nominal
from loopid.systems import helicopter
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task

T = 40  # the hover task cut to 40 steps


def short_hover(noise_std=None, stop_norm=5.0):
    task = make_task("hover", noise_std=noise_std)
    task = task._replace(target=task.target[: T + 1])
    return helicopter_plant(task, stop_norm=stop_norm)


@pytest.fixture(scope="module")
def model():
    """A linear offset model (the degree-1 feature map, FTRL) fitted to 8 of the expert's noisy
    hover rollouts (action noise std 0.5): the model class the loop learns, with a plan that
    does something."""
    plant = short_hover()
    mc = feature_model(hover_nominal(21, 4), polynomial(21, 4, 1), ftrl_least_squares(1e-3))
    K = jnp.broadcast_to(expert_gains(plant.task), (T, 4, 21))
    keys = jax.random.split(jax.random.key(0), 8)
    rows = flatten(jax.vmap(lambda k: plant.rollout(K, k, 0.5))(keys))
    return mc, mc.params(mc.update(mc.init(), rows))


def cost(plant):
    return control.quadratic_cost(plant.task.Q, plant.task.R)


def flown_by_mpc(plant, model, **settings):
    """``plant`` flown by MPC on ``model`` with the task's cost, first plans from Δu = 0."""
    return mpc_plant(plant, control.replanner(model, cost(plant), jnp.zeros(4), **settings))


def test_one_plan_over_the_horizon_flies_as_its_gains(model):
    """H = every = the horizon: MPC plans once, from the start, and its feedback
    U_j − K_j(Δx − X_j) is the plan's gains (:func:`loopid.control.as_gains`, α = 0); the gains
    plant flying them gives the same test costs (3 noise draws) and, with no action noise, the
    same training rollout."""
    mc, W = model
    plant = short_hover()
    x0 = helicopter.to_error(plant.task.x0, plant.task.target[0])
    sol = control.plan(mc.dynamics, cost(plant), x0, jnp.zeros((T, 4)), params=W, iterations=10)
    K = control.as_gains(sol, alpha=0.0)
    mpc = flown_by_mpc(plant, mc.dynamics, horizon=T, every=T, iterations=10).plant
    noise = plant.eval_noise(jax.random.key(1), 3)
    ref = jax.vmap(lambda w: plant.eval_one(K, w))(noise)
    got = jax.jit(jax.vmap(lambda w: mpc.eval_one(W, w)))(noise)
    assert np.all(np.asarray(ref[0]) < 1e4), ref  # a flight, not the cap
    np.testing.assert_allclose(got[0], ref[0], rtol=1e-9)

    key = jax.random.key(2)
    a, b = plant.rollout(K, key), jax.jit(mpc.rollout)(W, key)
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_allclose(b.dx, a.dx, atol=1e-9)
    np.testing.assert_allclose(b.du, a.du, atol=1e-9)


def test_replanning_matches_mpc_rollout_on_the_simulator_in_error_coordinates():
    """The funnel's moving target (no pads, cut to 40 steps, no noise), planned on the simulator
    itself written in error coordinates, ``Δx' = to_error(f(from_error(Δx, x*_t), Δu),
    x*_{t+1})``: 10-step plans of 2 iLQR iterations (so the warm start matters), re-planned every
    3 steps (40 is not a multiple of 3: the last block is cut). The plant's MPC flight costs what
    :func:`loopid.control.mpc_rollout` flying the same function costs (Σ stage costs + the final
    ``Δx_TᵀQΔx_T``): the same plans at the same times from the same states."""
    task = make_task("funnel", noise_std=0.0, pads=False)
    task = task._replace(target=task.target[: T + 1])
    plant = helicopter_plant(task)
    target = task.target

    def true(dx, du, t):
        x = helicopter.from_error(dx, target[t])
        return helicopter.to_error(helicopter.step(x, du, jnp.zeros(6)), target[t + 1])

    def model(params, dx, du, t):
        return true(dx, du, t)

    x0 = helicopter.to_error(task.x0, target[0])
    ref = control.mpc_rollout(
        None, true, model, cost(plant), x0, T, U0=jnp.zeros(4), horizon=10, every=3,
        iterations=2,
    )  # fmt: skip
    total = float(jnp.sum(ref.costs) + quadratic_form(task.Q)(ref.X[-1]))
    mpc = flown_by_mpc(plant, model, horizon=10, every=3, iterations=2)
    got, diverged = jax.jit(mpc.plant.eval_one)(None, jnp.zeros((T, 6)))
    assert not diverged and 0 < total < 1e4
    np.testing.assert_allclose(float(got), total, rtol=1e-9)
    X, _ = jax.jit(mpc.flight)(None, jnp.zeros((T, 6)))  # the raw states flown
    np.testing.assert_allclose(jax.vmap(helicopter.to_error)(X, target), ref.X, atol=1e-9)


def test_a_training_rollout_is_its_test_flight_and_restarts_at_a_blocks_end(model):
    """With the safe region out of reach and no action noise, the training rollout is the test
    flight under the same noise: its recorded stage costs plus the final one sum to
    ``eval_one``'s. With a small safe region, each restart waits for the end of its block: the
    block's rows after the step that left are masked, and the next episode starts from μ at
    t = 0 at a multiple of ``every``."""
    mc, W = model
    every = 4
    planner = control.replanner(mc.dynamics, cost(plant := short_hover()), jnp.zeros(4),
                                horizon=10, every=every, iterations=5)  # fmt: skip
    wide = mpc_plant(short_hover(stop_norm=1e9), planner).plant
    key = jax.random.key(3)
    rows = jax.jit(wide.rollout)(W, key)
    assert rows.mask.shape == (T,) and rows.mask.all()
    noise = plant.dynamics.noise_sequence(jax.random.split(key)[0], T, plant.noise_std)
    flown, _ = jax.jit(wide.eval_one)(W, noise)
    qQ, qR = quadratic_form(plant.task.Q), quadratic_form(plant.task.R)
    stage = jax.vmap(lambda dx, du: qQ(dx) + qR(du))(rows.dx, rows.du)
    np.testing.assert_allclose(float(jnp.sum(stage) + qQ(rows.dx_next[-1])), flown, rtol=1e-9)

    tight = mpc_plant(short_hover(stop_norm=0.8), planner).plant
    r = jax.jit(tight.rollout)(W, jax.random.key(4))
    x0 = np.asarray(plant.task.x0)
    mask, t, x = np.asarray(r.mask), np.asarray(r.t), np.asarray(r.x)
    starts = [i for i in range(1, T) if t[i] == 0 and t[i - 1] != 0]
    assert starts, "the small safe region never cut a rollout"
    for i in starts:
        assert i % every == 0
        np.testing.assert_array_equal(x[i], x0)
        left = i - 1 - np.argmax(mask[i - 1 :: -1])  # the last recorded row before the restart
        assert not mask[left + 1 : i].any() and i - (left + 1) <= every


def test_a_seeds_mpc_costs_do_not_depend_on_the_seeds_beside_it(model):
    """Seed chunks (:mod:`loopid.experiments.chunks`): 3 seeds' MPC test costs (4 trajectories
    each, every seed its own model) alone and among 7 seeds, bit for bit."""
    mc, W = model
    plant = short_hover()
    params = W[None] * (1.0 + 0.05 * jnp.arange(7.0))[:, None, None]  # 7 nearby models
    mpc = flown_by_mpc(plant, mc.dynamics, horizon=10, every=5, iterations=3).plant
    noise = eval_noise(plant, seed_keys(np.arange(7)), 4, "last").test
    run = jax.jit(mpc.eval_seeds)
    alone, among = run(params[:3], noise[:, :, :3])[0], run(params, noise)[0][:3]
    assert np.all(np.asarray(alone) < 1e4), alone
    np.testing.assert_array_equal(np.asarray(alone), np.asarray(among))
