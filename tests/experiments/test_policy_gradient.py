"""The model-free policy-gradient baseline on hover (issue 5 "Must show" 5; SPEC §2).

The issue asks that it lowers its cost over 20 iterations of 500 samples. With the current
defaults (``pg_horizon = 25``, ``pg_sigma = 0.01``, ``pg_step = 0.05``) it does not: the first
step makes every seed's test cost jump from ~2.5e6 to the 1e8 cap. The gradient of the 25-step
surrogate (rollouts from ν_t-like states) points where the 400-step test cost grows — even the
exact (autodiff) gradient of that surrogate does, at normalised steps of 1e-3 — and smaller
steps (2e-4) or a 100-step horizon only slow the growth. Kept as a strict xfail so that it turns
into a failure (and the mark is removed) once the lead settles the baseline's defaults.
"""

import numpy as np
import pytest

from loopid.experiments.results import trace_table
from loopid.experiments.runner import run
from loopid.experiments.scenarios import scenario

SCENARIO = scenario("hover", iterations=20, samples=500, seeds=2, test_trajectories=50)


@pytest.fixture(scope="module")
def trace():
    return run("pg", SCENARIO)


@pytest.mark.slow
def test_pg_trace_is_well_formed(trace):
    rows = trace.rows
    assert rows.test_cost.shape == (SCENARIO.seeds, SCENARIO.iterations)
    trace_table(SCENARIO.name, "pg", trace)  # no NaN
    assert np.all(rows.test_cost <= SCENARIO.cost_cap)
    assert np.all((rows.diverged >= 0) & (rows.diverged <= SCENARIO.test_trajectories))
    # each iteration spends the m transitions of the other methods (2·P rollouts of H steps)
    pairs = SCENARIO.samples // (2 * SCENARIO.pg_horizon)
    assert np.all(rows.valid_samples[:, 1:] == 2 * pairs * SCENARIO.pg_horizon)
    assert 2 * pairs * SCENARIO.pg_horizon <= SCENARIO.samples
    # it starts from the model-based methods' π_1, which barely acts (SPEC §4.4: ~2.6e6)
    assert np.all((rows.test_cost[:, 0] > 1e6) & (rows.test_cost[:, 0] < 1e7))


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="PG with the default pg_step/pg_horizon diverges on hover (see module docstring)",
)
def test_pg_lowers_its_cost(trace):
    c = trace.rows.test_cost
    assert np.median(c[:, -1]) < np.median(c[:, 0]), np.median(c, axis=0)
