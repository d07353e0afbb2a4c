r"""The linear offset model (paper section 6): a nominal (A, B) plus learned offsets.

In error coordinates Δx [n] (the last entry is the constant 1, so the last column of A is an
affine offset) and control changes Δu [m]::

    Δx' ≈ (A + A')Δx + (B + B')Δu.

The learner fits W = [A' B']ᵀ [n+m, n] by least squares on features and residual targets::

    z = [Δx; Δu]  [n+m],     y = Δx' − (AΔx + BΔu)  [n],     y ≈ Wᵀz,

so Â = A + W[:n]ᵀ and B̂ = B + W[n:]ᵀ. Time-varying form (the funnel): A [T, n, n], B [T, n, m]
and/or W [T, n+m, n], one pair per time step t, each row carrying its step ``t`` [b]; build the
nominal with :func:`time_varying_nominal`, which folds the target's own motion into the affine
column. Rows are batched: dx [b, n], du [b, m], dx_next [b, n], t [b] integers.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "LinearOffsetModel",
    "features",
    "hover_nominal",
    "per_sample_loss",
    "predict",
    "residual_targets",
    "time_varying_nominal",
    "to_matrices",
]


class LinearOffsetModel(NamedTuple):
    """The nominal model: A [n, n] and B [n, m], or time-varying A [T, n, n] and B [T, n, m]."""

    A: jax.Array
    B: jax.Array

    @property
    def n(self) -> int:
        return self.A.shape[-1]

    @property
    def m(self) -> int:
        return self.B.shape[-1]

    @property
    def time_varying(self) -> bool:
        return self.A.ndim == 3


def _check_model(model: LinearOffsetModel) -> None:
    A, B = jnp.shape(model.A), jnp.shape(model.B)
    ok = len(A) in (2, 3) and len(A) == len(B) and A[-1] == A[-2] and B[:-1] == A[:-1]
    if not ok:
        raise ValueError(f"model needs A [(T,) n, n] and B [(T,) n, m], got A {A}, B {B}")


def _check_rows(model, dx, du, dx_next=None, t=None, W=None):
    """Check row shapes against the model (static checks only; fine on tracers)."""
    _check_model(model)
    n, m = model.n, model.m
    dx = jnp.asarray(dx)
    du = jnp.asarray(du)
    if dx.ndim != 2 or dx.shape[1] != n:
        raise ValueError(f"dx must have shape [b, {n}], got {dx.shape}")
    b = dx.shape[0]
    if du.shape != (b, m):
        raise ValueError(f"du must have shape [{b}, {m}], got {du.shape}")
    if dx_next is not None and jnp.shape(dx_next) != (b, n):
        raise ValueError(f"dx_next must have shape [{b}, {n}], got {jnp.shape(dx_next)}")
    if W is not None:
        W = jnp.asarray(W)
        if W.ndim not in (2, 3) or W.shape[-2:] != (n + m, n):
            raise ValueError(f"W must have shape [(T,) {n + m}, {n}], got {W.shape}")
    needs_t = model.time_varying or (W is not None and W.ndim == 3)
    if needs_t:
        if t is None:
            raise ValueError("t [b] (each row's time step) is required for a time-varying model")
        t = jnp.asarray(t)
        if t.shape != (b,) or not jnp.issubdtype(t.dtype, jnp.integer):
            raise ValueError(f"t must be an integer array of shape [{b}], got {t.dtype} {t.shape}")
    return dx.astype(jnp.float64), du.astype(jnp.float64), (t if needs_t else None), W


def _rows(M, t):
    """M [r, c] (shared) or [T, r, c] gathered per row with t [b] -> [b, r, c] or [r, c]."""
    return M if M.ndim == 2 else M[t]


def _apply(M, v):
    """M v per row: M [r, c] or [b, r, c], v [b, c] -> [b, r]."""
    return v @ M.T if M.ndim == 2 else jnp.einsum("brc,bc->br", M, v)


def features(dx, du) -> jax.Array:
    """z = [Δx; Δu]: dx [b, n], du [b, m] -> [b, n+m] (any matching leading axes)."""
    return jnp.concatenate([jnp.asarray(dx), jnp.asarray(du)], axis=-1).astype(jnp.float64)


def _nominal(A, B, dx, du, t):
    return _apply(_rows(A, t), dx) + _apply(_rows(B, t), du)


@jax.jit
def _residual(A, B, dx, du, dx_next, t):
    return dx_next - _nominal(A, B, dx, du, t)


@jax.jit
def _predict(A, B, W, dx, du, t):
    z = jnp.concatenate([dx, du], axis=-1)
    Wr = _rows(W, t)
    offset = z @ Wr if Wr.ndim == 2 else jnp.einsum("bf,bfn->bn", z, Wr)
    return _nominal(A, B, dx, du, t) + offset


def _AB(model):
    return tuple(jnp.asarray(a, dtype=jnp.float64) for a in model)


def residual_targets(model: LinearOffsetModel, dx, du, dx_next, t=None) -> jax.Array:
    """y = Δx' − (AΔx + BΔu) [b, n] (A, B taken at each row's step t when time-varying)."""
    dx, du, t, _ = _check_rows(model, dx, du, dx_next, t)
    return _residual(*_AB(model), dx, du, jnp.asarray(dx_next, dtype=jnp.float64), t)


def predict(model: LinearOffsetModel, W, dx, du, t=None) -> jax.Array:
    """Δx' prediction (A + A')Δx + (B + B')Δu [b, n] with W = [A' B']ᵀ [(T,) n+m, n]."""
    dx, du, t, W = _check_rows(model, dx, du, None, t, W)
    return _predict(*_AB(model), W.astype(jnp.float64), dx, du, t)


def per_sample_loss(model: LinearOffsetModel, W, dx, du, dx_next, t=None) -> jax.Array:
    """||Δx' − prediction||² per row [b] (the paper's squared prediction error)."""
    dx, du, t, W = _check_rows(model, dx, du, dx_next, t, W)
    pred = _predict(*_AB(model), W.astype(jnp.float64), dx, du, t)
    return sum_last((jnp.asarray(dx_next, dtype=jnp.float64) - pred) ** 2)


def sum_last(x) -> jax.Array:
    """``x [..., k] -> [...]``: the sum over the last axis in one fixed order, x₀ + x₁ + ... (k
    elementwise adds). ``jnp.sum`` over a short last axis is vectorised by XLA's CPU backend in a
    way that depends on how many rows there are, so under ``vmap`` a seed's sum could change in
    its last bit with the number of seeds beside it; this one does not (so the experiment
    pipeline may split seeds into chunks)."""
    x = jnp.asarray(x)
    total = x[..., 0]
    for i in range(1, x.shape[-1]):
        total = total + x[..., i]
    return total


def to_matrices(model: LinearOffsetModel, W) -> tuple[jax.Array, jax.Array]:
    """(Â, B̂) = (A + W[:n]ᵀ, B + W[n:]ᵀ): [n, n], [n, m], or [T, n, n], [T, n, m] if either
    the nominal or W is time-varying. Works under jit/vmap (extra leading axes on W broadcast)."""
    _check_model(model)
    n, m = model.n, model.m
    W = jnp.asarray(W, dtype=jnp.float64)
    if W.ndim < 2 or W.shape[-2:] != (n + m, n):
        raise ValueError(f"W must have shape [..., {n + m}, {n}], got {W.shape}")
    A = jnp.asarray(model.A, dtype=jnp.float64) + jnp.swapaxes(W[..., :n, :], -1, -2)
    B = jnp.asarray(model.B, dtype=jnp.float64) + jnp.swapaxes(W[..., n:, :], -1, -2)
    return A, B


def hover_nominal(n: int, m: int) -> LinearOffsetModel:
    """The paper's initial hover model: A = I [n, n]; B [n, m] adds Δu into the u_prev (rows 0..m-1)
    and du_prev (rows m..2m-1) entries of the error state (the helicopter's state layout)."""
    for name, v in (("n", n), ("m", m)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    if n < 2 * m:
        raise ValueError(f"n must be >= 2*m to hold u_prev and du_prev, got n={n}, m={m}")
    B = np.zeros((n, m))
    B[0:m] = np.eye(m)
    B[m : 2 * m] = np.eye(m)
    return LinearOffsetModel(A=jnp.asarray(np.eye(n)), B=jnp.asarray(B))


def time_varying_nominal(A, B, increments) -> LinearOffsetModel:
    """Time-varying nominal for a moving target: Δx_{t+1} = AΔx_t + BΔu_t − (x*_{t+1} ⊖ x*_t).

    With the constant 1 as the last error coordinate, the increment folds into the affine column:
    A_t = A with A_t[:, -1] −= increments[t], B_t = B (the funnel's nominal model).

    Args:
      A: [n, n], B: [n, m], the hover linearisation in error coordinates.
      increments: [T, n], x*_{t+1} ⊖ x*_t in error coordinates. Its last entry (the constant
        coordinate, not a state difference) is ignored, so the constant stays exactly 1.

    Returns:
      LinearOffsetModel with A [T, n, n], B [T, n, m].
    """
    A = jnp.asarray(A, dtype=jnp.float64)
    B = jnp.asarray(B, dtype=jnp.float64)
    inc = jnp.asarray(increments, dtype=jnp.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or B.ndim != 2 or B.shape[0] != A.shape[0]:
        raise ValueError(f"A must be [n, n] and B [n, m], got {A.shape}, {B.shape}")
    n = A.shape[0]
    if inc.ndim != 2 or inc.shape[1] != n or inc.shape[0] < 1:
        raise ValueError(f"increments must have shape [T, {n}], got {inc.shape}")
    if not isinstance(inc, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(inc))):
        raise ValueError("increments has non-finite values")
    T = inc.shape[0]
    inc = inc.at[:, -1].set(0.0)
    At = jnp.broadcast_to(A, (T, n, n)).at[:, :, -1].add(-inc)
    Bt = jnp.broadcast_to(B, (T, *B.shape))
    return LinearOffsetModel(A=At, B=Bt)
