"""The linear offset model: nominal constructors, residual targets, round trips with a learner."""

import jax
import numpy as np
import pytest

from loopid.learners import ftrl_least_squares, indexed
from loopid.models import (
    LinearOffsetModel,
    features,
    hover_nominal,
    per_sample_loss,
    predict,
    residual_targets,
    time_varying_nominal,
    to_matrices,
)


def _rows(rng, b, n, m):
    dx = rng.normal(size=(b, n))
    dx[:, -1] = 1.0  # the constant error coordinate
    return dx, rng.normal(size=(b, m))


def test_hover_nominal_matches_the_paper():
    model = hover_nominal(21, 4)  # the helicopter's sizes
    A, B = np.asarray(model.A), np.asarray(model.B)
    assert A.shape == (21, 21) and B.shape == (21, 4)
    np.testing.assert_array_equal(A, np.eye(21))
    expected = np.zeros((21, 4))
    expected[0:4] = np.eye(4)
    expected[4:8] = np.eye(4)
    np.testing.assert_array_equal(B, expected)
    # Δu goes into u_prev and du_prev: x' = x + BΔu moves exactly those entries.
    dx, du = np.zeros((1, 21)), np.array([[1.0, 2.0, 3.0, 4.0]])
    out = np.asarray(predict(model, np.zeros((25, 21)), dx, du))[0]
    np.testing.assert_array_equal(out[:8], [1, 2, 3, 4, 1, 2, 3, 4])
    assert np.all(out[8:] == 0)


def test_ftrl_on_residual_targets_recovers_the_true_offsets(rng):
    """Exact data from (A + A', B + B'): the λ = 0 fit gives back Â, B̂ and zero loss."""
    n, m, b = 7, 2, 60
    model = hover_nominal(n, m)
    A_true = np.asarray(model.A) + 0.1 * rng.normal(size=(n, n))
    B_true = np.asarray(model.B) + 0.1 * rng.normal(size=(n, m))
    A_true[-1] = 0.0
    A_true[-1, -1] = 1.0  # the constant stays 1
    dx, du = _rows(rng, b, n, m)
    dx_next = dx @ A_true.T + du @ B_true.T
    learner = ftrl_least_squares(0.0)
    state = learner.update(
        learner.init(n + m, n), features(dx, du), residual_targets(model, dx, du, dx_next)
    )
    W = learner.weights(state)
    A_hat, B_hat = to_matrices(model, W)
    np.testing.assert_allclose(np.asarray(A_hat), A_true, atol=1e-10)
    np.testing.assert_allclose(np.asarray(B_hat), B_true, atol=1e-10)
    np.testing.assert_allclose(np.asarray(predict(model, W, dx, du)), dx_next, atol=1e-10)
    assert float(per_sample_loss(model, W, dx, du, dx_next).max()) < 1e-18


def test_predict_and_loss_agree_with_to_matrices(rng):
    n, m, b = 5, 2, 9
    model = LinearOffsetModel(rng.normal(size=(n, n)), rng.normal(size=(n, m)))
    W = rng.normal(size=(n + m, n))
    dx, du = _rows(rng, b, n, m)
    dx_next = rng.normal(size=(b, n))
    A_hat, B_hat = (np.asarray(a) for a in to_matrices(model, W))
    pred = dx @ A_hat.T + du @ B_hat.T
    np.testing.assert_allclose(np.asarray(predict(model, W, dx, du)), pred, atol=1e-12)
    loss = np.asarray(per_sample_loss(model, W, dx, du, dx_next))
    np.testing.assert_allclose(loss, ((dx_next - pred) ** 2).sum(axis=1), atol=1e-12)
    # With W = 0 the loss is the squared residual target.
    y = np.asarray(residual_targets(model, dx, du, dx_next))
    loss0 = np.asarray(per_sample_loss(model, np.zeros_like(W), dx, du, dx_next))
    np.testing.assert_allclose(loss0, (y**2).sum(axis=1), atol=1e-12)


def test_time_varying_nominal_folds_the_increment_into_the_affine_column(rng):
    n, m, T, b = 6, 2, 5, 30
    A, B = rng.normal(size=(n, n)), rng.normal(size=(n, m))
    inc = rng.normal(size=(T, n))
    inc[:, -1] = 1.0  # x*_{t+1} ⊖ x*_t may carry the constant coordinate: it is ignored
    model = time_varying_nominal(A, B, inc)
    assert model.A.shape == (T, n, n) and model.B.shape == (T, n, m) and model.time_varying
    dx, du = _rows(rng, b, n, m)
    t = rng.integers(0, T, size=b)
    expected = dx @ A.T + du @ B.T - np.where(np.arange(n) == n - 1, 0.0, inc[t])
    got = np.asarray(predict(model, np.zeros((n + m, n)), dx, du, t))
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # With A's last row e_nᵀ the constant coordinate stays exactly 1.
    A1 = A.copy()
    A1[-1] = 0.0
    A1[-1, -1] = 1.0
    B1 = B.copy()
    B1[-1] = 0.0
    out = predict(time_varying_nominal(A1, B1, inc), np.zeros((n + m, n)), dx, du, t)
    np.testing.assert_array_equal(np.asarray(out)[:, -1], 1.0)


def test_time_varying_fit_equals_independent_per_step_fits(rng):
    n, m, T, b = 4, 2, 3, 90
    A, B = rng.normal(size=(n, n)), rng.normal(size=(n, m))
    model = time_varying_nominal(A, B, rng.normal(size=(T, n)))
    dx, du = _rows(rng, b, n, m)
    t = rng.integers(0, T, size=b)
    dx_next = rng.normal(size=(b, n))
    lam = 1e-3
    tv = indexed(ftrl_least_squares(lam), T)
    z, y = features(dx, du), residual_targets(model, dx, du, dx_next, t)
    W = tv.weights(tv.update(tv.init(n + m, n), z, y, index=t))
    A_hat, B_hat = to_matrices(model, W)
    assert A_hat.shape == (T, n, n) and B_hat.shape == (T, n, m)
    one = ftrl_least_squares(lam)
    for s in range(T):
        rows = t == s
        step_model = LinearOffsetModel(model.A[s], model.B[s])
        ys = residual_targets(step_model, dx[rows], du[rows], dx_next[rows])
        Ws = one.weights(one.update(one.init(n + m, n), z[rows], ys))
        As, Bs = to_matrices(step_model, Ws)
        np.testing.assert_allclose(np.asarray(A_hat[s]), np.asarray(As), atol=1e-10)
        np.testing.assert_allclose(np.asarray(B_hat[s]), np.asarray(Bs), atol=1e-10)
        np.testing.assert_allclose(
            np.asarray(predict(model, W, dx[rows], du[rows], t[rows])),
            np.asarray(predict(step_model, Ws, dx[rows], du[rows])),
            atol=1e-10,
        )


def test_to_matrices_broadcasts_over_seed_axes(rng):
    model = hover_nominal(9, 2)
    W = rng.normal(size=(4, 11, 9))  # four seeds
    A_hat, B_hat = jax.vmap(lambda w: to_matrices(model, w))(W)
    A2, B2 = to_matrices(model, W)
    np.testing.assert_allclose(np.asarray(A_hat), np.asarray(A2))
    np.testing.assert_allclose(np.asarray(B_hat), np.asarray(B2))


def test_bad_shapes_raise(rng):
    model = hover_nominal(9, 2)
    dx, du = _rows(rng, 3, 9, 2)
    with pytest.raises(ValueError, match=r"du must have shape \[3, 2\]"):
        residual_targets(model, dx, du[:, :1], dx)
    with pytest.raises(ValueError, match=r"dx_next must have shape \[3, 9\]"):
        residual_targets(model, dx, du, dx[:2])
    with pytest.raises(ValueError, match=r"W must have shape"):
        predict(model, np.zeros((9, 9)), dx, du)
    with pytest.raises(ValueError, match=r"t \[b\].*required"):
        predict(model, np.zeros((2, 11, 9)), dx, du)
    with pytest.raises(ValueError, match=r"increments must have shape \[T, 9\]"):
        time_varying_nominal(model.A, model.B, np.zeros((4, 8)))
    with pytest.raises(ValueError, match=r"n must be >= 2\*m"):
        hover_nominal(5, 3)
    with pytest.raises(ValueError, match=r"model needs A"):
        to_matrices(LinearOffsetModel(np.eye(3), np.zeros((4, 1))), np.zeros((4, 3)))
