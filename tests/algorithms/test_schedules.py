"""The generic policy-fraction schedules p_n (DAgger ½, Batch 0, Abbeel 0 then 1), and a bad
schedule or fraction is one line of ValueError."""

import numpy as np
import pytest

from loopid.algorithms.schedules import policy_fractions


def test_schedules():
    np.testing.assert_array_equal(policy_fractions("dagger", 4), [0, 0.5, 0.5, 0.5])
    np.testing.assert_array_equal(policy_fractions("batch", 4), [0, 0, 0, 0])
    np.testing.assert_array_equal(policy_fractions("abbeel", 4), [0, 0, 1, 1])
    np.testing.assert_array_equal(
        policy_fractions("dagger", 3, dagger_fraction=0.25), [0, 0.25, 0.25]
    )


def test_bad_schedule_or_fraction():
    with pytest.raises(ValueError, match="unknown schedule 'dagger-t'; choose from dagger"):
        policy_fractions("dagger-t", 3)
    with pytest.raises(ValueError, match=r"dagger_fraction must lie in \[0, 1\], got 1.5"):
        policy_fractions("dagger", 3, dagger_fraction=1.5)
