"""The plant's batched test (every seed's test trajectories as one column batch) against one
trajectory at a time (``eval_one``), for a system with column support (the helicopter, with and
without delay) and one without (the linear system, through the ``vmap`` fallback); a seed's test
costs bit for bit the same beside any number of other seeds (seed chunks); ``ordered_sum``."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop_program import eval_noise
from loopid.algorithms.plant import make_plant, noise_columns, ordered_sum
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task
from loopid.systems.linear import linear_dynamics, linear_task


def _check(plant, K, n_test=7, seeds=3):
    W = eval_noise(plant, seed_keys(np.arange(seeds)), n_test, "last").test
    costs, diverged = jax.jit(plant.eval_seeds)(K, W)
    per_seed = jnp.moveaxis(W, (2, 3), (0, 1))  # [S, n_test, horizon, k]
    one = jax.jit(jax.vmap(lambda k, w: jax.vmap(lambda ww: plant.eval_one(k, ww))(w)))
    ref_costs, ref_div = one(K, per_seed)
    np.testing.assert_allclose(costs, ref_costs, rtol=1e-12)
    np.testing.assert_array_equal(diverged, ref_div)
    np.testing.assert_array_equal(noise_columns(per_seed), W)
    return np.asarray(costs), np.asarray(diverged)


@pytest.mark.parametrize("name", ["hover", "hover-delay"])
def test_helicopter_columns_equal_one_at_a_time(name):
    task = make_task(name)
    plant = helicopter_plant(task)
    L = jnp.broadcast_to(expert_gains(task), (plant.horizon, 4, 21))
    # seed 0 the expert, seed 1 nothing (drifts, ~1e6), seed 2 a destabilising gain (the cap)
    K = jnp.stack([L, jnp.zeros_like(L), -3.0 * L])
    costs, diverged = _check(plant, K)
    assert np.all(costs[0] < 200) and not diverged[0].any()
    assert np.all((costs[1] > 1e4) & (costs[1] < 1e8))
    assert np.all(costs[2] == 1e8) and diverged[2].all()


def test_linear_system_through_the_vmap_fallback(rng):
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.0], [0.1]])
    task = linear_task(np.eye(2), 0.1 * np.eye(1), [1.0, 0.0], 50, noise_std=0.1)
    plant = make_plant(task, linear_dynamics(A, B))
    K = jnp.asarray(rng.normal(size=(3, 50, 1, 3)))
    _check(plant, K)


@pytest.mark.parametrize("name", ["hover", "hover-delay"])
def test_a_seeds_test_costs_do_not_depend_on_the_seeds_beside_it(name):
    """Seed chunks (issue 18): 5 seeds' 100 test trajectories each, alone (500 columns) and
    among 45 seeds (4,500 columns), give the same costs bit for bit, in the column batch
    (``eval_seeds``) and in a vmapped batch of ``eval_one`` (the mixture policy's path).
    Before the costs were summed in a fixed order, ``jnp.sum`` over the 21 error coordinates
    changed 115 of these 500 costs in their last bit (measured)."""
    task = make_task(name)
    plant = helicopter_plant(task)
    L = jnp.broadcast_to(expert_gains(task), (plant.horizon, 4, 21))
    K = jnp.stack([L, jnp.zeros_like(L), -3.0 * L, 0.5 * L, 1.7 * L])
    W = eval_noise(plant, seed_keys(np.arange(45)), 100, "last").test
    run = jax.jit(plant.eval_seeds)
    alone, among = run(K, W[:, :, :5]), run(jnp.concatenate([K] * 9), W)
    for a, b in zip(alone, among, strict=True):
        np.testing.assert_array_equal(a, b[:5])
    assert np.unique(np.asarray(alone[0])).size > 300  # real, distinct costs (not all capped)

    one = jax.jit(jax.vmap(plant.eval_one, in_axes=(None, 0)))
    per_run = jnp.moveaxis(W, (2, 3), (0, 1)).reshape(-1, *W.shape[:2])  # [45·100, horizon, k]
    np.testing.assert_array_equal(one(L, per_run[:7])[0], one(L, per_run)[0][:7])


def test_ordered_sum_adds_every_term_once_in_its_documented_order():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 7, 21, 100):  # integers: any order is exact, a lost term shows
        x = rng.integers(-1000, 1000, size=(4, n, 5)).astype(np.float64)
        np.testing.assert_array_equal(ordered_sum(x, axis=1), x.sum(axis=1))
    assert ordered_sum(np.zeros((0, 3)), axis=0).shape == (3,)
    # pairwise halving: (x0 + x2) + (x1 + x3) = 0 + 2; left to right would give 1
    assert float(ordered_sum(jnp.array([1e16, 1.0, -1e16, 1.0]))) == 2.0
    # a long odd length: within rounding of the exact sum
    x = rng.normal(size=(1001,)) * 10.0 ** rng.integers(-5, 5, 1001)
    assert abs(float(ordered_sum(x)) - math.fsum(x)) <= 1e-13 * np.abs(x).sum()


def test_ordered_sum_of_a_column_does_not_depend_on_the_columns_beside_it():
    """``jnp.sum(v, axis=0)`` of ``v [21, b]`` changes some columns in the last bit between
    b = 1,400 and 4,000 on XLA's CPU backend (measured: ~1 in 3); ``ordered_sum`` must not, over
    either axis."""
    rng = np.random.default_rng(1)
    v = rng.normal(size=(21, 4000)) * 10.0 ** rng.integers(-3, 3, (21, 4000))
    total = jax.jit(lambda a: ordered_sum(a, axis=0))
    for b in (3, 100, 1400, 1403, 2000):
        np.testing.assert_array_equal(total(v[:, :b]), total(v)[:b])
    rows = jax.jit(lambda a: ordered_sum(a, axis=-1))
    c = v.reshape(-1)[: 64 * 100].reshape(64, 100)  # seeds x test trajectories
    for S in (3, 40, 41, 64):
        np.testing.assert_array_equal(rows(c[:S]), rows(c)[:S])
