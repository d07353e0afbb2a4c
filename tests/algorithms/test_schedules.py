"""The generic policy-fraction schedules: the helicopter's methods follow them number for
number, and a bad schedule or fraction is one line of ValueError."""

import numpy as np
import pytest

from loopid.algorithms.schedules import SCHEDULES, policy_fractions
from loopid.experiments.families.helicopter import methods as M


def test_schedules():
    np.testing.assert_array_equal(policy_fractions("dagger", 4), [0, 0.5, 0.5, 0.5])
    np.testing.assert_array_equal(policy_fractions("batch", 4), [0, 0, 0, 0])
    np.testing.assert_array_equal(policy_fractions("abbeel", 4), [0, 0, 1, 1])
    np.testing.assert_array_equal(
        policy_fractions("dagger", 3, dagger_fraction=0.25), [0, 0.25, 0.25]
    )


@pytest.mark.parametrize("method", M.LEARNING_METHODS)
def test_every_learning_method_follows_its_schedule(method):
    schedule = method.split("-")[0]
    assert schedule in SCHEDULES
    for f in (0.0, 0.3, 1.0):
        a = M.policy_fractions(method, 6, dagger_fraction=f)
        b = policy_fractions(schedule, 6, dagger_fraction=f)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_bad_schedule_or_fraction():
    with pytest.raises(ValueError, match="unknown schedule 'dagger-t'; choose from dagger"):
        policy_fractions("dagger-t", 3)
    with pytest.raises(ValueError, match=r"dagger_fraction must lie in \[0, 1\], got 1.5"):
        policy_fractions("dagger", 3, dagger_fraction=1.5)
    with pytest.raises(ValueError, match="'expert' does not learn a model"):
        M.policy_fractions("expert", 3)
