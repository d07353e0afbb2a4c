"""Regret bookkeeping against direct NumPy computations."""

import numpy as np

from loopid.learners import hindsight_loss, online_loss, regret_curve


def _batch_loss(W, X, Y, keep):
    err = ((Y - X @ W) ** 2).sum(axis=1)
    return err[keep].mean() if keep.any() else 0.0


def _best_fixed(Xs, Ys, keeps):
    """min_W (1/N) Σ_i mean_{kept j in i} ||y − Wᵀx||², by weighted lstsq (rows weigh 1/b_i)."""
    rows_X, rows_Y = [], []
    for X, Y, k in zip(Xs, Ys, keeps, strict=True):
        if k.any():
            w = np.sqrt(1.0 / k.sum())
            rows_X.append(w * X[k])
            rows_Y.append(w * Y[k])
    X, Y = np.concatenate(rows_X), np.concatenate(rows_Y)
    W = np.linalg.lstsq(X, Y, rcond=None)[0]
    return ((Y - X @ W) ** 2).sum() / len(Xs)


def test_online_loss_is_the_masked_mean_squared_error(rng):
    W, X, Y = rng.normal(size=(4, 2)), rng.normal(size=(9, 4)), rng.normal(size=(9, 2))
    keep = rng.random(9) < 0.5
    keep[0] = True
    Xp = np.where(keep[:, None], X, np.nan)
    np.testing.assert_allclose(float(online_loss(W, Xp, Y, keep)), _batch_loss(W, X, Y, keep))
    assert float(online_loss(W, X, Y, np.zeros(9, bool))) == 0.0


def test_online_loss_time_varying(rng):
    W, X, Y = rng.normal(size=(3, 4, 2)), rng.normal(size=(9, 4)), rng.normal(size=(9, 2))
    idx = rng.integers(0, 3, size=9)
    expected = np.mean([((Y[j] - X[j] @ W[idx[j]]) ** 2).sum() for j in range(9)])
    np.testing.assert_allclose(float(online_loss(W, X, Y, index=idx)), expected)


def test_hindsight_and_regret_curve_match_numpy(rng):
    N, b, f, t = 12, 7, 3, 2
    X, Y = rng.normal(size=(N, b, f)), rng.normal(size=(N, b, t))
    keep = rng.random((N, b)) < 0.7
    keep[:, 0] = True
    losses = rng.random(N)
    np.testing.assert_allclose(float(hindsight_loss(X, Y, keep)), _best_fixed(X, Y, keep))
    curve = regret_curve(losses, X, Y, keep)
    for k in (0, 3, N - 1):  # prefix 0..k; the first prefixes are rank-deficient
        best = _best_fixed(X[: k + 1], Y[: k + 1], keep[: k + 1])
        np.testing.assert_allclose(float(curve.best_fixed_loss[k]), best, atol=1e-12)
        avg = losses[: k + 1].mean()
        np.testing.assert_allclose(float(curve.average_online_loss[k]), avg)
        np.testing.assert_allclose(float(curve.average_regret[k]), avg - best, atol=1e-12)


def test_hindsight_time_varying_is_per_step(rng):
    N, b, f, t, T = 6, 20, 3, 2, 4
    X, Y = rng.normal(size=(N, b, f)), rng.normal(size=(N, b, t))
    idx = rng.integers(0, T, size=(N, b))
    got = float(hindsight_loss(X, Y, index=idx, n_steps=T))
    total = 0.0
    for s in range(T):  # one fixed W per step; every batch is full, so rows weigh 1/b
        rows = idx.reshape(-1) == s
        Xs, Ys = X.reshape(-1, f)[rows], Y.reshape(-1, t)[rows]
        W = np.linalg.lstsq(Xs, Ys, rcond=None)[0]
        total += ((Ys - Xs @ W) ** 2).sum() / b
    np.testing.assert_allclose(got, total / N)
