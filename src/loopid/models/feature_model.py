r"""Feature models: the linear offset model plus a fixed nonlinear feature map.

In error coordinates Δx [n] (the last entry is the constant 1) and control changes Δu [m]::

    Δx' ≈ AΔx + BΔu + Wᵀφ(Δx, Δu),      φ = [z; ψ(v)]  [F],
    z = [Δx; Δu]  [n+m],                  v = [Δx_{:-1}; Δu]  [k = n−1+m],

with a fixed nominal (A, B) (:class:`~loopid.models.linear_offset.LinearOffsetModel`) and a
fixed map φ whose first n+m entries are the linear terms, so W = [A' B' | C]ᵀ [F, n] and W = 0
is the nominal. ψ acts on the non-constant coordinates v only (products with the constant 1
would repeat lower degrees). The model is linear in W, so the existing convex online learners
(:func:`~loopid.learners.ftrl_least_squares`, :func:`~loopid.learners.ogd`) fit it unchanged on
rows (φ [b, F], y = Δx' − (AΔx + BΔu) [b, n]) and the paper's no-regret argument (Ross & Bagnell
2012, section 4) carries over. One global W serves every time step (a time-varying nominal
A [T, n, n] is still honoured through each row's step t).

The feature maps (:func:`~loopid.models.feature_maps.polynomial`,
:func:`~loopid.models.feature_maps.random_fourier`) and their measured defaults:
:mod:`loopid.models.feature_maps`.

The planner differentiates :func:`dynamics` (``jax.jacfwd``); it keeps the constant coordinate
exactly 1 by setting the output's last entry to 1 (its Jacobian row is then zero).
:func:`predict` does not (so with ``degree=1`` it equals
:func:`loopid.models.linear_offset.predict`); fitted on consistent data (Δx'_{-1} = 1, nominal
last row e_n) W's last column is zero anyway.

For polynomial maps (any degree) :func:`dynamics` carries an analytic derivative: a
``jax.custom_jvp`` on A_tΔx + B_tΔu + Wᵀφ with W, A_t, B_t as arguments, whose Jacobian in
z = [Δx; Δu] is [A_t B_t]ᵀ + W's first n+m rows + Σ_d ψ_{d−1}(v)·G_d on the non-constant
inputs, G_d [M_{d−1}, k, n] gathered once from W's degree-d rows (ψ_1 = v; each monomial's
derivative), so ``jax.jacfwd``'s n+m tangents meet one [n+m, n] matrix per point instead of
each passing through φ [F] and W [F, n] (helicopter, degree 2: v·G_2 is ~12k multiply-adds
per step against 25 tangents × 325 × 21 ≈ 170k). The values are the plain expression's bit for
bit; the derivatives (∂/∂Δx, ∂/∂Δu, ∂/∂W, second derivatives; ``jacfwd``, ``jacrev``, ``vmap``,
``jit`` all work) equal autodiff's to rounding (~1e-15). Random Fourier features keep plain
autodiff (``FeatureMap.jacobian`` is ``None``). Measured on the funnel plan of
``benchmarks/nonlinear.py`` (T = 599, degree 2, F = 325, 10 iterations, 2 shared CPU cores):
one quadratisation along the plan (the Jacobians and the cost's derivatives) took 55 ms (true
model 1.6 ms) and now 3.4 ms (true 1.7); a plan took 4.5x the true model's time (interleaved,
best of 12: 441 vs 98 ms) and now 1.7x (164 vs 96 ms). What remains is mostly the forward
pass, 11 line-search rollouts through the [11, 325] x [325, 21] product per step (3.3x the
true model's). The pendulum's degree-3 model (F = 35) stays at 1.2x.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import jax
import jax.numpy as jnp

from loopid.models.feature_maps import FeatureMap
from loopid.models.linear_offset import (
    LinearOffsetModel,
    _check_model,
    _nominal,
    residual_targets,
    sum_last,
)

__all__ = [
    "dynamics",
    "features",
    "per_sample_loss",
    "predict",
    "residual_targets",
]


def features(fmap: FeatureMap, dx, du) -> jax.Array:
    """φ(Δx, Δu): dx [b, n], du [b, m] -> [b, F] (any matching leading axes)."""
    return fmap(dx, du)


def _check(model: LinearOffsetModel, fmap: FeatureMap, W, dx, du, t):
    _check_model(model)
    if (model.n, model.m) != (fmap.n, fmap.m):
        raise ValueError(
            f"feature map is for n={fmap.n}, m={fmap.m}, the model has n={model.n}, m={model.m}"
        )
    W = jnp.asarray(W)
    if W.shape != (fmap.size, model.n):
        raise ValueError(f"W must have shape [{fmap.size}, {model.n}], got {W.shape}")
    dx = jnp.asarray(dx, dtype=jnp.float64)
    du = jnp.asarray(du, dtype=jnp.float64)
    if dx.ndim != 2 or dx.shape[1] != model.n or du.shape != (dx.shape[0], model.m):
        raise ValueError(
            f"dx, du must have shapes [b, {model.n}], [b, {model.m}], got {dx.shape}, {du.shape}"
        )
    if model.time_varying:
        if t is None:
            raise ValueError("t [b] (each row's time step) is required for a time-varying model")
        t = jnp.asarray(t)
        if t.shape != (dx.shape[0],) or not jnp.issubdtype(t.dtype, jnp.integer):
            raise ValueError(f"t must be an integer array of shape [{dx.shape[0]}], got {t.shape}")
    else:
        t = None
    AB = tuple(jnp.asarray(a, dtype=jnp.float64) for a in model)
    return AB, W.astype(jnp.float64), dx, du, t


@partial(jax.jit, static_argnums=0)
def _predict(fmap, A, B, W, dx, du, t):
    return _nominal(A, B, dx, du, t) + fmap.fn(dx, du) @ W


def predict(model: LinearOffsetModel, fmap: FeatureMap, W, dx, du, t=None) -> jax.Array:
    """AΔx + BΔu + Wᵀφ(Δx, Δu) per row: W [F, n], dx [b, n], du [b, m] -> [b, n]
    (A, B at each row's step t [b] when the nominal is time-varying)."""
    (A, B), W, dx, du, t = _check(model, fmap, W, dx, du, t)
    return _predict(fmap, A, B, W, dx, du, t)


def per_sample_loss(model: LinearOffsetModel, fmap: FeatureMap, W, dx, du, dx_next, t=None):
    """||Δx' − prediction||² per row [b] (the paper's squared prediction error)."""
    (A, B), W, dx, du, t = _check(model, fmap, W, dx, du, t)
    dx_next = jnp.asarray(dx_next, dtype=jnp.float64)
    if dx_next.shape != dx.shape:
        raise ValueError(f"dx_next must have shape {dx.shape}, got {dx_next.shape}")
    return sum_last((dx_next - _predict(fmap, A, B, W, dx, du, t)) ** 2)


def dynamics(model: LinearOffsetModel, fmap: FeatureMap, W) -> Callable:
    """The learned model as the solvers' ``f(dx [n], du [m], t) -> dx' [n]``, pure and
    differentiable (``jax.jacfwd``, ``jit``, ``vmap``).

    f(Δx, Δu, t) = A_t Δx + B_t Δu + Wᵀφ(Δx, Δu), then its last entry set to exactly 1 (the
    constant coordinate). ``t`` (an integer, may be traced) picks A_t, B_t of a time-varying
    nominal and is ignored otherwise. W: [F, n].
    """
    (A, B), W, _, _, _ = _check(
        model, fmap, W, jnp.zeros((1, model.n)), jnp.zeros((1, model.m)), jnp.zeros(1, jnp.int32)
    )
    tv = model.time_varying

    def f(dx, du, t=0):
        At, Bt = (A[t], B[t]) if tv else (A, B)
        if fmap.jacobian is None:  # autodiff
            out = At @ dx + Bt @ du + fmap.fn(dx, du) @ W
        else:
            out = _step(fmap, W, At, Bt, dx, du)
        return out.at[-1].set(1.0)

    return f


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _step(fmap: FeatureMap, W, At, Bt, dx, du):
    """A_tΔx + B_tΔu + Wᵀφ(Δx, Δu) at one point (dx [n], du [m]), with its analytic JVP.

    W, A_t, B_t are arguments (a custom_jvp must not close over tracers). The JVP is
    J_zᵀdz + dA_t Δx + dB_t Δu + φᵀdW with J_z = [A_t B_t]ᵀ + ∂(Wᵀφ)/∂z [n+m, n] (W's first n+m
    rows plus ``fmap.jacobian`` on the non-constant inputs), so ``jax.jacfwd`` pushes its basis
    through one [n+m, n] matrix per point instead of through φ and W.
    """
    return At @ dx + Bt @ du + fmap.fn(dx, du) @ W


def _is_zero(tangent) -> bool:
    return isinstance(tangent, jax.custom_derivatives.SymbolicZero)


@partial(_step.defjvp, symbolic_zeros=True)
def _step_jvp(fmap, primals, tangents):
    W, At, Bt, dx, du = primals
    dW, dAt, dBt, ddx, ddu = tangents
    phi = fmap.fn(dx, du)
    out = At @ dx + Bt @ du + phi @ W  # as _step
    parts = []
    if not (_is_zero(ddx) and _is_zero(ddu)):
        n = fmap.n
        Jv = fmap.jacobian(W, phi, jnp.concatenate([dx[:-1], du]))  # [k, n]
        # ∂out/∂z [n+m, n]: the nominal's, W's linear rows, Jv on the non-constant inputs
        Jz = W[: n + fmap.m] + jnp.concatenate(
            [At.T[: n - 1] + Jv[: n - 1], At.T[n - 1 :], Bt.T + Jv[n - 1 :]]
        )
        ddx = jnp.zeros_like(dx) if _is_zero(ddx) else ddx
        ddu = jnp.zeros_like(du) if _is_zero(ddu) else ddu
        parts.append(jnp.concatenate([ddx, ddu]) @ Jz)
    if not _is_zero(dAt):
        parts.append(dAt @ dx)
    if not _is_zero(dBt):
        parts.append(dBt @ du)
    if not _is_zero(dW):
        parts.append(phi @ dW)
    return out, sum(parts[1:], parts[0]) if parts else jnp.zeros_like(out)
