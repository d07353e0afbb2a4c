"""Infinite-horizon discrete LQR by the structure-preserving doubling algorithm (SDA).

Problem (python-control / SciPy convention)::

    minimise   sum_t  x_tᵀ Q x_t + u_tᵀ R u_t + 2 x_tᵀ N u_t
    subject to x_{t+1} = A x_t + B u_t,        u_t = -K x_t,

    P = AᵀPA - (AᵀPB + N)(R + BᵀPB)⁻¹(BᵀPA + Nᵀ) + Q,   K = (R + BᵀPB)⁻¹(BᵀPA + Nᵀ).

Shapes: ``A [..., n, n]``, ``B [..., n, m]``, ``Q [..., n, n]``, ``R [..., m, m]``,
``N [..., n, m]``; leading batch axes broadcast. Results ``K [..., m, n]``, ``P [..., n, n]``.

SDA (Chu, Fan & Lin 2005; Lin & Xu 2006) with A₀ = A, G₀ = B R⁻¹ Bᵀ, H₀ = Q::

    W_k = I + G_k H_k,   A_{k+1} = A_k W_k⁻¹ A_k,
    G_{k+1} = G_k + A_k W_k⁻¹ G_k A_kᵀ,   H_{k+1} = H_k + A_kᵀ H_k W_k⁻¹ A_k

H_k converges quadratically to the stabilising P when (A, B) is stabilisable and (A, Q) has no
unobservable mode on the unit circle; W_k is always invertible (its eigenvalues are ≥ 1 because
G_k, H_k are PSD). No inverse of A is ever taken, so singular or ill-conditioned A is fine. The
iteration runs at most ``max_iter`` times inside ``lax.while_loop`` and stops early when
``‖H_{k+1} - H_k‖_F ≤ tol ‖H_{k+1}‖_F``. An iterate that is non-finite or exceeds 1e150 (an
unstable mode without a control path doubles its exponent every step) is discarded and the loop
stops: the last finite iterate is returned with ``converged = False``.

Up to two Newton (Kleinman-Hewer) steps then refine P: the value of the gain K(P) by a
Smith-doubling Lyapunov solve, kept only where it lowers the residual. They recover the digits the
doubling loses when R is tiny (the helicopter's R = dt·1e-6·I makes G = BR⁻¹Bᵀ ~ 1e7: residual
1e-9 → 1e-17 on hover). A step is taken only while the relative residual exceeds 1e-14, so the
usual case (doubling alone reaches ~1e-15) pays nothing for them.

``converged`` is True only when the iteration met ``tol``, every number is finite, the relative
Riccati residual is at most ``rtol_residual`` and the closed loop A - BK is Schur stable
(spectral radius < 1; :func:`loopid.control.spectral.spectral_radius`: from the eigenvalues on
a CPU, by repeated squaring on an accelerator). A pair that cannot be stabilised (e.g. an
eigenvalue-1 mode with cost but no control path) returns finite K, P with ``converged = False``.

The affine variant for loopid's error coordinates x = [z; 1] (constant last entry) is
:func:`loopid.control.lqr_affine.dlqr_affine`.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from loopid.control._checks import (
    check_batch,
    check_finite,
    check_psd,
    check_shape,
    check_square,
)
from loopid.control.linalg import BLOWUP, broadcast_batch, finite_or_zero, psd_solve
from loopid.control.spectral import spectral_radius

__all__ = ["LQRSolution", "dlqr"]

_REFINE_ABOVE = 1e-14  # Newton-refine only a doubling result with a larger relative residual


class LQRSolution(NamedTuple):
    """Steady-state LQR gain and value (batch axes first).

    Attributes:
        K: ``[..., m, n]`` gain, u = -K x.
        P: ``[..., n, n]`` value matrix, cost-to-go xᵀPx.
        converged: ``[...]`` bool, see the module docstring.
        residual: ``[...]`` relative Riccati residual ‖AᵀPA - P - (AᵀPB + N)K + Q‖_F /
            (‖AᵀPA‖_F + ‖P‖_F + ‖Q‖_F).
        spectral_radius: ``[...]`` largest ``|eigenvalue|`` of A - BK.
        iterations: ``[...]`` int, doubling steps taken.
    """

    K: Array
    P: Array
    converged: Array
    residual: Array
    spectral_radius: Array
    iterations: Array


def _sda(A: Array, G: Array, H: Array, max_iter: int, tol: float):
    """Doubling iteration; returns (H, iterations, met_tol)."""
    n = A.shape[-1]
    eye = jnp.eye(n, dtype=A.dtype)

    def cond(state):
        _, _, _, k, done, _ = state
        return (~done) & (k < max_iter)

    def body(state):
        A, G, H, k, _, _ = state
        W = eye + G @ H
        # W⁻¹[A G] as the explicit inverse times [A G] plus one step of iterative refinement:
        # on XLA CPU under vmap, LAPACK's batched getrs with 2n right-hand sides costs more than
        # getri-by-solve + three products (measured), and the refinement step restores the
        # accuracy of a backward-stable solve when W is ill-conditioned (tiny R: the inverse
        # alone loses 1e-2 relative in the hover P, which Newton cannot win back).
        rhs = jnp.concatenate([A, G], axis=-1)
        Winv = jnp.linalg.inv(W)
        Y = Winv @ rhs
        Y = Y + Winv @ (rhs - W @ Y)
        AY = A @ Y  # [A W⁻¹A | A W⁻¹G] in one product
        A1 = AY[:, :n]
        G1 = G + AY[:, n:] @ A.T
        H1 = H + A.T @ H @ Y[:, :n]
        G1 = 0.5 * (G1 + G1.T)
        H1 = 0.5 * (H1 + H1.T)
        big = jnp.max(jnp.stack([jnp.max(jnp.abs(Z)) for Z in (A1, G1, H1)]))
        bad = ~jnp.isfinite(big) | (big > BLOWUP)
        dH = jnp.linalg.norm(H1 - H)
        nH = jnp.linalg.norm(H1)
        met = dH <= tol * nH
        keep = lambda new, old: jnp.where(bad, old, new)  # noqa: E731
        return (keep(A1, A), keep(G1, G), keep(H1, H), k + 1, bad | met, met & ~bad)

    init = (A, G, H, jnp.asarray(0, jnp.int32), jnp.asarray(False), jnp.asarray(False))
    _, _, H, k, _, met = jax.lax.while_loop(cond, body, init)
    return H, k, met


def _gain_and_residual(A, B, Q, R, N, P):
    """K = (R + BᵀPB)⁻¹(BᵀPA + Nᵀ) and the relative Riccati residual of P."""
    S = R + B.T @ P @ B
    AtPB_N = A.T @ P @ B + N
    K, _ = psd_solve(S, AtPB_N.T)
    K = finite_or_zero(K)
    AtPA = A.T @ P @ A
    res = AtPA - P - AtPB_N @ K + Q
    scale = jnp.linalg.norm(AtPA) + jnp.linalg.norm(P) + jnp.linalg.norm(Q)
    residual = jnp.linalg.norm(res) / jnp.maximum(scale, 1e-300)
    residual = jnp.where(jnp.isfinite(residual), residual, jnp.inf)
    return K, residual


def _newton_step(A, B, Q, R, N, K, max_iter):
    """Value of the gain K: P = A_Kᵀ P A_K + Q - NK - KᵀNᵀ + KᵀRK, A_K = A - BK (Smith doubling)."""
    Acl = A - B @ K
    M = Q - N @ K - K.T @ N.T + K.T @ R @ K
    M = 0.5 * (M + M.T)

    def cond(state):
        _, _, k, done = state
        return (~done) & (k < max_iter)

    def body(state):
        X, Phi, k, _ = state
        X1 = X + Phi.T @ X @ Phi
        Phi1 = Phi @ Phi
        small = jnp.linalg.norm(X1 - X) <= 1e-17 * jnp.linalg.norm(X1)
        bad = ~jnp.all(jnp.isfinite(X1)) | ~jnp.all(jnp.isfinite(Phi1))
        return jnp.where(bad, X, X1), jnp.where(bad, Phi, Phi1), k + 1, small | bad

    init = (M, Acl, jnp.asarray(0, jnp.int32), jnp.asarray(False))
    X, _, _, _ = jax.lax.while_loop(cond, body, init)
    X = 0.5 * (X + X.T)
    return finite_or_zero(X)


def dlqr_single(A, B, Q, R, N, max_iter, tol, rtol_residual, newton_steps=2) -> LQRSolution:
    """The solve of the module docstring for one system (``A [n, n]``, ``B [n, m]``, ``Q``,
    ``R``, ``N [n, m]``; no batch axes), no checks; jittable and vmappable."""
    m = B.shape[-1]
    Q = 0.5 * (Q + Q.T)
    R = 0.5 * (R + R.T)
    # R⁻¹ through a Cholesky factor, regularised minimally when R is singular.
    L = jnp.linalg.cholesky(R)
    delta = 1e-12 * jnp.maximum(jnp.max(jnp.abs(jnp.diag(R))), 1.0)
    L_reg = jnp.linalg.cholesky(R + delta * jnp.eye(m, dtype=R.dtype))
    L = jnp.where(jnp.all(jnp.isfinite(L)), L, L_reg)
    Rinv_NT = jax.scipy.linalg.cho_solve((L, True), N.T)  # [m, n]
    A0 = A - B @ Rinv_NT
    Q0 = Q - N @ Rinv_NT
    Q0 = 0.5 * (Q0 + Q0.T)
    LiBT = jax.scipy.linalg.solve_triangular(L, B.T, lower=True)  # [m, n]
    G0 = LiBT.T @ LiBT
    P, iterations, met = _sda(A0, G0, Q0, max_iter, tol)
    P = finite_or_zero(P)
    K, residual = _gain_and_residual(A, B, Q, R, N, P)

    # Defect correction: Newton (Kleinman-Hewer) steps recover the digits the doubling loses
    # when R is tiny (G = BR⁻¹Bᵀ huge). A step is taken only while the residual is above
    # _REFINE_ABOVE and kept only where it lowers the residual; as a while_loop this also holds
    # under vmap, where the loop runs no step at all when no system of the batch needs one.
    def refine_cond(carry):
        _, _, residual, k, improved = carry
        return met & improved & (residual > _REFINE_ABOVE) & (k < newton_steps)

    def refine(carry):
        P, K, residual, k, _ = carry
        P1 = _newton_step(A, B, Q, R, N, K, max_iter)
        K1, residual1 = _gain_and_residual(A, B, Q, R, N, P1)
        better = residual1 < residual
        return (
            jnp.where(better, P1, P),
            jnp.where(better, K1, K),
            jnp.where(better, residual1, residual),
            k + 1,
            better,
        )

    init = (P, K, residual, jnp.asarray(0, jnp.int32), jnp.asarray(True))
    P, K, residual, _, _ = jax.lax.while_loop(refine_cond, refine, init)
    rho = spectral_radius(A - B @ K)  # the eigenvalues on a CPU, squaring on an accelerator
    rho = jnp.where(jnp.isfinite(rho), rho, jnp.inf)
    converged = met & (residual <= rtol_residual) & (rho < 1.0)
    return LQRSolution(K, P, converged, residual, rho, iterations)


def check_lqr_args(A, B, Q, R, N):
    """:func:`dlqr`'s checks (``N`` may be None): shapes always, finiteness and symmetric PSD
    ``Q``, ``R`` on concrete inputs; returns ``(batch shape, n, m)``."""
    sA = check_square("A", A)
    n = sA[-1]
    sB = check_shape("B", B, (n, None))
    m = sB[-1]
    sQ = check_shape("Q", Q, (n, n))
    sR = check_shape("R", R, (m, m))
    shapes = {"A": sA, "B": sB, "Q": sQ, "R": sR}
    core = {"A": 2, "B": 2, "Q": 2, "R": 2}
    if N is not None:
        shapes["N"] = check_shape("N", N, (n, m))
        core["N"] = 2
    batch = check_batch(shapes, core)
    for name, x in (("A", A), ("B", B), ("N", N)):
        check_finite(name, x)
    check_psd("Q", Q)
    check_psd("R", R)
    return batch, n, m


@partial(jax.jit, static_argnames=("max_iter",))
def _dlqr(A, B, Q, R, N=None, max_iter=64, tol=1e-13, rtol_residual=1e-8) -> LQRSolution:
    """Batched core, no checks: leading axes broadcast here (inside the jit: no eager dispatch
    per argument); ``N=None`` is zero."""
    if N is None:
        N = jnp.zeros(A.shape[:-2] + B.shape[-2:], A.dtype)
    batch, (A, B, Q, R, N) = broadcast_batch(A, B, Q, R, N)
    f = partial(dlqr_single, max_iter=max_iter, tol=tol, rtol_residual=rtol_residual)
    if not batch:
        return f(A, B, Q, R, N)
    flat = [x.reshape((-1, *x.shape[-2:])) for x in (A, B, Q, R, N)]
    sol = jax.vmap(f)(*flat)
    return jax.tree.map(lambda y: y.reshape(batch + y.shape[1:]), sol)


def dlqr(
    A,
    B,
    Q,
    R,
    *,
    N=None,
    max_iter: int = 64,
    tol: float = 1e-13,
    rtol_residual: float = 1e-8,
) -> LQRSolution:
    """Infinite-horizon discrete LQR, u = -K x; see the module docstring for the math.

    Args:
        A: ``[..., n, n]`` dynamics.
        B: ``[..., n, m]`` input matrix.
        Q: ``[..., n, n]`` symmetric PSD state weight.
        R: ``[..., m, m]`` symmetric PSD input weight (singular R is regularised by 1e-12·max R).
        N: optional ``[..., n, m]`` cross weight (cost term 2 xᵀ N u).
        max_iter: cap on doubling steps (each squares the horizon covered; 64 is ample).
        tol: relative change of P at which the doubling stops.
        rtol_residual: largest relative Riccati residual still called converged.

    Returns:
        :class:`LQRSolution`, batch axes = the broadcast of the inputs' leading axes.

    Shape checks always run (also on tracers, inside ``jit``/``vmap``/``scan``); symmetry and
    PSD checks run on concrete inputs only. Call it directly from jitted code.
    """
    check_lqr_args(A, B, Q, R, N)
    A, B, Q, R = (jnp.asarray(x, dtype=jnp.float64) for x in (A, B, Q, R))
    N = None if N is None else jnp.asarray(N, dtype=jnp.float64)
    return _dlqr(A, B, Q, R, N, max_iter=max_iter, tol=tol, rtol_residual=rtol_residual)
