"""The Gymnasium loop's ``test_policy = "best"``
(:func:`loopid.algorithms.gym_loop.run_learning_host`): the same training as ``last``, a
reported cost that is one of the costs ``last`` reported so far (the same test episodes), and
saved gains ``best_K`` that fly to the last reported cost."""

from pathlib import Path

import numpy as np

from loopid.algorithms import gym_loop
from loopid.experiments.families import gym
from loopid.experiments.families.gym.setup import gym_setup

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pendulum.toml"


def test_best_reports_a_policy_so_far_and_trains_as_last():
    fields, _ = gym.read_file(EXAMPLE)
    small = dict(horizon=100, num_envs=4, samples=100, test_trajectories=3, iterations=5, seeds=3)
    last = gym.run("dagger", gym.build("gym", {**fields, **small}))
    s = gym.build("gym", {**fields, **small, "test_policy": "best"})
    best = gym.run("dagger", s)

    # the test policy changes what is tested, never what is learned
    for name in ("loss_nu", "loss_policy", "online_loss", "policy_samples", "valid_samples"):
        np.testing.assert_array_equal(getattr(best.rows, name), getattr(last.rows, name), name)
    np.testing.assert_array_equal(best.final["K"], last.final["K"])

    a, b = last.rows.test_cost, best.rows.test_cost
    np.testing.assert_array_equal(b[:, 0], a[:, 0])  # π_1 is the only policy so far
    for seed in range(a.shape[0]):
        for n in range(a.shape[1]):
            assert b[seed, n] in a[seed, : n + 1], (seed, n)
    assert not np.array_equal(a, b)  # the selection did choose an earlier policy somewhere

    # the saved best gains fly, on the test episodes, to the last reported cost
    with gym_setup(s) as setup:
        costs, _ = gym_loop.test_episodes(
            setup.system, best.final["best_K"], [0, 1, 2], 3, setup.test_cost, s.termination,
            s.cost_cap,
        )  # fmt: skip
    np.testing.assert_array_equal(costs.mean(1), b[:, -1])
