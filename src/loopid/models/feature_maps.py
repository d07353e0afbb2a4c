r"""Fixed feature maps φ(Δx, Δu) for the feature model (:mod:`loopid.models.feature_model`).

In error coordinates Δx [n] (the last entry is the constant 1) and control changes Δu [m]::

    φ = [z; ψ(v)]  [F],      z = [Δx; Δu]  [n+m],      v = [Δx_{:-1}; Δu]  [k = n−1+m],

the first n+m entries the linear terms (so W = 0 in the model's Wᵀφ is the nominal); ψ acts on
the non-constant coordinates v only (products with the constant 1 would repeat lower degrees).

Feature maps:

- :func:`polynomial`: ψ = all monomials of v of degree 2 to ``degree`` (``comb(k+d−1, d)`` of degree
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

Polynomial maps (any degree) carry the analytic derivative of their nonlinear part
(:attr:`FeatureMap.jacobian`, each monomial's derivative), which
:func:`loopid.models.feature_model.dynamics` uses; random Fourier features keep plain autodiff
(``jacobian`` is ``None``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "DEFAULT_BANDWIDTH",
    "DEFAULT_COUNT",
    "DEFAULT_DEGREE",
    "FeatureMap",
    "polynomial",
    "random_fourier",
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
