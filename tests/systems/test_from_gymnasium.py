"""Any Gymnasium env as the real system: the adapter, its seeding, and the host loop."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.gym_loop import (
    Exploration,
    episode_costs,
    gym_agent,
    gym_nominal_model,
    make_host_program,
    run_learning_host,
)
from loopid.systems import helicopter
from loopid.systems.from_gymnasium import GymSystem
from loopid.systems.gym_cost import observation_cost
from loopid.systems.gym_policies import CallablePolicy, LinearPolicy
from loopid.systems.gym_slots import Slot, slot_streams

PENDULUM = {"reset_options": {"x_init": 0.3, "y_init": 0.5}}


class Integrator(gymnasium.Env):
    """x' = x + a on [-2, 2]; terminated when |x'| > 1; actions clipped by the adapter to ±0.5."""

    def __init__(self):
        self.observation_space = gymnasium.spaces.Box(-2.0, 2.0, (1,), np.float64)
        self.action_space = gymnasium.spaces.Box(-0.5, 0.5, (1,), np.float64)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.np_random.uniform(-0.2, 0.2, size=1)
        return self.x.copy(), {}

    def step(self, a):
        self.x = np.clip(self.x + a, -2.0, 2.0)
        return self.x.copy(), -float(self.x @ self.x), bool(abs(self.x[0]) > 1.0), False, {}


def integrator(max_steps=None):
    def make():
        env = Integrator()
        return env if max_steps is None else gymnasium.wrappers.TimeLimit(env, max_steps)

    return make


# ----------------------------------------------------------------------------- equivalence
def native_closed_loop(K, x_star, noise):
    """The JAX path: x_{t+1} = helicopter.step(x_t, −K [x_t − x*; 1], w_t) by lax.scan."""

    def body(x, w):
        du = -K @ jnp.concatenate([x - x_star, jnp.ones(1)])
        return helicopter.step(x, du, w), (x, du)

    _, (X, U) = jax.lax.scan(body, x_star, noise)
    return np.asarray(X), np.asarray(U)


@pytest.mark.slow
def test_helicopter_through_the_adapter_matches_the_native_jax_path(rng):
    T = 40
    x_star = helicopter.hover_target()
    K = 0.01 * rng.standard_normal((helicopter.N_ACTION, helicopter.N_STATE + 1))
    with GymSystem(
        "loopid/HelicopterHover-v0", target=np.asarray(x_star), horizon=T, num_envs=2
    ) as system:
        slots = [Slot(0, 0, seed, 0.0, restart=False) for seed in (3, 17, 2024)]
        r = system.rollouts([system.linear_policy(K)], slots)
    assert r.mask.all() and (r.steps == T).all() and not r.terminated.any()
    for i, slot in enumerate(slots):
        _, g = slot_streams(slot, T, helicopter.N_ACTION)
        noise_seed = int(g.integers(2**32))  # the env's reset seed = its noise seed
        noise = helicopter.noise_sequence(jax.random.key(noise_seed), T, 1.0)
        X, U = native_closed_loop(jnp.asarray(K), x_star, noise)
        np.testing.assert_allclose(r.x[i], X, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(r.du[i], U, rtol=1e-10, atol=1e-12)
        # open loop through the library's own rollout with the adapter's recorded actions
        X_open = helicopter.rollout(x_star, r.du[i], noise)
        x_next = r.dx_next[i, :, :-1] + np.asarray(x_star)
        np.testing.assert_allclose(x_next, X_open[1:], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(r.dx[i, :, :-1], X - np.asarray(x_star), atol=1e-10)
        assert (r.dx[i, :, -1] == 1.0).all() and (r.dx_next[i, :, -1] == 1.0).all()


# ----------------------------------------------------------------------------- seeding
def test_rollouts_depend_on_the_slot_seeds_only():
    slots = [Slot(0, 0, 10 + i, 0.3, restart=True) for i in range(5)] + [
        Slot(0, 0, 99, 0.0, restart=False)
    ]
    K = np.array([[0.0, 8.0, 1.5]])
    runs = []
    for num_envs in (1, 3):
        with GymSystem(
            "Pendulum-v1", target=[1.0, 0.0, 0.0], horizon=60, num_envs=num_envs, stop_norm=0.6,
            **PENDULUM,
        ) as system:  # fmt: skip
            runs.append(system.rollouts([system.linear_policy(K)], slots))
            runs.append(system.rollouts([system.linear_policy(K)], slots))
    for other in runs[1:]:
        for a, b in zip(runs[0], other, strict=True):
            np.testing.assert_array_equal(a, b)
    other_seed = [s._replace(seed=s.seed + 1000) for s in slots]
    with GymSystem("Pendulum-v1", target=[1.0, 0.0, 0.0], horizon=60, **PENDULUM) as system:
        r = system.rollouts([system.linear_policy(K)], other_seed)
    assert not np.array_equal(r.x, runs[0].x)


# ----------------------------------------------------------------------------- episodes
def test_terminated_truncated_clipping_and_restarts():
    push = CallablePolicy(lambda o: np.array([2.0]), 1)  # clipped to 0.5: |x| > 1 after ~3 steps
    with GymSystem(integrator(), target=[0.0], horizon=10, num_envs=2) as system:
        r = system.rollouts([push], [Slot(0, 0, 1, restart=False), Slot(0, 0, 2, restart=True)])
    np.testing.assert_array_equal(r.du[r.mask], 0.5)  # the applied (clipped) action
    np.testing.assert_allclose(r.dx_next[r.mask], r.dx[r.mask] + [0.5, 0.0], atol=1e-15)
    test, train = 0, 1
    n = r.steps[test]
    assert r.terminated[test] and n in (3, 4)
    assert r.mask[test, :n].all() and not r.mask[test, n:].any()
    assert abs(r.x[test, n - 1, 0] + 0.5) > 1.0  # the terminal observation is recorded
    assert r.mask[train].all() and r.steps[train] == 10  # restarted until the buffer is full
    t = r.t[train]
    assert t[0] == 0 and (np.diff(t) <= 1).all() and (t == 0).sum() >= 2
    # truncation by the env's TimeLimit (4 steps) before the horizon
    hold = CallablePolicy(lambda o: np.array([0.0]), 1)
    with GymSystem(integrator(max_steps=4), target=[0.0], horizon=10, num_envs=1) as system:
        r = system.rollouts([hold], [Slot(0, 0, 5, restart=False), Slot(0, 0, 6, restart=True)])
    assert r.steps[0] == 4 and not r.terminated[0] and r.mask[0, :4].all()
    np.testing.assert_array_equal(r.t[1], [0, 1, 2, 3, 0, 1, 2, 3, 0, 1])


def test_linear_policy_and_observation_cost_closed_forms(rng):
    K = rng.standard_normal((2, 4))
    target, a_op = rng.standard_normal(3), rng.standard_normal(2)
    obs = rng.standard_normal((5, 3))
    a = LinearPolicy(K, target, a_op).act(obs, np.zeros(5, int), np.zeros(5, int))
    dx = np.concatenate([obs - target, np.ones((5, 1))], axis=1)
    np.testing.assert_allclose(a, a_op - dx @ K.T, rtol=1e-14)
    cost = observation_cost(target, [1.0, 2.0, 3.0], 0.5 * np.eye(2), a_op)
    e, d = obs[0] - target, a[0] - a_op
    assert cost(obs[0], a[0]) == pytest.approx(e @ np.diag([1.0, 2.0, 3.0]) @ e + 0.5 * d @ d)
    np.testing.assert_allclose(cost(obs, a), [cost(o, u) for o, u in zip(obs, a, strict=True)])
    Qa, _ = cost.augmented()
    assert Qa.shape == (4, 4) and Qa[3].sum() == 0 and Qa[:, 3].sum() == 0
    with pytest.raises(ValueError, match="Q must"):
        observation_cost(target, np.eye(2), [1.0])


def test_reward_cost_matches_the_pendulum_formula():
    K = np.array([[0.0, 6.0, 1.0]])
    with GymSystem("Pendulum-v1", target=[1.0, 0.0, 0.0], horizon=30, **PENDULUM) as system:
        r = system.rollouts(
            [system.linear_policy(K)], [Slot(0, 0, s, 0.5, False) for s in range(3)]
        )
        from_reward, _ = episode_costs(system, r, "reward")

        def pendulum(obs, action):  # Gymnasium's Pendulum-v1 cost, from the observation
            th = np.arctan2(obs[1], obs[0])
            return th**2 + 0.1 * obs[2] ** 2 + 0.001 * float(action[0]) ** 2

        by_hand, _ = episode_costs(system, r, pendulum)
    np.testing.assert_allclose(from_reward, by_hand, rtol=1e-5)  # float32 observations


# ----------------------------------------------------------------------------- bad input
def test_discrete_spaces_and_unknown_ids_are_refused():
    with pytest.raises(ValueError, match="Discrete"):
        GymSystem("CartPole-v1", target=[0.0] * 4)
    with pytest.raises(ValueError, match="cannot make env"):
        GymSystem("NoSuchEnv-v7", target=[0.0])
    with pytest.raises(ValueError, match="target must be 3"):
        GymSystem("Pendulum-v1", target=[0.0, 0.0])
    with pytest.raises(ValueError, match="observe"):
        GymSystem("Pendulum-v1", target=[0.0, 0.0], observe=[1, 5])


# ----------------------------------------------------------------------------- the host loop
@pytest.mark.slow
def test_host_loop_semantics_and_common_random_numbers():
    with GymSystem(
        "Pendulum-v1", target=[0.0, 0.0], observe=[1, 2], horizon=50, num_envs=4, stop_norm=1.0,
        **PENDULUM,
    ) as system:  # fmt: skip
        cost = observation_cost([0.0, 0.0], [1.0, 0.1], [0.001])
        agent = gym_agent(system, cost, gym_nominal_model(system))
        nu = Exploration(system.linear_policy(np.array([[3.0, 0.5]])), 0.5)
        cell = make_host_program(agent, samples=60)
        run = dict(samples=60, n_test=3, cost=cost, program=cell)
        dagger = run_learning_host(system, agent, nu, [0.0, 0.5, 0.5], [0, 1], **run)
        batch = run_learning_host(system, agent, nu, [0.0, 0.0, 0.0], [0, 1], **run)
        again = run_learning_host(system, agent, nu, [0.0, 0.5, 0.5], [0, 1], **run)
    rows = dagger.rows
    assert rows.test_cost.shape == (2, 3)
    np.testing.assert_array_equal(dagger.samples, [0, 60, 120])
    # iteration 1: the same initial model tested on the same episodes by every method
    np.testing.assert_array_equal(rows.test_cost[:, 0], batch.rows.test_cost[:, 0])
    assert (rows.valid_samples[:, 0] == 0).all() and (rows.valid_samples[:, 1:] > 0).all()
    assert (batch.rows.policy_samples == 0).all()
    assert (rows.policy_samples[:, 1:] > 0).all()
    assert (rows.policy_samples[:, 1:] < rows.valid_samples[:, 1:]).all()
    assert (rows.test_cost[:, -1] < 0.1 * rows.test_cost[:, 0]).all()
    for a, b in zip(dagger.rows, again.rows, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
