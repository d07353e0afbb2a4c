"""The Gymnasium adapter: API conformance, determinism, and agreement with the JAX core."""

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from loopid.systems import helicopter as h
from loopid.systems.base import trajectory_cost
from loopid.systems.helicopter.gymnasium_env import HelicopterEnv

IDS = ["loopid/HelicopterHover-v0", "loopid/HelicopterHoverDelay-v0", "loopid/HelicopterFunnel-v0"]


# Both spaces are deliberately unbounded (no control saturation; a diverging controller drives
# the state past any bound), so check_env's advice about infinite/unnormalised Box limits is
# expected; every other warning stays an error.
@pytest.mark.filterwarnings("ignore:.*A Box (action|observation) space (minimum|maximum) value is")
@pytest.mark.filterwarnings("ignore:.*For Box action spaces, we recommend using a symmetric")
@pytest.mark.parametrize("env_id", IDS)
def test_check_env(env_id):
    env = gymnasium.make(env_id)
    check_env(env.unwrapped)
    env.close()


def test_registered_defaults():
    tasks = [gymnasium.make(i).unwrapped.task for i in IDS]
    assert [(t.name, t.noise_std, t.delay) for t in tasks] == [
        ("hover", 1.0, 0),
        ("hover-delay", 1.0, 1),
        ("funnel", 0.1, 0),
    ]


def test_noise_free_trim_hover_is_deterministic():
    env = gymnasium.make("loopid/HelicopterHover-v0", noise_std=0.0)
    obs, _ = env.reset(seed=3)
    target = np.asarray(h.hover_target())
    np.testing.assert_array_equal(obs, target)
    for t in range(400):
        obs, reward, terminated, truncated, info = env.step(np.zeros(4))
        assert not terminated and truncated == (t == 399)
        assert np.max(np.abs(obs - target)) < 1e-9 and abs(reward) < 1e-12
    assert info["next_state_cost"] < 1e-12
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(4))


def test_kwargs_override():
    env = gymnasium.make("loopid/HelicopterHover-v0", noise_std=0.0, delay=2).unwrapped
    assert (env.task.noise_std, env.task.delay) == (0.0, 2)
    env.reset(seed=0)
    du = np.array([0.0, 0.0, 0.0, 0.01])
    seen = [env.step(a)[0][h.DU_PREV] for a in (du, np.zeros(4), np.zeros(4))]
    np.testing.assert_array_equal(seen, [np.zeros(4), np.zeros(4), du])
    funnel = gymnasium.make("loopid/HelicopterFunnel-v0", noise_std=0.5).unwrapped
    assert funnel.task.noise_std == 0.5


def _episode(env, seed, actions):
    obs = [env.reset(seed=seed)[0]]
    out = [env.step(a) for a in actions]
    return np.array(obs + [o[0] for o in out]), np.array([o[1] for o in out]), out[-1][4]


def test_same_seed_same_observations(rng):
    env = gymnasium.make("loopid/HelicopterHoverDelay-v0")
    actions = 0.01 * rng.normal(size=(20, 4))
    a, _, _ = _episode(env, 11, actions)
    b, _, _ = _episode(env, 11, actions)
    c, _, _ = _episode(env, 12, actions)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    # a seedless reset continues the env's random stream instead of repeating the episode
    env.reset(seed=11)
    _, info = env.reset()
    assert info["noise_seed"] != 11


@pytest.mark.parametrize("env_id", ["loopid/HelicopterHoverDelay-v0", "loopid/HelicopterFunnel-v0"])
def test_env_reproduces_the_jax_rollout_and_the_task_cost(env_id, rng):
    env = gymnasium.make(env_id).unwrapped
    task = env.task
    actions = 0.01 * rng.normal(size=(task.horizon, 4))
    X_env, rewards, last_info = _episode(env, 5, actions)
    noise = h.noise_sequence(jax.random.key(env.noise_seed), task.horizon, task.noise_std)
    X = np.asarray(h.rollout(task.x0, actions, noise, delay=task.delay))
    np.testing.assert_allclose(X_env, X, rtol=1e-13, atol=1e-13)
    dX = jax.vmap(h.to_error)(X, task.target)
    total = trajectory_cost(dX, actions, task.Q, task.R)
    np.testing.assert_allclose(-rewards.sum() + last_info["next_state_cost"], total, rtol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"task": "loop"}, r"'loop'"),
        ({"noise_std": -0.1}, r"noise_std .*-0\.1"),
        ({"delay": -1}, r"delay .*-1"),
        ({"render_mode": "human"}, r"render_mode .*'human'"),
    ],
)
def test_env_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        HelicopterEnv(**kwargs)


def test_env_rejects_bad_actions():
    env = HelicopterEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action .*shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match=r"action .*nan"):
        env.step(np.array([0.0, np.nan, 0.0, 0.0]))
