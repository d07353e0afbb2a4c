"""Dense linear algebra the Riccati solvers share (:mod:`loopid.control.lqr`,
:mod:`loopid.control.lqr_affine`, :mod:`loopid.control.tvlqr`), written never to return NaN.

- :func:`psd_solve`: S X = rhs for a symmetric PSD ``S [m, m]`` and ``rhs [m, k]`` by Cholesky
  (written out element by element for m ≤ 8, which XLA fuses into a few kernels); where the
  factor fails, S + δI with δ = 1e-12·(tr S / m) + 1e-300; where that fails too, zeros.
- :func:`finite_or_zero`: NaN as 0 and ±inf as ± ``BLOWUP`` (1e150, the size at which the
  doubling of :mod:`loopid.control.lqr` counts an iterate as diverged).
- :func:`broadcast_batch`: the leading (batch) axes of matrices ``[..., r, c]`` broadcast to one
  batch shape.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = ["broadcast_batch", "finite_or_zero", "psd_solve"]

BLOWUP = 1e150


def _small_cho_solve(S: Array, rhs: Array) -> Array:
    """Cholesky solve written out element by element (m ≤ 8): XLA fuses it into a few kernels,
    where LAPACK's potrf would be one call per matrix (most of tvlqr's time for m = 4)."""
    m = S.shape[0]
    L = [[None] * m for _ in range(m)]
    for j in range(m):
        d = S[j, j] - sum((L[j][k] * L[j][k] for k in range(j)), start=0.0)
        L[j][j] = jnp.sqrt(d)
        for i in range(j + 1, m):
            v = S[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), start=0.0)
            L[i][j] = v / L[j][j]
    y = []
    for i in range(m):
        v = rhs[i] - sum((L[i][k] * y[k] for k in range(i)), start=0.0)
        y.append(v / L[i][i])
    x = [None] * m
    for i in reversed(range(m)):
        v = y[i] - sum((L[k][i] * x[k] for k in range(i + 1, m)), start=0.0)
        x[i] = v / L[i][i]
    return jnp.stack(x)


def _cho_solve(S: Array, rhs: Array) -> Array:
    if S.shape[0] <= 8:
        return _small_cho_solve(S, rhs)
    L = jnp.linalg.cholesky(S)
    return jax.scipy.linalg.cho_solve((L, True), rhs)


def psd_solve(S: Array, rhs: Array) -> tuple[Array, Array]:
    """Solve S X = rhs for symmetric PSD ``S [m, m]``, ``rhs [m, k]``; never returns NaN.

    Cholesky first; if that fails (S singular or indefinite by round-off) retry with
    S + δI, δ = 1e-12·(tr S / m) + 1e-300; if that fails too return zeros. Returns
    ``(X, ok)`` where ``ok`` is True when the plain Cholesky solve succeeded.
    """
    S = 0.5 * (S + S.T)
    m = S.shape[-1]
    delta = 1e-12 * jnp.abs(jnp.trace(S)) / m + 1e-300
    # Both attempts as one stacked solve: half as many (tiny) XLA kernels as two separate ones.
    S2 = jnp.stack([S, S + delta * jnp.eye(m, dtype=S.dtype)])
    X2 = jax.vmap(_cho_solve, in_axes=(0, None))(S2, rhs)
    ok = jnp.all(jnp.isfinite(X2), axis=tuple(range(1, X2.ndim)))
    X = jnp.where(ok[0], X2[0], jnp.where(ok[1], X2[1], jnp.zeros_like(rhs)))
    return X, ok[0]


def finite_or_zero(x: Array) -> Array:
    """``x`` with NaN as 0 and ±inf as ± ``BLOWUP`` (never NaN downstream)."""
    return jnp.nan_to_num(x, nan=0.0, posinf=BLOWUP, neginf=-BLOWUP)


def broadcast_batch(*xs):
    """Broadcast the leading (batch) axes of matrices ``[..., r, c]`` to one batch shape."""
    batch = tuple(np.broadcast_shapes(*(x.shape[:-2] for x in xs)))
    return batch, [jnp.broadcast_to(x, batch + x.shape[-2:]) for x in xs]
