"""The two readings of a delay (SPEC §5.1, ``delay_mode``) and the ν readings under ``fifo``.

- ``latency`` and ``fifo`` fly the same closed loop for any fixed gain: the expert's test costs
  agree at every seed on the same noise (common random numbers), to round-off.
- Under ``latency`` the learner records the true transition: every recorded row is exactly
  ``step(x_t, Δu_t, w_t)`` (no delay), and the change is the gain applied to the state observed
  one step earlier; under ``fifo`` it is not (the contrast that makes the check able to fail).
- Under ``latency``, on a linear system with a one-step latency (the realisable case: the
  transition is Markov), DAgger's model converges to the true (A, B); under ``fifo`` it cannot.
- ``nu_pending = "rollout"``: ν_e's samples are the expert's own recorded transitions.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.contracts import LoopSpec
from loopid.algorithms.exploration import nu_expert, nu_trajectory
from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop_program import eval_noise, make_loop_program
from loopid.algorithms.model_based import linear_agent
from loopid.algorithms.plant import make_plant
from loopid.control import dlqr_affine
from loopid.learners import ftrl_least_squares
from loopid.models.linear_offset import LinearOffsetModel, to_matrices
from loopid.systems import helicopter
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task
from loopid.systems.linear import linear_dynamics, linear_task


@pytest.fixture(scope="module")
def delay_task():
    return make_task("hover-delay")


@pytest.fixture(scope="module")
def K(delay_task):
    """The linearised expert's gain ``[horizon, 4, 21]`` (SPEC §2)."""
    return expert_gains(delay_task)


def test_latency_and_fifo_give_the_expert_the_same_test_cost(delay_task, K):
    keys = seed_keys(np.arange(5))
    costs = {}
    for mode in ("fifo", "latency"):
        plant = helicopter_plant(delay_task, delay_mode=mode)
        W = eval_noise(plant, keys, 20, "last").test
        c, div = jax.jit(plant.eval_seeds)(jnp.broadcast_to(K, (5, *K.shape)), W)
        assert not np.asarray(div).any()
        costs[mode] = np.asarray(c)
        # the one-trajectory form agrees with the column batch under each mode
        one = plant.eval_one(K, jnp.moveaxis(W[:, :, 0, 0], 0, 0))
        np.testing.assert_allclose(float(one[0]), costs[mode][0, 0], rtol=1e-12)
    # the same closed loop: only the R term differs (commanded vs applied changes, ~1e-12)
    np.testing.assert_allclose(costs["latency"], costs["fifo"], rtol=1e-9)
    assert 40 < np.median(costs["fifo"]) < 100  # SPEC §3: about 62 at delay 1


def _replay(plant, tr, key):
    """Each recorded row's next state recomputed with the plain, undelayed step and the
    rollout's own process noise."""
    k_noise, _ = jax.random.split(key)
    noise = plant.dynamics.noise_sequence(k_noise, plant.horizon, plant.noise_std)
    target = jnp.asarray(plant.task.target)
    x_next = jax.vmap(helicopter.step)(tr.x, tr.du, noise)
    return jax.vmap(helicopter.to_error)(x_next, target[tr.t + 1])


def test_latency_records_the_true_transition(delay_task, K):
    key = jax.random.key(3)
    plant = helicopter_plant(delay_task, delay_mode="latency")
    tr = jax.jit(plant.rollout)(K, key, 0.01)
    assert bool(tr.mask.all())  # the expert stays in the safe region
    # the same arithmetic compiled differently: equal to the last bit or two
    np.testing.assert_allclose(np.asarray(_replay(plant, tr, key)), tr.dx_next, atol=1e-13)
    # the change acts on the state observed one step earlier (zero before anything was seen),
    # plus the action noise
    k_act = jax.random.split(key)[1]
    eps = 0.01 * jax.random.normal(k_act, (plant.horizon, 4), dtype=jnp.float64)
    expected = -jnp.einsum("mn,tn->tm", K[0], tr.dx[:-1]) + eps[1:]
    np.testing.assert_allclose(np.asarray(tr.du[1:]), np.asarray(expected), atol=1e-14)
    np.testing.assert_allclose(np.asarray(tr.du[0]), np.asarray(eps[0]), atol=1e-15)
    # ν queries under latency are plain one-step queries
    q = plant.query(tr.x[5], tr.du[5], tr.t[5], jax.random.key(9))
    w = plant.dynamics.noise_sequence(jax.random.key(9), 1, plant.noise_std)[0]
    plain = helicopter.to_error(helicopter.step(tr.x[5], tr.du[5], w), delay_task.target[6])
    np.testing.assert_allclose(np.asarray(q.dx_next), np.asarray(plain), atol=1e-13)


def test_fifo_records_the_command_not_the_applied_change(delay_task, K):
    key = jax.random.key(3)
    plant = helicopter_plant(delay_task, delay_mode="fifo")
    tr = jax.jit(plant.rollout)(K, key, 0.01)
    err = np.abs(np.asarray(_replay(plant, tr, key)) - np.asarray(tr.dx_next))
    assert err.max() > 1e-3  # the recorded command is not what moved the state


def test_nu_rollout_keeps_the_experts_own_transitions(delay_task, K):
    plant = helicopter_plant(delay_task, nu_pending="rollout")
    sample = jax.jit(nu_expert(plant, K), static_argnums=1)(jax.random.key(4), 50)
    # each sample is a row of the expert's rollout: a commanded change that acts one step later,
    # so the plain undelayed step does not give its next state (it does under "hold" queries)
    x_next = jax.vmap(helicopter.step)(sample.x, sample.du, jnp.zeros((50, 6)))
    target = jnp.asarray(delay_task.target)
    plain = jax.vmap(helicopter.to_error)(x_next, target[sample.t + 1])
    # the applied change is the recorded du_prev of the next state, not the sample's du
    applied = np.asarray(sample.dx_next[:, 4:8])
    assert np.abs(applied - np.asarray(sample.du)).max() > 1e-3
    held = helicopter_plant(delay_task, nu_pending="hold")
    queried = jax.jit(nu_expert(held, K), static_argnums=1)(jax.random.key(4), 50)
    np.testing.assert_array_equal(np.asarray(queried.dx_next[:, 4:8]), np.asarray(queried.du))
    assert np.isfinite(np.asarray(plain)).all()


# ---------------------------------------------------------------- the realisable linear case
K_STATE, M_ACT, HORIZON, ITERATIONS = 3, 2, 100, 12


def _dagger_model(delay_mode: str):
    """DAgger-ν_t on x' = Ax + Bu + w with a one-step delay under ``delay_mode``; returns the
    fitted (Â, B̂) of each seed and the truth in error coordinates."""
    rng = np.random.default_rng(1)
    A = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.1], [0.0, 0.0, 0.95]])
    B = 0.3 * rng.normal(size=(K_STATE, M_ACT))
    task = linear_task(np.eye(K_STATE), 0.1 * np.eye(M_ACT), np.ones(K_STATE), HORIZON,
                       noise_std=0.1)._replace(delay=1)  # fmt: skip
    plant = make_plant(task, linear_dynamics(A, B), stop_norm=50.0, delay_mode=delay_mode)
    nominal = LinearOffsetModel(jnp.eye(K_STATE + 1), jnp.zeros((K_STATE + 1, M_ACT)))
    learner = ftrl_least_squares(1e-3)
    agent = linear_agent(nominal, learner, task.Q, task.R, HORIZON)
    nu = nu_trajectory(plant, state_var=0.25, action_var=0.25)
    program = make_loop_program(LoopSpec(plant, agent, nu, samples=100, n_test=10), ITERATIONS)
    keys = seed_keys(np.arange(3))
    noise = eval_noise(plant, keys, 10, "last")
    carry, _ = program.start(keys, noise)
    for n in range(2, ITERATIONS + 1):
        carry, _ = program.step(carry, keys, noise, jnp.int32(n), jnp.float64(0.5))
    A_hat, B_hat = to_matrices(nominal, jax.vmap(learner.weights)(carry.learner.learner))
    Ae = np.zeros((K_STATE + 1, K_STATE + 1))
    Ae[:K_STATE, :K_STATE], Ae[K_STATE, K_STATE] = A, 1.0
    Be = np.zeros((K_STATE + 1, M_ACT))
    Be[:K_STATE] = B
    return np.asarray(A_hat), np.asarray(B_hat), Ae, Be, task


@pytest.mark.slow
def test_latency_dagger_recovers_the_true_model_on_a_linear_system():
    A_hat, B_hat, Ae, Be, task = _dagger_model("latency")
    # 1100 transitions of noise std 0.1, all Markov: every entry within a few 1e-2
    np.testing.assert_allclose(A_hat, np.broadcast_to(Ae, A_hat.shape), atol=0.04)
    np.testing.assert_allclose(B_hat, np.broadcast_to(Be, B_hat.shape), atol=0.04)
    assert np.max(np.abs(Be)) > 0.2  # the nominal (B = 0) is far from the truth
    assert dlqr_affine(Ae, Be, task.Q, task.R).K.shape == (M_ACT, K_STATE + 1)


@pytest.mark.slow
def test_fifo_dagger_cannot_recover_the_true_model_on_a_linear_system():
    A_hat, B_hat, Ae, Be, _ = _dagger_model("fifo")
    # the policy half records commands that act a step later: not in the model class
    err = max(np.abs(A_hat - Ae).max(), np.abs(B_hat - Be).max())
    assert err > 0.1, err
