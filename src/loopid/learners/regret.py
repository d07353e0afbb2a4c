r"""Regret bookkeeping for online least squares.

Online protocol: before the update at round i, the learner's current W_i is scored on the new
batch, ℓ_i = L_i(W_i) with L_i(W) = (1/b_i) Σ_j ||y_j − Wᵀx_j||² (mean over kept rows; 0 for an
empty batch). After N rounds the average regret against the best fixed model in hindsight is::

    R_N / N = (1/N) Σ_i ℓ_i  −  min_W (1/N) Σ_i L_i(W).

The paper's guarantee (Theorem 4.1) needs R_N / N → 0; no-regret learners give O(1/√N).

- :func:`online_loss` scores weights on a batch (call it *before* ``update``).
- :func:`hindsight_loss` is the second term for a whole stream [N, b, ...] (time-varying models:
  one fixed W per step, pass ``index`` and ``n_steps``).
- :func:`regret_curve` gives both terms for every prefix N' = 1..N at once (cumulative weighted
  sufficient statistics), for tests and diagnostics.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from loopid.learners.base import check_batch, check_index, zero_dropped

__all__ = ["RegretCurve", "hindsight_loss", "online_loss", "regret_curve"]


class RegretCurve(NamedTuple):
    """Per-prefix regret figures, each [N]: entry k covers rounds 0..k."""

    average_online_loss: jax.Array
    best_fixed_loss: jax.Array
    average_regret: jax.Array


def online_loss(W, X, Y, mask=None, index=None) -> jax.Array:
    """Mean over kept rows of ||y − Wᵀx||² (0 when no row is kept).

    Args:
      W: [f, t] weights, or [T, f, t] with ``index`` [b] picking each row's step.
      X, Y, mask: a batch, [b, f], [b, t], [b] (see :mod:`loopid.learners.base`).
    """
    W = jnp.asarray(W)
    if W.ndim not in (2, 3) or (W.ndim == 3) != (index is not None):
        raise ValueError(f"W must be [f, t] (or [T, f, t] with index), got shape {W.shape}")
    X, Y, keep = check_batch(X, Y, mask, W.shape[-2], W.shape[-1])
    if index is not None:
        index = check_index(index, X.shape[0], W.shape[0])
    return _online_loss(W.astype(jnp.float64), X, Y, keep, index)


@jax.jit
def _online_loss(W, X, Y, keep, index):
    X, Y = zero_dropped(X, Y, keep)
    pred = X @ W if index is None else jnp.einsum("bf,bft->bt", X, W[index])
    err = jnp.sum((Y - pred) ** 2, axis=-1)
    k = keep.astype(jnp.float64)
    return jnp.sum(err * k) / jnp.maximum(k.sum(), 1.0)


def _stream(X, Y, mask):
    """Check a stream [N, b, f], [N, b, t], [N, b]; return float64 X, Y and row weights 1/b_i."""
    X = jnp.asarray(X)
    Y = jnp.asarray(Y)
    if X.ndim != 3 or Y.ndim != 3 or X.shape[:2] != Y.shape[:2]:
        raise ValueError(f"X, Y must be streams [N, b, f], [N, b, t], got {X.shape}, {Y.shape}")
    N, b, f = X.shape
    if mask is not None and jnp.shape(mask) != (N, b):
        raise ValueError(f"mask must have shape [{N}, {b}], got {jnp.shape(mask)}")
    flat = check_batch(
        X.reshape(N * b, f),
        Y.reshape(N * b, -1),
        None if mask is None else jnp.reshape(mask, (N * b,)),
        f,
        Y.shape[-1],
    )
    Xf, Yf = zero_dropped(*flat)
    k = flat[2].astype(jnp.float64).reshape(N, b)
    w = k / jnp.maximum(k.sum(axis=1, keepdims=True), 1.0)  # each batch's rows weigh 1/b_i
    return Xf.reshape(N, b, f), Yf.reshape(N, b, -1), w


def _min_loss(ZZ, ZY, yy):
    """min_W yy − 2 tr(WᵀZY) + tr(WᵀZZ W) = yy − tr(ZYᵀ ZZ⁺ ZY) (batched over leading axes)."""
    W = jnp.linalg.pinv(ZZ, hermitian=True) @ ZY
    return yy - jnp.sum(W * ZY, axis=(-2, -1))


def hindsight_loss(X, Y, mask=None, index=None, n_steps: int | None = None) -> jax.Array:
    """Average loss (1/N) Σ_i L_i(W*) of the best fixed model W* in hindsight (no regulariser).

    Args:
      X, Y, mask: the stream of batches, [N, b, f], [N, b, t], [N, b].
      index, n_steps: for a time-varying model, the step of each row [N, b] and the number of
        steps T; the best fixed model then has one W per step.
    """
    Xs, Ys, w = _stream(X, Y, mask)
    N, b, _ = Xs.shape
    if index is None:
        return _hindsight(Xs, Ys, w)
    if n_steps is None:
        raise ValueError("n_steps is required with index")
    idx = check_index(jnp.reshape(jnp.asarray(index), (N * b,)), N * b, n_steps)
    return _hindsight_indexed(Xs, Ys, w, idx, n_steps)


@jax.jit
def _hindsight(Xs, Ys, w):
    ZZ = jnp.einsum("nb,nbf,nbg->fg", w, Xs, Xs)
    ZY = jnp.einsum("nb,nbf,nbt->ft", w, Xs, Ys)
    return _min_loss(ZZ, ZY, jnp.sum(w[..., None] * Ys**2)) / Xs.shape[0]


@partial(jax.jit, static_argnums=4)
def _hindsight_indexed(Xs, Ys, w, idx, n_steps):
    N, b, f = Xs.shape
    xw = (w[..., None] * Xs).reshape(N * b, f)
    Xf, Yf = Xs.reshape(N * b, f), Ys.reshape(N * b, -1)
    ZZ = jnp.zeros((n_steps, f, f)).at[idx].add(xw[:, :, None] * Xf[:, None, :])
    ZY = jnp.zeros((n_steps, f, Yf.shape[-1])).at[idx].add(xw[:, :, None] * Yf[:, None, :])
    yy = jnp.zeros((n_steps,)).at[idx].add(w.reshape(-1) * jnp.sum(Yf**2, axis=-1))
    return jnp.sum(_min_loss(ZZ, ZY, yy)) / N


def regret_curve(online_losses, X, Y, mask=None) -> RegretCurve:
    """Average online loss, best fixed loss in hindsight and average regret for every prefix.

    Args:
      online_losses: [N], ℓ_i = :func:`online_loss` of the learner's weights on batch i,
        computed before the learner saw batch i.
      X, Y, mask: the stream, [N, b, f], [N, b, t], [N, b].
    """
    losses = jnp.asarray(online_losses, dtype=jnp.float64)
    Xs, Ys, w = _stream(X, Y, mask)
    N = Xs.shape[0]
    if losses.shape != (N,):
        raise ValueError(f"online_losses must have shape [{N}], got {losses.shape}")
    return _curve(losses, Xs, Ys, w)


@jax.jit
def _curve(losses, Xs, Ys, w):
    N = Xs.shape[0]
    ZZ = jnp.cumsum(jnp.einsum("nb,nbf,nbg->nfg", w, Xs, Xs), axis=0)
    ZY = jnp.cumsum(jnp.einsum("nb,nbf,nbt->nft", w, Xs, Ys), axis=0)
    yy = jnp.cumsum(jnp.einsum("nb,nbt->n", w, Ys**2), axis=0)
    count = jnp.arange(1, N + 1, dtype=jnp.float64)
    avg = jnp.cumsum(losses) / count
    best = _min_loss(ZZ, ZY, yy) / count
    return RegretCurve(average_online_loss=avg, best_fixed_loss=best, average_regret=avg - best)
