"""The shared interface: no retracing, fixed state types, and ValueError on bad input."""

import jax
import numpy as np
import pytest

from loopid.learners import Learner, ftrl_least_squares, indexed, ogd, online_loss

LEARNERS = {
    "ftrl": lambda: ftrl_least_squares(1e-3),
    "ogd": lambda: ogd(0.05, radius=10.0),
    "indexed-ftrl": lambda: indexed(ftrl_least_squares(1e-3), 5),
    "indexed-ogd": lambda: indexed(ogd(0.05), 5),
}


def _call(learner, state, X, Y, mask, idx):
    if learner.name.startswith("indexed"):
        return learner.update(state, X, Y, mask, index=idx)
    return learner.update(state, X, Y, mask)


def _avals(tree):
    return [(a.shape, a.dtype, a.aval.weak_type) for a in jax.tree_util.tree_leaves(tree)]


@pytest.mark.parametrize("name", LEARNERS)
def test_update_does_not_retrace_over_50_iterations(rng, name):
    learner = LEARNERS[name]()
    assert isinstance(learner, Learner)
    traces = 0

    def step(state, X, Y, mask, idx):
        nonlocal traces
        traces += 1
        return _call(learner, state, X, Y, mask, idx)

    step = jax.jit(step)
    state = learner.init(25, 21)
    first = _avals(state)
    for _ in range(50):
        X, Y = rng.normal(size=(100, 25)), rng.normal(size=(100, 21))
        mask, idx = rng.random(100) < 0.9, rng.integers(0, 5, size=100)
        state = step(state, X, Y, mask, idx)
    assert traces == 1
    assert _avals(state) == first  # same shapes, dtypes and weak types as init's state
    W = learner.weights(state)
    assert W.shape[-2:] == (25, 21) and np.all(np.isfinite(np.asarray(W)))


@pytest.mark.parametrize("name", LEARNERS)
def test_shape_and_value_errors_name_the_argument(rng, name):
    learner = LEARNERS[name]()
    s = learner.init(4, 2)
    X, Y, idx = rng.normal(size=(6, 4)), rng.normal(size=(6, 2)), np.zeros(6, dtype=int)
    with pytest.raises(ValueError, match=r"X must have shape \[b, 4\].*\(6, 3\)"):
        _call(learner, s, X[:, :3], Y, None, idx)
    with pytest.raises(ValueError, match=r"X must have shape"):
        _call(learner, s, X[0], Y, None, idx)
    with pytest.raises(ValueError, match=r"Y must have shape \[6, 2\].*\(5, 2\)"):
        _call(learner, s, X, Y[:5], None, idx)
    with pytest.raises(ValueError, match=r"mask must have shape \[6\]"):
        _call(learner, s, X, Y, np.ones(5, bool), idx)
    Xbad = X.copy()
    Xbad[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"X has non-finite values.*row 2"):
        _call(learner, s, Xbad, Y, None, idx)
    Ybad = Y.copy()
    Ybad[4, 0] = np.inf
    with pytest.raises(ValueError, match=r"Y has non-finite values.*row 4"):
        _call(learner, s, X, Ybad, None, idx)
    keep = np.ones(6, bool)
    keep[2] = False
    _call(learner, s, Xbad, Y, keep, idx)  # a masked non-finite row is fine
    with pytest.raises(ValueError, match=r"n_features must be a positive integer, got 0"):
        learner.init(0, 2)


def test_hyperparameter_errors():
    with pytest.raises(ValueError, match=r"lam .*-0\.1"):
        ftrl_least_squares(-0.1)
    with pytest.raises(ValueError, match=r"lam .*nan"):
        ftrl_least_squares(float("nan"))
    with pytest.raises(ValueError, match=r"step_size .*0"):
        ogd(0.0)
    with pytest.raises(ValueError, match=r"radius .*-1"):
        ogd(0.1, radius=-1.0)
    with pytest.raises(ValueError, match=r"T must be a positive integer, got 0"):
        indexed(ftrl_least_squares(), 0)
    with pytest.raises(TypeError, match=r"learner"):
        indexed(object(), 3)


def test_index_errors(rng):
    learner = indexed(ftrl_least_squares(), 3)
    s = learner.init(2, 1)
    X, Y = rng.normal(size=(4, 2)), rng.normal(size=(4, 1))
    with pytest.raises(ValueError, match=r"index is required"):
        learner.update(s, X, Y)
    with pytest.raises(ValueError, match=r"index values must lie in \[0, 3\).*max 3"):
        learner.update(s, X, Y, index=np.array([0, 1, 2, 3]))
    with pytest.raises(ValueError, match=r"index must be an integer array of shape \[4\]"):
        learner.update(s, X, Y, index=np.zeros(4))
    with pytest.raises(ValueError, match=r"W must be"):
        online_loss(np.zeros((3, 2, 1)), X, Y)  # time-varying W needs an index
