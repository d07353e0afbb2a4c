"""The plant's batched test (every seed's test trajectories as one column batch) against one
trajectory at a time (``eval_one``), for a system with column support (the helicopter, with and
without delay) and one without (the linear system, through the ``vmap`` fallback)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.expert import expert_gains
from loopid.algorithms.loop import eval_noise, seed_keys
from loopid.algorithms.plant import make_plant, noise_columns
from loopid.experiments.families.helicopter import helicopter_plant
from loopid.systems.linear import linear_dynamics, linear_task
from loopid.systems.tasks import make_task


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
