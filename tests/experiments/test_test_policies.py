"""Test-time policies (SPEC §1): ``best`` reports one of the policies ``last`` reported (the same
training, the same test noise), ``mixture`` at iteration 1 is π_1."""

import numpy as np
import pytest

from loopid.experiments.families.helicopter import run
from loopid.experiments.families.helicopter.scenario import scenario

BASE = dict(iterations=4, seeds=2, test_trajectories=5)


@pytest.fixture(scope="module")
def traces():
    return {p: run("dagger-e", scenario("hover", test_policy=p, **BASE)) for p in
            ("last", "best", "mixture")}  # fmt: skip


@pytest.mark.slow
def test_best_is_one_of_the_policies_so_far(traces):
    last, best = traces["last"].rows.test_cost, traces["best"].rows.test_cost
    assert np.all(np.isfinite(best))
    for s in range(last.shape[0]):
        for n in range(last.shape[1]):
            assert np.any(np.isclose(best[s, n], last[s, : n + 1], rtol=1e-12)), (s, n)


@pytest.mark.slow
def test_mixture_starts_at_the_first_policy(traces):
    last, mix = traces["last"].rows.test_cost, traces["mixture"].rows.test_cost
    np.testing.assert_allclose(mix[:, 0], last[:, 0], rtol=1e-12)
    assert np.all(np.isfinite(mix)) and np.all(mix <= 1e8)
