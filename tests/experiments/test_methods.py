"""The helicopter's methods follow the generic p_n schedules number for number; the expert and
the policy gradient have none; each method's ν."""

import numpy as np
import pytest

from loopid.algorithms.schedules import SCHEDULES, policy_fractions
from loopid.experiments.families.helicopter import methods as M


@pytest.mark.parametrize("method", M.LEARNING_METHODS)
def test_every_learning_method_follows_its_schedule(method):
    schedule = method.split("-")[0]
    assert schedule in SCHEDULES
    for f in (0.0, 0.3, 1.0):
        a = M.policy_fractions(method, 6, dagger_fraction=f)
        b = policy_fractions(schedule, 6, dagger_fraction=f)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_a_method_that_learns_no_model_has_no_schedule():
    with pytest.raises(ValueError, match="'expert' does not learn a model"):
        M.policy_fractions("expert", 3)


def test_policy_fraction_schedules():
    """Moved from the loop's linear-system tests (``tests/algorithms/test_loop_linear.py``)."""
    np.testing.assert_array_equal(M.policy_fractions("dagger-e", 4), [0, 0.5, 0.5, 0.5])
    np.testing.assert_array_equal(M.policy_fractions("batch-en", 4), [0, 0, 0, 0])
    np.testing.assert_array_equal(M.policy_fractions("abbeel", 4), [0, 0, 1, 1])
    np.testing.assert_array_equal(
        M.policy_fractions("dagger-t", 3, dagger_fraction=0.25), [0, 0.25, 0.25]
    )
    assert M.nu_kind("abbeel") == "e" and M.nu_kind("batch-en") == "en"
    assert M.nu_kind("expert") is None and M.nu_kind("pg") is None
