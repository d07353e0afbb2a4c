r"""Online (projected) gradient descent on the per-batch least-squares loss.

Batch t (t = 1, 2, ... counts the non-empty batches) brings the loss
L_t(W) = (1/b_t) Σ_j ||y_j − Wᵀx_j||² over its kept rows, with gradient
∇L_t(W) = (2/b_t) Xᵀ(XW − Y). The update is (Zinkevich 2003)::

    W ← Π( W − (η/√t) ∇L_t(W) ),     Π = projection onto {||W||_F ≤ radius} (or the identity),

starting from W = 0. With bounded gradients and a bounded feasible set its average regret
against the best fixed W in hindsight is O(1/√N). Only W and t are kept: OGD forgets the data,
which is the point of offering it next to FTRL (the paper: "any no-regret learner").

A batch whose rows are all masked is not a round: W and t stay as they are (so the indexed,
time-varying form leaves a step without samples untouched).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from loopid.learners.base import Learner, check_batch, check_dims, zero_dropped

__all__ = ["OGDState", "ogd"]


class OGDState(NamedTuple):
    """OGD state: the current weights W [f, t] and the number t of non-empty batches seen."""

    W: jax.Array
    t: jax.Array


def ogd(step_size: float = 0.1, radius: float | None = None) -> Learner:
    """Online gradient descent, step ``step_size / √t``, optional Frobenius-ball projection.

    Args:
      step_size: η > 0. For stability at t = 1, η·2·λ_max(E[x xᵀ]) should stay below about 2
        (features of order 1: η ≲ 1/f is safe).
      radius: the ball {||W||_F ≤ radius} to project onto, or ``None`` for no projection.

    Returns:
      A :class:`Learner` whose state is :class:`OGDState`; ``weights`` gives W [f, t].
    """
    for name, v, ok_none in (("step_size", step_size, False), ("radius", radius, True)):
        if v is None and ok_none:
            continue
        try:
            fv = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a positive number, got {v!r}") from None
        if not (fv > 0 and math.isfinite(fv)):
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    eta = float(step_size)
    rad = None if radius is None else float(radius)

    def init(n_features, n_targets) -> OGDState:
        f, t = check_dims(n_features, n_targets)
        return OGDState(W=jnp.zeros((f, t), jnp.float64), t=jnp.zeros((), jnp.int64))

    @jax.jit
    def _update(state, X, Y, keep):
        X, Y = zero_dropped(X, Y, keep)
        b = keep.astype(jnp.float64).sum()
        grad = (2.0 / jnp.maximum(b, 1.0)) * (X.T @ (X @ state.W - Y))
        t_new = state.t + 1
        W = state.W - (eta / jnp.sqrt(t_new.astype(jnp.float64))) * grad
        if rad is not None:
            W = W * jnp.minimum(1.0, rad / jnp.maximum(jnp.linalg.norm(W), 1e-300))
        active = b > 0
        return OGDState(W=jnp.where(active, W, state.W), t=jnp.where(active, t_new, state.t))

    def update(state: OGDState, X, Y, mask=None) -> OGDState:
        X, Y, keep = check_batch(X, Y, mask, state.W.shape[-2], state.W.shape[-1])
        return _update(state, X, Y, keep)

    def weights(state: OGDState) -> jax.Array:
        return state.W

    label = f"ogd(step_size={eta:g}" + ("" if rad is None else f", radius={rad:g}") + ")"
    return Learner(init=init, update=update, weights=weights, name=label)
