"""The time-varying path end to end, against an oracle.

Give the agent's solver the true model linearised (in error coordinates about the target) along
the expert's own feasible trajectory: time-varying LQR on it must fly the noisy funnel as well as
the iLQR expert. A wrong model layout (the constant column, the time index), a wrong tvlqr, a
wrong policy convention or a wrong test would all show here.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms import loop
from loopid.algorithms.model_based import finite_horizon_gains
from loopid.systems import helicopter as h
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task


@pytest.mark.slow
def test_tvlqr_on_the_true_linearisation_flies_the_funnel_like_the_expert(funnel_expert):
    plant, K_expert = funnel_expert.plant, funnel_expert.K_expert
    task = plant.task
    flight = jax.jit(helicopter_plant(make_task("funnel", noise_std=0.0)).rollout)(
        K_expert, jax.random.key(0)
    )
    assert bool(flight.mask.all())
    target = jnp.asarray(task.target)

    def g(dx, du, t):  # the true noise-free step in error coordinates
        return h.to_error(h.step(h.from_error(dx, target[t]), du, jnp.zeros(6)), target[t + 1])

    def linearise(dx, du, t):
        A = jax.jacfwd(g, argnums=0)(dx, du, t)
        B = jax.jacfwd(g, argnums=1)(dx, du, t)
        offset = g(dx, du, t) - A @ dx - B @ du  # affine part, into the constant column
        A = A.at[:, -1].add(offset).at[-1].set(jnp.zeros(21).at[-1].set(1.0))
        return A, B

    A, B = jax.jit(jax.vmap(linearise))(flight.dx, flight.du, flight.t)  # one compilation
    K = finite_horizon_gains(A, B, task.Q, task.R, plant.horizon)
    noise = loop.eval_noise(plant, loop.seed_keys(np.arange(2)), 10, "last").test
    eval_seeds = jax.jit(plant.eval_seeds)  # compiled once for both policies
    oracle = eval_seeds(jnp.stack([K, K]), noise)[0]
    expert = eval_seeds(jnp.stack([K_expert, K_expert]), noise)[0]
    assert float(jnp.max(expert)) < 60.0  # SPEC: about 49.4
    np.testing.assert_allclose(np.asarray(oracle), np.asarray(expert), rtol=0.02)
