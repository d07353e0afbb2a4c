"""The packaged funnel scenario's runner flies the default reading of the funnel's nominal,
"heading" (its Setup's initial model). The readings themselves, and "spec" as the plant's
nominal bit for bit, are ``tests/systems/test_funnel_nominal.py``."""

import numpy as np

from loopid.systems.helicopter.funnel_nominal import funnel_nominal


def test_the_funnel_scenario_flies_the_heading_nominal(funnel_setup):
    plant = funnel_setup.plant
    # the packaged scenario's runner flies the default reading, heading
    default = funnel_nominal("heading", plant.task)
    np.testing.assert_array_equal(funnel_setup.nominal.A, default.A)
    np.testing.assert_array_equal(funnel_setup.nominal.B, default.B)
