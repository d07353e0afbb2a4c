r"""Online multi-class SVM: the Crammer-Singer hinge loss by diagonal AdaGrad, as a
:class:`Learner` (the paper's second model class: deterministic models learnt by online
classification of the next state, section 3-4).

Rows ``x [f]`` (one-hot ``e_{(s,a)}`` for a tabular class), targets one-hot ``y = e_{s'} [t]``
(the label is ``argmax y``). Scores ``w = Wᵀx [t]``; the model predicts ``argmax_k w_k`` (a
deterministic model ``T̂_sa = δ_ŝ``). Round i's loss is the mean over the batch's kept rows of

    ℓ(W; x, y) = max(0, 1 + max_{k≠y} w_k − w_y)      (≥ the 0-1 loss of the prediction),

convex in W; its subgradient is ``x (e_k̂ − e_y)ᵀ`` on rows with positive loss. Diagonal AdaGrad
(Duchi, Hazan & Singer 2011)::

    G ← G + g²,     W ← W − η g / √G     (element-wise; 0 where G = 0)

is no-regret (O(√N) regret) on these convex rounds, and is invariant to the batch-size scale,
so a pair seen once gets a full step η whatever the batch size. ``bias [f, t]`` is the initial
W (the prior prediction for unseen rows; e.g. "stay put" with a margin below 1).
For a stochastic system no deterministic model is exact: the agnostic case.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.learners.base import Learner, check_batch, check_dims, zero_dropped

__all__ = ["HingeState", "hinge_loss", "online_hinge"]


class HingeState(NamedTuple):
    """Scores ``W [f, t]``, AdaGrad accumulators ``G [f, t]`` and the rounds seen ``n``."""

    W: jax.Array
    G: jax.Array
    n: jax.Array


def hinge_loss(W: jax.Array, X: jax.Array, labels: jax.Array) -> jax.Array:
    """Per-row Crammer-Singer hinge loss ``[b]`` of scores ``X W`` against int ``labels [b]``."""
    scores = X @ W
    t = W.shape[-1]
    own = jnp.take_along_axis(scores, labels[:, None], axis=-1)[:, 0]
    other = jnp.max(jnp.where(jax.nn.one_hot(labels, t, dtype=bool), -jnp.inf, scores), axis=-1)
    return jnp.maximum(0.0, 1.0 + other - own)


def online_hinge(eta: float = 1.0, bias=None) -> Learner:
    """Online multi-class hinge (Crammer-Singer) by diagonal AdaGrad with step ``eta``.

    Args:
      eta: AdaGrad step size, > 0.
      bias: initial scores ``[f, t]`` (None: zeros).

    Returns:
      A :class:`Learner`; state :class:`HingeState`; ``weights`` gives the scores W ``[f, t]``.
    """
    try:
        eta = float(eta)
    except (TypeError, ValueError):
        raise ValueError(f"eta must be a real number > 0, got {eta!r}") from None
    if not (eta > 0 and math.isfinite(eta)):
        raise ValueError(f"eta must be a finite number > 0, got {eta!r}")
    if bias is not None:
        bias = np.asarray(bias, dtype=np.float64)
        if bias.ndim != 2 or not np.isfinite(bias).all():
            raise ValueError(f"bias must be a finite [f, t] array, got shape {bias.shape}")

    def init(n_features, n_targets) -> HingeState:
        f, t = check_dims(n_features, n_targets)
        if bias is not None and bias.shape != (f, t):
            raise ValueError(f"bias has shape {bias.shape}, the learner is [{f}, {t}]")
        W = jnp.zeros((f, t), jnp.float64) if bias is None else jnp.asarray(bias)
        return HingeState(W, jnp.zeros((f, t), jnp.float64), jnp.zeros((), jnp.float64))

    @jax.jit
    def _update(state, X, Y, keep):
        X, Y = zero_dropped(X, Y, keep)
        t = Y.shape[-1]
        labels = jnp.argmax(Y, axis=-1)
        scores = X @ state.W
        rival = jnp.argmax(jnp.where(jax.nn.one_hot(labels, t, dtype=bool), -jnp.inf, scores), -1)
        active = keep & (hinge_loss(state.W, X, labels) > 0)
        direction = jax.nn.one_hot(rival, t, dtype=jnp.float64) - jax.nn.one_hot(
            labels, t, dtype=jnp.float64
        )
        direction = jnp.where(active[:, None], direction, 0.0)
        count = jnp.maximum(jnp.sum(keep), 1).astype(jnp.float64)
        g = X.T @ direction / count
        G = state.G + g**2
        step = jnp.where(G > 0, g / jnp.sqrt(jnp.where(G > 0, G, 1.0)), 0.0)
        n = state.n + jnp.any(keep).astype(jnp.float64)
        return HingeState(state.W - eta * step, G, n)

    def update(state: HingeState, X, Y, mask=None) -> HingeState:
        X, Y, keep = check_batch(X, Y, mask, state.W.shape[0], state.W.shape[1])
        return _update(state, X, Y, keep)

    @jax.jit
    def weights(state: HingeState) -> jax.Array:
        return state.W

    return Learner(init=init, update=update, weights=weights, name=f"hinge(eta={eta:g})")
