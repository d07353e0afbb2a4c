"""The JAX Pendulum-v1 against Gymnasium's own env, its error coordinates, the hanging start."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.systems import pendulum
from loopid.systems.pendulum import PendulumHangingEnv, PendulumParams


def gym_step(env, x, u):
    """One step of Gymnasium's PendulumEnv from state ``x`` with action ``u`` (float64)."""
    env.state = np.array(x, np.float64)
    obs, reward, *_ = env.step(np.array(u, np.float64))
    return np.array(env.state), np.asarray(obs, np.float64), -float(reward)


def random_pairs(rng, k):
    """States spanning several turns and beyond the speed limit, torques beyond the torque limit,
    so that both clips are exercised."""
    th = rng.uniform(-3 * np.pi, 3 * np.pi, k)
    thdot = rng.uniform(-10.0, 10.0, k)
    u = rng.uniform(-4.0, 4.0, (k, 1))
    return np.stack([th, thdot], axis=1), u


def test_step_and_cost_equal_gymnasium(rng):
    env = gymnasium.make("Pendulum-v1").unwrapped
    env.reset(seed=0)
    X, U = random_pairs(rng, 400)
    ours = jax.jit(jax.vmap(pendulum.step))(X, U)
    c = jax.jit(jax.vmap(pendulum.cost))(X, U)
    clipped_u = clipped_v = 0
    for i in range(len(X)):
        x_next, obs, cost = gym_step(env, X[i], U[i])
        np.testing.assert_allclose(ours[i], x_next, rtol=0, atol=1e-12)
        np.testing.assert_allclose(c[i], cost, rtol=0, atol=1e-12)
        np.testing.assert_allclose(pendulum.observe(ours[i]), obs, atol=1e-6)  # obs are float32
        clipped_u += abs(U[i, 0]) > 2
        clipped_v += abs(x_next[1]) == 8.0
    assert clipped_u > 50 and clipped_v > 20  # both clips were exercised


def test_step_obs_commutes_with_to_error(rng):
    """step_obs(to_error(x)) = to_error(step(x)): the error-coordinate dynamics are the same map."""
    X, U = random_pairs(rng, 200)
    dX = pendulum.to_error(X)
    np.testing.assert_allclose(dX[:, -1], 1.0)
    np.testing.assert_allclose(dX[:, :3] + pendulum.TARGET, pendulum.observe(X), atol=0)
    lhs = jax.vmap(pendulum.step_obs)(dX, U)
    rhs = pendulum.to_error(jax.vmap(pendulum.step)(X, U))
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)
    # Gym's cost read from the error coordinates
    np.testing.assert_allclose(
        jax.vmap(pendulum.cost_obs)(dX, U), jax.vmap(pendulum.cost)(X, U), rtol=0, atol=1e-12
    )
    # from_error inverts to_error up to whole turns
    back = pendulum.from_error(dX)
    np.testing.assert_allclose(np.cos(back[:, 0] - X[:, 0]), 1.0, atol=1e-12)
    np.testing.assert_allclose(back[:, 1], X[:, 1])


def test_step_obs_jacobian_matches_finite_differences(rng):
    """Inside the clips the autodiff Jacobians are the true ones (central differences)."""
    dx = pendulum.to_error(jnp.array([2.0, 1.5]))
    du = jnp.array([0.7])
    A, B = jax.jacfwd(pendulum.step_obs, argnums=(0, 1))(dx, du)
    h = 1e-6
    for j in range(3):
        e = jnp.zeros(4).at[j].set(h)
        fd = (pendulum.step_obs(dx + e, du) - pendulum.step_obs(dx - e, du)) / (2 * h)
        np.testing.assert_allclose(A[:, j], fd, atol=1e-7)
    fd = (pendulum.step_obs(dx, du + h) - pendulum.step_obs(dx, du - h)) / (2 * h)
    np.testing.assert_allclose(B[:, 0], fd, atol=1e-7)
    # beyond the torque limit the torque has no effect: the clip kills the gradient
    _, B_out = jax.jacfwd(pendulum.step_obs, argnums=(0, 1))(dx, jnp.array([2.5]))
    np.testing.assert_allclose(B_out, 0.0)


def test_params_are_traceable():
    """The physical constants can be traced arguments (one compilation for many values)."""
    f = jax.jit(lambda p, x, u: pendulum.step(x, u, None, p))
    x, u = jnp.array([0.3, 0.1]), jnp.array([0.5])
    p = PendulumParams(*(jnp.asarray(v) for v in PendulumParams()))
    np.testing.assert_allclose(f(p, x, u), pendulum.step(x, u), atol=1e-15)
    p2 = p._replace(g=jnp.asarray(9.81))
    env = gymnasium.make("Pendulum-v1", g=9.81).unwrapped
    env.reset(seed=0)
    np.testing.assert_allclose(f(p2, x, u), gym_step(env, x, u)[0], atol=1e-12)


def test_hanging_env_starts_down_and_steps_like_pendulum():
    env = gymnasium.make("loopid/PendulumHanging-v0")
    assert env.spec.max_episode_steps == 200
    obs, _ = env.reset(seed=3)
    np.testing.assert_allclose(obs, [-1.0, 0.0, 0.0], atol=1e-7)
    obs, _ = env.reset(seed=3, options={"noise": 0.2})
    th, thdot = env.unwrapped.state
    assert abs(th - np.pi) <= 0.2 and th != np.pi and thdot == 0.0
    obs2, _ = env.reset(seed=3, options={"noise": 0.2})
    np.testing.assert_array_equal(obs, obs2)  # seeded
    x = env.unwrapped.state.copy()
    # a float64 action: with a float32 one Gym computes 0.001 u² in float32 (~5e-11 off)
    obs, reward, *_ = env.step(np.array([1.0]))
    np.testing.assert_allclose(env.unwrapped.state, pendulum.step(x, jnp.array([1.0])), atol=1e-12)
    assert reward == pytest.approx(-float(pendulum.cost(x, jnp.array([1.0]))), abs=1e-12)
    noisy = gymnasium.make("loopid/PendulumHanging-v0", noise=0.1)
    starts = [noisy.reset(seed=s)[0] for s in range(20)]
    th = np.arctan2(np.array(starts)[:, 1], np.array(starts)[:, 0])
    assert np.all(np.abs(np.abs(th) - np.pi) <= 0.1 + 1e-6)
    assert np.std(np.sin(th)) > 0.01


@pytest.mark.parametrize("bad", [-0.1, float("nan"), 4.0])
def test_bad_noise_raises(bad):
    with pytest.raises(ValueError, match="noise must be"):
        PendulumHangingEnv(noise=bad)
