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

Feature maps:

- :func:`polynomial`: ψ = all monomials of v of degree 2..``degree`` (``comb(k+d−1, d)`` of degree
  d); ``degree=1`` is exactly the linear offset model.
- :func:`random_fourier`: ψ = √(2/count) cos(Ω v/σ + b), Ω ~ N(0, I) [count, k], b ~ U[0, 2π)
  (Rahimi & Recht 2007): ψ(v)ᵀψ(v') ≈ exp(−||(v − v')/σ||²/2) for large ``count``.

Defaults, measured (held-out one-step prediction on Gymnasium Pendulum-v1, Δx = [cos θ − 1,
sin θ, θ̇, 1], Δu = torque; 40 random starts x 200 steps of uniform random torques in [−2, 2]
to fit, 40 others to test; nominal A = I, B = 0; FTRL's ridge with λ = 1e-3, i.e.
``Ridge(alpha=λ√N)``; mean over test rows of ||Δx' − prediction||²)::

    model                          F    test MSE    (train)
    nominal (Δx' = Δx)             -    2.96e-1
    linear (degree 1)              5    2.34e-2     2.30e-2
    polynomial degree 2           15    5.81e-4     4.40e-4
    polynomial degree 3           35    3.59e-4     2.41e-4
    polynomial degree 4           70    3.46e-4     2.27e-4
    polynomial degree 5          126    2.61e-4     1.68e-4
    RFF count (mean of 3 draws)   σ = 0.5    σ = 1      σ = 2      σ = 4
      50                          1.9e-2     4.7e-3     5.7e-4     4.6e-4
      100                         1.5e-2     1.1e-3     3.4e-4     3.8e-4
      200                         9.9e-3     3.0e-4     2.7e-4     3.5e-4
      400                         1.5e-3     1.9e-4     2.4e-4     3.3e-4
      800                         2.9e-4     1.4e-4     2.1e-4     3.2e-4
    (σ = per-input data std (0.65, 0.67, 3.6, 1.2): 3.2e-4 at 200, 2.9e-4 at 400)

The defaults are ``degree=2`` (:data:`DEFAULT_DEGREE`), ``count=400`` (:data:`DEFAULT_COUNT`)
and ``bandwidth=1.0`` (:data:`DEFAULT_BANDWIDTH`). Why: degree 2 removes 97.5% of the linear
model's error (2.3e-2 -> 5.8e-4); degree 3 gains a further 1.6x, but the count grows as k³/6
(the helicopter, k = 24: 2,925 features, FTRL's ZZ alone 68 MB per seed), so the default is 2
and small systems such as the pendulum may ask for 3. For RFF, σ = 1 is best from 400 features
on (inputs of order one, as error coordinates are), and 400 features beat polynomial degree 3
(1.9e-4 vs 3.6e-4) at a size (F = n+m+400) that stays affordable on the helicopter; doubling to
800 gains only 1.3x. The floor is the environment's clip of θ̇ at ±8, which no smooth map
represents: 47 of the 8,000 test rows hit it and hold 90% of degree 3's error (3.7e-5 on the
others).

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

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from loopid.models.linear_offset import (
    LinearOffsetModel,
    _check_model,
    _nominal,
    residual_targets,
    sum_last,
)

__all__ = [
    "DEFAULT_BANDWIDTH",
    "DEFAULT_COUNT",
    "DEFAULT_DEGREE",
    "FeatureMap",
    "dynamics",
    "features",
    "per_sample_loss",
    "polynomial",
    "predict",
    "random_fourier",
    "residual_targets",
]

DEFAULT_DEGREE = 2
DEFAULT_COUNT = 400
DEFAULT_BANDWIDTH = 1.0
MAX_FEATURES = 100_000  # polynomial maps larger than this are refused (FTRL's ZZ is F x F)


@dataclass(frozen=True, eq=False)
class FeatureMap:
    """A fixed feature map φ(Δx [..., n], Δu [..., m]) -> [..., size], first n+m entries z.

    Hashable by identity, so it can be closed over or passed as a static ``jit`` argument.

    Attributes:
      name: a short label, e.g. ``"poly3"`` or ``"rff200"``.
      n, m: the sizes of Δx (with its constant 1) and Δu.
      size: F, the number of features.
      fn: the pure map on ``(dx, du)`` arrays with the right last axes (no checks).
      jacobian: ``(W [F, n], φ [F], v [k]) -> ∂(Wᵀφ)/∂v [k, n]`` at one point, the derivative of
        the nonlinear part ψ only (the linear terms z contribute W's first n+m rows), given φ
        there (v = [Δx_{:-1}; Δu]); :func:`dynamics` differentiates through it instead of
        autodiff. ``None`` (random Fourier features): autodiff.
    """

    name: str
    n: int
    m: int
    size: int
    fn: Callable[[jax.Array, jax.Array], jax.Array]
    jacobian: Callable[[jax.Array, jax.Array, jax.Array], jax.Array] | None = field(
        default=None, repr=False
    )

    def __call__(self, dx, du) -> jax.Array:
        """φ(Δx, Δu): dx [..., n], du [..., m] (same leading axes) -> [..., size]."""
        dx = jnp.asarray(dx, dtype=jnp.float64)
        du = jnp.asarray(du, dtype=jnp.float64)
        if dx.ndim < 1 or dx.shape[-1] != self.n:
            raise ValueError(f"dx must have shape [..., {self.n}], got {dx.shape}")
        if du.shape != (*dx.shape[:-1], self.m):
            raise ValueError(f"du must have shape {(*dx.shape[:-1], self.m)}, got {du.shape}")
        return self.fn(dx, du)


def _positive_int(name: str, v, low: int = 1) -> int:
    if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
    return int(v)


def _sizes(n, m) -> tuple[int, int]:
    return _positive_int("n", n), _positive_int("m", m)


def _linear_and(psi):
    """φ = [Δx; Δu; ψ(v)] with v = [Δx_{:-1}; Δu]."""

    def fn(dx, du):
        v = jnp.concatenate([dx[..., :-1], du], axis=-1)
        return jnp.concatenate([dx, du, psi(v)], axis=-1)

    return fn


def _monomials(k: int, degree: int) -> list[np.ndarray]:
    """Index tables, one per degree d = 2..degree: [comb(k+d−1, d), d] (sorted tuples)."""
    tables = []
    for d in range(2, degree + 1):
        rows = list(itertools.combinations_with_replacement(range(k), d))
        tables.append(np.asarray(rows, dtype=np.int32).reshape(len(rows), d))
    return tables


def _lowered(k: int, tables: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per degree d = 2..: (q [M_d, d], c [M_d, d]): monomial p without its slot j is monomial
    q[p, j] of degree d−1 (its index into ``range(k)`` for d = 2, else into the degree-(d−1)
    table), and c[p, j] = p's index in slot j."""
    out = []
    index = {(i,): i for i in range(k)}
    for table in tables:
        rows = [tuple(r) for r in table.tolist()]
        d = table.shape[1]
        q = np.asarray(
            [[index[r[:j] + r[j + 1 :]] for j in range(d)] for r in rows], dtype=np.int32
        ).reshape(len(rows), d)
        out.append((q, table))
        index = {r: i for i, r in enumerate(rows)}
    return out


def polynomial(n: int, m: int, degree: int = DEFAULT_DEGREE) -> FeatureMap:
    """Polynomial features: z, then every monomial v_{i₁}···v_{i_d}, i₁ ≤ ... ≤ i_d, d = 2..degree.

    Size F = n + m + Σ_{d=2}^{degree} comb(k+d−1, d), k = n−1+m (pendulum n=4, m=1: 15 at
    degree 2, 35 at 3; helicopter n=21, m=4: 325 at degree 2). Each degree's monomials are a
    gather of v's columns [..., M_d, d] multiplied left to right (fixed shapes, no powers).

    Any degree comes with its analytic derivative (:attr:`FeatureMap.jacobian`, each monomial's
    derivative), which :func:`dynamics` uses.
    """
    n, m = _sizes(n, m)
    degree = _positive_int("degree", degree)
    k = n - 1 + m
    size = n + m + sum(math.comb(k + d - 1, d) for d in range(2, degree + 1))
    if size > MAX_FEATURES:
        raise ValueError(
            f"degree={degree} gives {size} features for {k} inputs, more than {MAX_FEATURES}"
        )
    np_tables = _monomials(k, degree)
    tables = [jnp.asarray(t) for t in np_tables]
    lowered = _lowered(k, np_tables)

    def psi(v):
        out = [jnp.zeros((*v.shape[:-1], 0), v.dtype)]
        for table in tables:
            g = v[..., table]  # [..., M_d, d]
            p = g[..., 0]
            for j in range(1, table.shape[1]):
                p = p * g[..., j]
            out.append(p)
        return jnp.concatenate(out, axis=-1)

    def jacobian(W, phi, v):
        # ∂/∂v_c of Σ_p W_p v_{i₁}···v_{i_d} = Σ_{q of degree d−1} mono_q(v) G_d[q, c], where
        # G_d [M_{d−1}, k, n] gathers, for each monomial p and each slot j (c = i_j), W_p into
        # the row of p without that slot (a repeated index is met once per slot, hence
        # v_c² -> 2v_c). G_d depends on W alone: under vmap over points or tangents it is built
        # once.
        out = jnp.zeros((k, W.shape[1]), W.dtype)
        start = n + m  # the degree-d block of φ and W
        below = v  # the monomials of degree d−1 (degree 1: v itself)
        for table, (q, c) in zip(np_tables, lowered, strict=True):
            rows = W[start : start + table.shape[0]]  # [M_d, n]
            G = jnp.zeros((below.shape[0], k, W.shape[1]), W.dtype)
            G = G.at[q, c].add(jnp.broadcast_to(rows[:, None, :], (*q.shape, W.shape[1])))
            out = out + jnp.einsum("q,qcn->cn", below, G)
            below = phi[start : start + table.shape[0]]
            start += table.shape[0]
        return out

    return FeatureMap(f"poly{degree}", n, m, size, jax.jit(_linear_and(psi)), jacobian)


def random_fourier(
    n: int,
    m: int,
    count: int = DEFAULT_COUNT,
    bandwidth=DEFAULT_BANDWIDTH,
    seed: int = 0,
) -> FeatureMap:
    """Random Fourier features: z, then √(2/count) cos(Ω (v/σ) + b)  [count].

    Ω [count, k] ~ N(0, I) and b [count] ~ U[0, 2π) are drawn once from ``jax.random.key(seed)``
    (split into two keys). E_{Ω,b}[ψ(v)ᵀψ(v')] = exp(−||(v − v')/σ||²/2), the Gaussian kernel
    with bandwidth σ (Rahimi & Recht 2007).

    Args:
      n, m: sizes of Δx (with its constant 1) and Δu.
      count: number of random features, >= 1.
      bandwidth: σ > 0, a scalar or one per input of v ([n−1+m]: Δx without its constant, then
        Δu), in the units of those inputs.
      seed: integer seed of the draw.
    """
    n, m = _sizes(n, m)
    count = _positive_int("count", count)
    if count > MAX_FEATURES:
        raise ValueError(f"count must be at most {MAX_FEATURES}, got {count}")
    k = n - 1 + m
    bw = np.asarray(bandwidth, dtype=np.float64)
    if bw.ndim > 1 or (bw.ndim == 1 and bw.shape[0] != k):
        raise ValueError(f"bandwidth must be a scalar or have {k} entries, got shape {bw.shape}")
    if not (np.all(np.isfinite(bw)) and np.all(bw > 0)):
        raise ValueError(f"bandwidth must be finite and > 0, got {bandwidth!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    k_omega, k_phase = jax.random.split(jax.random.key(int(seed)))
    omega = jax.random.normal(k_omega, (count, k), dtype=jnp.float64)
    phase = jax.random.uniform(k_phase, (count,), dtype=jnp.float64, maxval=2 * math.pi)
    scaled = omega / jnp.asarray(np.broadcast_to(bw, (k,)))[None, :]  # Ω/σ, column-wise
    scale = math.sqrt(2.0 / count)

    def psi(v):
        return scale * jnp.cos(v @ scaled.T + phase)

    return FeatureMap(f"rff{count}", n, m, n + m + count, jax.jit(_linear_and(psi)))


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
