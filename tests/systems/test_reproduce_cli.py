"""Smoke test of the placeholder ``loopid reproduce``: its number agrees with the Gymnasium env."""

import re

import gymnasium
import numpy as np
from typer.testing import CliRunner

from loopid.cli import app


def test_reproduce_placeholder_matches_env_rollouts(tmp_path):
    result = CliRunner().invoke(app, ["reproduce", "--out", str(tmp_path), "--seeds", "2"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "hover_open_loop.txt").read_text() in result.output
    mean = float(re.search(r"mean total cost (\S+)", result.output).group(1))
    costs = []
    env = gymnasium.make("loopid/HelicopterHover-v0")
    for seed in (0, 1):
        env.reset(seed=seed)
        rewards = []
        for _ in range(400):
            _, r, _, truncated, info = env.step(np.zeros(4))
            rewards.append(r)
        assert truncated
        costs.append(-sum(rewards) + info["next_state_cost"])
    np.testing.assert_allclose(mean, np.mean(costs), rtol=1e-5)  # printed to 6 digits
