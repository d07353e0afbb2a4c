"""The tests' pytree comparison (``conftest.tree_allclose``) can fail: on structure, on shape,
on one ulp when asked for bit-for-bit equality; NaN equals NaN (a masked row is the same)."""

from typing import NamedTuple

import numpy as np

from conftest import tree_allclose


class Pair(NamedTuple):
    a: np.ndarray
    b: np.ndarray


def test_tree_allclose_fails_when_it_should():
    x = Pair(np.array([1.0, np.nan]), np.zeros((2, 3)))
    assert tree_allclose(x, Pair(x.a.copy(), x.b.copy()), rtol=0.0, atol=0.0)
    one_ulp = Pair(np.array([np.nextafter(1.0, 2.0), np.nan]), x.b)
    assert not tree_allclose(x, one_ulp, rtol=0.0, atol=0.0)
    assert tree_allclose(x, one_ulp)  # within the default tolerance
    assert not tree_allclose(x, (x.a, x.b))  # another structure
    assert not tree_allclose(x, Pair(x.a, np.zeros((3, 2))))  # another shape
