"""The online-learner interface and the input checks every learner shares.

A learner (optax style) is a named triple of pure functions built by a factory that closes over
its hyperparameters::

    learner = ftrl_least_squares(lam=1e-3)
    state = learner.init(n_features, n_targets)     # a NamedTuple of fixed-shape arrays
    state = learner.update(state, X, Y, mask)       # X: [b, n_features], Y: [b, n_targets]
    W = learner.weights(state)                      # [n_features, n_targets]; predict Y ≈ X W

The online problem is least squares: batch i brings rows (x_j, y_j) and the loss
L_i(W) = (1/b_i) Σ_j ||y_j − Wᵀx_j||² (mean over the batch's kept rows). ``mask`` ([b], bool or
float, nonzero = kept; ``None`` = all rows) drops padded rows, e.g. the tail of an early-stopped
trajectory; masked rows may hold anything, NaN included, and change nothing.

``update`` and ``weights`` are pure and jit-compiled; they work on tracers, so the loop can call
them inside ``jax.lax.scan`` and ``jax.vmap``. The thin Python wrapper checks shapes (static) and,
only when the inputs are concrete arrays, values (finite kept rows), raising ``ValueError`` naming
the bad argument before any tracing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Learner"]


class Learner(NamedTuple):
    """An online least-squares learner: ``init``, ``update``, ``weights`` (and a ``name``).

    Attributes:
      init: ``init(n_features, n_targets) -> state``.
      update: ``update(state, X, Y, mask=None) -> state``; X [b, f], Y [b, t], mask [b].
        Learners made by :func:`loopid.learners.indexed` take ``index=`` [b] as well.
      weights: ``weights(state) -> W`` of shape [f, t] (indexed learners: [T, f, t]).
      name: a short label for results and reprs.
      update_indexed: optional fast path used by :func:`loopid.learners.indexed`:
        ``update_indexed(states, X, Y, keep, index) -> states`` on states stacked over T steps,
        where row j updates step ``index[j]`` only (``keep`` [b] bool, inputs already checked
        and masked rows zeroed). Learners whose state is additive in the rows (FTRL) provide a
        scatter-add version; ``None`` means ``indexed`` vmaps ``update`` over the T steps.
    """

    init: Callable[..., Any]
    update: Callable[..., Any]
    weights: Callable[[Any], jax.Array]
    name: str = "learner"
    update_indexed: Callable[..., Any] | None = None


def is_concrete(*xs) -> bool:
    """True when none of ``xs`` is a JAX tracer (so their values can be inspected)."""
    return not any(isinstance(x, jax.core.Tracer) for x in xs)


def check_dims(n_features, n_targets) -> tuple[int, int]:
    """Validate ``init``'s arguments: positive Python integers."""
    out = []
    for name, v in (("n_features", n_features), ("n_targets", n_targets)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
        out.append(int(v))
    return out[0], out[1]


def check_batch(X, Y, mask, n_features: int, n_targets: int):
    """Check one batch against a state's sizes; return float64 ``X``, ``Y`` and a bool ``keep``.

    Shapes are checked always (they are static under tracing); finiteness of the kept rows only
    when the arrays are concrete. Raises ``ValueError`` naming the argument and its shape/value.
    """
    X = jnp.asarray(X)
    Y = jnp.asarray(Y)
    if X.ndim != 2 or X.shape[1] != n_features:
        raise ValueError(f"X must have shape [b, {n_features}] (n_features), got {X.shape}")
    b = X.shape[0]
    if Y.ndim != 2 or Y.shape != (b, n_targets):
        raise ValueError(f"Y must have shape [{b}, {n_targets}] (b, n_targets), got {Y.shape}")
    for name, v in (("X", X), ("Y", Y)):
        if not (jnp.issubdtype(v.dtype, jnp.floating) or jnp.issubdtype(v.dtype, jnp.integer)):
            raise ValueError(f"{name} must be a real array, got dtype {v.dtype}")
    if mask is None:
        keep = jnp.ones((b,), dtype=bool)
    else:
        mask = jnp.asarray(mask)
        if mask.shape != (b,):
            raise ValueError(f"mask must have shape [{b}] (rows of X), got {mask.shape}")
        keep = mask if mask.dtype == jnp.bool_ else mask != 0
    X = X.astype(jnp.float64)
    Y = Y.astype(jnp.float64)
    if is_concrete(X, Y, keep):
        k = np.asarray(keep)
        for name, v in (("X", X), ("Y", Y)):
            bad = k & ~np.isfinite(np.asarray(v)).all(axis=1)
            if bad.any():
                j = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"{name} has non-finite values in {int(bad.sum())} kept row(s), "
                    f"first row {j}: {np.asarray(v)[j]}"
                )
    return X, Y, keep


def check_index(index, b: int, T: int):
    """Check a per-row time-step index: integer [b], values in [0, T) when concrete."""
    if index is None:
        raise ValueError("index is required for an indexed (time-varying) learner: [b] integers")
    index = jnp.asarray(index)
    if index.shape != (b,) or not jnp.issubdtype(index.dtype, jnp.integer):
        raise ValueError(
            f"index must be an integer array of shape [{b}], got {index.dtype} {index.shape}"
        )
    if is_concrete(index) and b > 0:
        i = np.asarray(index)
        if i.min() < 0 or i.max() >= T:
            raise ValueError(f"index values must lie in [0, {T}), got min {i.min()}, max {i.max()}")
    return index


def zero_dropped(X, Y, keep):
    """Zero the dropped rows (so NaN padding cannot leak through ``0 * NaN``)."""
    return jnp.where(keep[:, None], X, 0.0), jnp.where(keep[:, None], Y, 0.0)
