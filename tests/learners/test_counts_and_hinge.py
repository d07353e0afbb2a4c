"""Count estimator and online hinge classifier: closed forms, rates, invariants."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.learners.counts import count_estimator
from loopid.learners.hinge import hinge_loss, online_hinge


def _onehot(i, n):
    return np.eye(n)[np.asarray(i)]


def test_counts_equal_numpy_frequencies_with_prior(rng):
    f, t, alpha = 5, 4, 0.5
    prior = rng.dirichlet(np.ones(t), size=f)
    est = count_estimator(alpha, prior)
    state = est.init(f, t)
    N = np.zeros((f, t))
    for _ in range(3):
        x, y = rng.integers(0, f, 30), rng.integers(0, t, 30)
        mask = rng.random(30) < 0.8
        X, Y = _onehot(x, f), _onehot(y, t)
        X[~mask] = np.nan  # masked rows may hold anything
        state = est.update(state, X, Y, mask)
        np.add.at(N, (x[mask], y[mask]), 1.0)
    expected = (N + alpha * prior) / (N.sum(1, keepdims=True) + alpha)
    np.testing.assert_allclose(est.weights(state), expected, atol=1e-14)
    np.testing.assert_allclose(np.asarray(est.weights(state)).sum(1), 1.0, atol=1e-14)


def test_counts_l1_error_falls_like_one_over_sqrt_n():
    """L1 error of the estimate of one 8-outcome distribution, 200 repetitions per n."""
    t = 8
    p = jnp.asarray(np.random.default_rng(1).dirichlet(np.ones(t)))
    est = count_estimator(1e-6)
    ns = np.array([16, 64, 256, 1024, 4096])

    def err(key, n):
        y = jax.random.categorical(key, jnp.log(p), shape=(n,))
        state = est.update(est.init(1, t), jnp.ones((n, 1)), jax.nn.one_hot(y, t))
        return jnp.sum(jnp.abs(est.weights(state)[0] - p))

    errors = []
    for n in ns:
        keys = jax.random.split(jax.random.key(int(n)), 200)
        errors.append(float(jnp.mean(jax.vmap(lambda k, n=int(n): err(k, n))(keys))))
    slope = np.polyfit(np.log(ns), np.log(errors), 1)[0]
    assert -0.7 <= slope <= -0.3, (slope, errors)


def test_counts_is_vmappable_and_rejects_bad_arguments():
    est = count_estimator(1.0)
    states = jax.vmap(lambda _: est.init(3, 2))(jnp.arange(4))
    X = jnp.asarray(_onehot([[0, 1]] * 4, 3))
    Y = jnp.asarray(_onehot([[1, 1]] * 4, 2))
    W = jax.vmap(est.weights)(jax.vmap(est.update)(states, X, Y))
    assert W.shape == (4, 3, 2)
    np.testing.assert_allclose(W[:, 0], [[1 / 4, 3 / 4]] * 4)
    with pytest.raises(ValueError, match="alpha"):
        count_estimator(0.0)
    with pytest.raises(ValueError, match="prior"):
        count_estimator(1.0, np.ones((3, 2))).init(3, 2)
    with pytest.raises(ValueError, match="prior has shape"):
        count_estimator(1.0, np.full((3, 2), 0.5)).init(4, 2)


def test_hinge_bounds_zero_one_loss(rng):
    W = rng.normal(size=(6, 5))
    X = _onehot(rng.integers(0, 6, 100), 6)
    labels = rng.integers(0, 5, 100)
    loss = np.asarray(hinge_loss(jnp.asarray(W), jnp.asarray(X), jnp.asarray(labels)))
    wrong = np.argmax(X @ W, axis=1) != labels
    assert (loss >= wrong).all() and (loss >= 0).all()
    # closed form of one row
    s = X[0] @ W
    other = np.max(np.delete(s, labels[0]))
    assert loss[0] == pytest.approx(max(0.0, 1 + other - s[labels[0]]))


def test_hinge_learns_separable_tabular_data_and_majority_of_noisy_labels(rng):
    f, t = 6, 4
    target = rng.integers(0, t, f)
    clf = online_hinge(1.0)
    state = clf.init(f, t)
    for _ in range(5):
        x = rng.integers(0, f, 40)
        state = clf.update(state, _onehot(x, f), _onehot(target[x], t))
    assert (np.argmax(np.asarray(clf.weights(state)), 1) == target).all()
    # one feature, labels 0/1/2 with probabilities .6/.3/.1: the best deterministic model is 0
    state = clf.init(1, 3)
    mistakes = 0
    for _ in range(300):
        y = rng.choice(3, size=10, p=[0.6, 0.3, 0.1])
        pred = int(np.argmax(np.asarray(clf.weights(state))[0]))
        mistakes += int((y != pred).sum())
        state = clf.update(state, np.ones((10, 1)), _onehot(y, 3))
    assert int(np.argmax(np.asarray(clf.weights(state))[0])) == 0
    assert mistakes / 3000 < 0.4 + 0.05  # online 0-1 loss near the best fixed predictor's 0.4


def test_hinge_masked_rows_change_nothing_and_bias_is_the_prior():
    bias = np.array([[0.5, 0.0], [0.0, 0.5]])
    clf = online_hinge(1.0, bias)
    state = clf.init(2, 2)
    np.testing.assert_allclose(clf.weights(state), bias)
    X = np.array([[1.0, 0.0], [np.nan, np.nan]])
    Y = np.array([[0.0, 1.0], [1.0, 0.0]])
    masked = clf.update(state, X, Y, np.array([False, False]))
    np.testing.assert_allclose(clf.weights(masked), bias)
    one = clf.update(state, X, Y, np.array([True, False]))
    W = np.asarray(clf.weights(one))
    assert np.argmax(W[0]) == 1 and (W[1] == bias[1]).all()  # a full AdaGrad step η on row 0
    with pytest.raises(ValueError, match="eta"):
        online_hinge(-1.0)
