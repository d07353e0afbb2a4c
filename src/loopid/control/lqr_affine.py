"""Steady-state LQR for affine dynamics written with a constant last coordinate: loopid's error
coordinates x = [z; 1] (:func:`dlqr_affine`; the math there).

With ``A = [[F, c], [0, 1]]``, ``B = [[G], [0]]`` the constant mode is uncontrollable at
eigenvalue 1, so the DARE is solved on the z block by :mod:`loopid.control.lqr` and the value's
linear term and the feedforward follow from one linear solve. Shapes as
:func:`loopid.control.dlqr`: ``A [..., n, n]``, ``B [..., n, m]``, ``Q [..., n, n]``,
``R [..., m, m]``, leading batch axes broadcast; results ``K [..., m, n]`` (u = -K x),
``P [..., n, n]``. :func:`dlqr_affine_unchecked` is the same batched solve without the checks,
for compiled code whose arguments are right by construction.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from loopid.control._checks import is_concrete
from loopid.control.linalg import broadcast_batch, finite_or_zero, psd_solve
from loopid.control.lqr import LQRSolution, check_lqr_args, dlqr_single

__all__ = ["dlqr_affine", "dlqr_affine_unchecked"]


def _dlqr_affine_single(A, B, Q, R, max_iter, tol, rtol_residual) -> LQRSolution:
    F, c, G = A[:-1, :-1], A[:-1, -1], B[:-1]
    Q = 0.5 * (Q + Q.T)
    Qzz, qz = Q[:-1, :-1], Q[:-1, -1]
    nz, m = G.shape
    sol = dlqr_single(F, G, Qzz, R, jnp.zeros((nz, m), F.dtype), max_iter, tol, rtol_residual)
    Kz, Pz = sol.K, sol.P
    Acl = F - G @ Kz
    lhs = jnp.eye(nz, dtype=F.dtype) - Acl.T
    rhs = qz + Acl.T @ (Pz @ c)
    p = jnp.linalg.solve(lhs, rhs)
    p_ok = jnp.all(jnp.isfinite(p))
    # the pseudo-inverse (an SVD) only where the solve failed: one system runs one branch (a
    # batch under vmap runs both and selects, the same numbers)
    p = jax.lax.cond(p_ok, lambda: p, lambda: finite_or_zero(jnp.linalg.pinv(lhs) @ rhs))
    S = R + G.T @ Pz @ G
    kff, _ = psd_solve(S, (G.T @ (Pz @ c + p))[:, None])
    kff = finite_or_zero(kff[:, 0])
    K = jnp.concatenate([Kz, kff[:, None]], axis=1)
    P = jnp.block([[Pz, p[:, None]], [p[None, :], jnp.zeros((1, 1), F.dtype)]])
    return sol._replace(K=K, P=P, converged=sol.converged & p_ok)


@partial(jax.jit, static_argnames=("max_iter",))
def dlqr_affine_unchecked(A, B, Q, R, max_iter=64, tol=1e-13, rtol_residual=1e-8) -> LQRSolution:
    """:func:`dlqr_affine` without its checks (jitted; leading axes broadcast here): for
    compiled code whose ``A``, ``B``, ``Q``, ``R`` have the right shapes and last rows."""
    batch, (A, B, Q, R) = broadcast_batch(A, B, Q, R)
    f = partial(_dlqr_affine_single, max_iter=max_iter, tol=tol, rtol_residual=rtol_residual)
    if not batch:
        return f(A, B, Q, R)
    flat = [x.reshape((-1, *x.shape[-2:])) for x in (A, B, Q, R)]
    sol = jax.vmap(f)(*flat)
    return jax.tree.map(lambda y: y.reshape(batch + y.shape[1:]), sol)


def dlqr_affine(
    A, B, Q, R, *, max_iter: int = 64, tol: float = 1e-13, rtol_residual: float = 1e-8
) -> LQRSolution:
    """Steady-state LQR for affine dynamics written with a constant last coordinate.

    x = [z; 1] with ``A = [[F, c], [0, 1]]``, ``B = [[G], [0]]``, ``Q = [[Q_zz, q], [qᵀ, q₀]]``,
    so z_{t+1} = F z_t + G u_t + c and the stage cost is zᵀQ_zz z + 2qᵀz + q₀ + uᵀRu. The constant
    mode is uncontrollable at eigenvalue 1, so the DARE is solved on the z block (F, G, Q_zz, R)
    giving K_z, P_z. The value's linear term p (cost-to-go zᵀP_z z + 2pᵀz + const) is the fixed
    point of the finite-horizon recursion p ← q + (F - GK_z)ᵀ(P_z c + p), i.e. the linear solve

        (I - (F - GK_z)ᵀ) p = q + (F - GK_z)ᵀ P_z c,

    and the feedforward is k = (R + GᵀP_zG)⁻¹ Gᵀ(P_z c + p). Returned ``K = [K_z, k]`` has shape
    ``[..., m, n]`` so that u = -K x; ``P = [[P_z, p], [pᵀ, 0]]`` (the constant part of the value
    grows with the horizon at the average cost per step and is reported as 0). ``converged``,
    ``residual``, ``spectral_radius`` and ``iterations`` refer to the z block (and ``converged``
    also needs a finite p). This is the limit of the first gain of :func:`tvlqr` on the same
    problem as the horizon grows.

    Shapes as :func:`dlqr`; the last row of A must be [0, …, 0, 1] and the last row of B zero.
    """
    _, n, _ = check_lqr_args(A, B, Q, R, None)
    if n < 2:
        raise ValueError(f"A must be at least 2x2 (state plus constant), got shape {jnp.shape(A)}")
    if is_concrete(A) and is_concrete(B):
        last = np.asarray(A)[..., -1, :]
        want = np.zeros(n)
        want[-1] = 1.0
        if not np.allclose(last, want, rtol=0.0, atol=1e-12):
            raise ValueError(f"A's last row must be [0, ..., 0, 1] (the constant), got {last}")
        lastB = np.asarray(B)[..., -1, :]
        if not np.allclose(lastB, 0.0, rtol=0.0, atol=1e-12):
            raise ValueError(f"B's last row must be zero (constant coordinate), got {lastB}")
    A, B, Q, R = (jnp.asarray(x, dtype=jnp.float64) for x in (A, B, Q, R))
    return dlqr_affine_unchecked(
        A, B, Q, R, max_iter=max_iter, tol=tol, rtol_residual=rtol_residual
    )
