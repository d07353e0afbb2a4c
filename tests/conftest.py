"""Strict numerics for every test: float64, strict dtype promotion, warnings as errors."""

import jax
import numpy as np
import pytest

import loopid  # noqa: F401  (turns on float64, registers the Gymnasium ids)

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


def tree_allclose(a, b, *, rtol=1e-10, atol=1e-12) -> bool:
    """True when two pytrees have the same structure and all leaves are close."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    if ta != tb:
        return False
    pairs = zip(la, lb, strict=True)
    return all(np.allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol) for x, y in pairs)


@pytest.fixture
def rng():
    """A NumPy generator with a fixed seed, for test data."""
    return np.random.default_rng(0)
