"""A lane set's pieces that need no system: the test noise repeated per method
(:func:`loopid.algorithms.loop_program.lane_noise`) and the shape of the schedules
:func:`loopid.algorithms.loop.run_lanes` takes.

That a lane set gives each method the numbers it has alone, bit for bit, is checked on small
finite MDPs in ``tests/experiments/test_lanes.py`` (their plant and agent are the MDP
family's) and on the helicopter end to end in ``tests/experiments/test_lane_sets.py``."""

import numpy as np
import pytest

from loopid.algorithms.contracts import EvalNoise, LoopSpec
from loopid.algorithms.loop import run_lanes
from loopid.algorithms.loop_program import lane_noise

SEEDS = np.arange(4)


def test_lane_noise_repeats_each_seed_method_major():
    w = np.arange(2 * 3 * 4 * 5, dtype=float).reshape(2, 3, 4, 5)  # [horizon, n_noise, S, n]
    noise = lane_noise(EvalNoise(w, np.zeros(0)), 3)
    tiled = np.asarray(noise.test)
    assert tiled.shape == (2, 3, 12, 5) and noise.select.shape == (0,)
    for m in range(3):
        np.testing.assert_array_equal(tiled[:, :, 4 * m : 4 * (m + 1)], w)


def test_schedules_must_be_methods_by_iterations():
    with pytest.raises(ValueError, match="schedules must be"):
        run_lanes(LoopSpec(None, None, None, samples=1, n_test=1), [0.5, 0.5], SEEDS)
    with pytest.raises(ValueError, match="policy fractions must lie in"):
        run_lanes(LoopSpec(None, None, None, samples=1, n_test=1), [[0.5, 1.5]], SEEDS)
