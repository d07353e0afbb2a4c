"""Finite-horizon, time-varying LQR with affine dynamics and linear cost terms.

Problem (t = 0..T-1; same quadratic convention as :func:`loopid.control.dlqr`, no ½)::

    minimise   Σ_t [x_tᵀQ_t x_t + 2q_tᵀx_t + u_tᵀR_t u_t + 2r_tᵀu_t + 2x_tᵀM_t u_t]
               + x_Tᵀ Q_T x_T + 2 q_Tᵀ x_T
    subject to x_{t+1} = A_t x_t + B_t u_t + c_t.

Solution: u_t = -K_t x_t - k_t, cost-to-go V_t(x) = xᵀP_t x + 2p_tᵀx + const. Backward
recursion from P_T = Q_T, p_T = q_T, with s = P_{t+1}c_t + p_{t+1}::

    H_xx = Q + AᵀPA,   H_uu = R + BᵀPB,   H_ux = Mᵀ + BᵀPA,   h_x = q + Aᵀs,   h_u = r + Bᵀs
    K = H_uu⁻¹ H_ux,   k = H_uu⁻¹ h_u
    P_t = H_xx - H_uxᵀK - KᵀH_ux + KᵀH_uu K,   p_t = h_x - H_uxᵀk - Kᵀh_u + KᵀH_uu k

(the last two are the value of the gains actually used, so they stay right when iLQR adds μI to
H_uu). H_uu is factored by Cholesky; when it is singular (R = 0 with rank-deficient B) the solve
falls back to H_uu + δI (δ = 1e-12 tr H_uu / m), then to zero gains: never NaN.

Shapes (time axis first): ``A [T, n, n]``, ``B [T, n, m]``, ``c [T, n]``, ``Q [T, n, n]``,
``q [T, n]``, ``R [T, m, m]``, ``r [T, m]``, ``M [T, n, m]``, ``Q_T [n, n]``, ``q_T [n]``. Any
per-step argument may drop its time axis (it is then the same at every step); T comes from the
arguments that have one, or from ``T=``. Batch by ``jax.vmap``. Results: ``K [T, m, n]``,
``k [T, m]``, ``P [T+1, n, n]``, ``p [T+1, n]``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from loopid.control._checks import check_finite, check_psd, check_shape, shape_of
from loopid.control.linalg import psd_solve

__all__ = ["TVLQRSolution", "tvlqr"]


class TVLQRSolution(NamedTuple):
    """Time-varying affine gains u_t = -K_t x_t - k_t and the value xᵀP_t x + 2p_tᵀx + const.

    Attributes:
        K: ``[T, m, n]`` feedback gains.
        k: ``[T, m]`` feedforward terms.
        P: ``[T+1, n, n]`` value matrices (P[T] = Q_T).
        p: ``[T+1, n]`` value linear terms (p[T] = q_T).
    """

    K: Array
    k: Array
    P: Array
    p: Array


class _BackwardAux(NamedTuple):
    """What iLQR needs besides the gains: predicted cost change terms and solve status."""

    hu_k: Array  # Σ_t h_uᵀk_t  (expected change of a step -αk: α²·kHk - 2α·hu_k)
    kHk: Array  # Σ_t k_tᵀ H_uu k_t
    ok: Array  # every H_uu (+ μI) was positive definite


def backward_recursion(A, B, c, Q, q, R, r, M, Q_T, q_T, mu, *, regularized=True):
    """The recursion of the module docstring, μI added to H_uu (:func:`tvlqr` with μ = 0, and
    iLQR's backward pass); all per-step arrays carry the time axis. No checks. Returns
    ``(TVLQRSolution, aux)``, ``aux`` iLQR's ``hu_k``, ``kHk`` and ``ok`` (every H_uu + μI
    positive definite).

    ``c``, ``q``, ``r``, ``M`` and ``q_T`` may be ``None`` (zero): their terms are then left out
    of the trace, and with no affine or linear term at all ``k`` and ``p`` are exactly zero and
    the linear recursion is skipped. ``regularized=False`` (μ = 0, plain tvlqr) uses the
    shorter, equivalent value update P_t = H_xx - H_xu K, p_t = h_x - H_xu k, and leaves the
    iLQR sums ``hu_k``, ``kHk`` at 0.

    Per step the three Hessian blocks come from two matrix products on the stacked
    [A_t B_t] (n × (n+m)): H = [A B]ᵀ(P[A B]) = [[AᵀPA, AᵀPB], [BᵀPA, BᵀPB]], with [A B]ᵀ
    built transposed when A_t, B_t are read, and the value update uses H_xu = AᵀPB (+ M) on the
    left, so no product contracts over the rows of its left operand (XLA CPU runs those batched
    products about 1.5× slower than plain ones).

    A ``fori_loop`` reads step t by dynamic index and writes the results in place, rather than a
    ``lax.scan`` over the inputs: under ``jax.vmap`` scan moves the time axis of every input
    ahead of the batch axis (a transposed copy of A, Q, … per call), which cost about a third
    of the time of ``tvlqr`` vmapped over problems. The current P_{t+1}, p_{t+1} are
    carried as values rather than read back from the output arrays.
    """
    T, n, m = B.shape
    dt = A.dtype
    eye_m = jnp.eye(m, dtype=dt)
    zero = jnp.zeros((), dt)
    linear = any(x is not None for x in (c, q, r, q_T))

    def step(i, carry):
        t = T - 1 - i
        Ks, ks, Ps, ps, P, p, hu_k, kHk, ok_all = carry
        AB = jnp.concatenate([A[t], B[t]], axis=1)  # [n, n+m]
        ABt = jnp.concatenate([A[t].T, B[t].T], axis=0)  # [A B]ᵀ, read transposed from A, B
        H = ABt @ (P @ AB)
        Hxx = Q[t] + H[:n, :n]
        Huu = R[t] + H[n:, n:]
        Hxu = H[:n, n:]  # = H_uxᵀ
        if M is not None:
            Hxu = Hxu + M[t]
        if linear:
            s = p if c is None else P @ c[t] + p
            h = ABt @ s  # [Aᵀs; Bᵀs]
            hx, hu = h[:n], h[n:]
            if q is not None:
                hx = hx + q[t]
            if r is not None:
                hu = hu + r[t]
            sol, ok = psd_solve(Huu + mu * eye_m, jnp.concatenate([Hxu.T, hu[:, None]], axis=1))
            K, k = sol[:, :-1], sol[:, -1]
        else:
            K, ok = psd_solve(Huu + mu * eye_m, Hxu.T)
        HxuK = Hxu @ K
        if regularized:
            HuuK = Huu @ K
            P_new = Hxx - HxuK - HxuK.T + K.T @ HuuK
        else:
            P_new = Hxx - HxuK
        P_new = 0.5 * (P_new + P_new.T)
        if linear:
            if regularized:
                Huuk = Huu @ k
                p_new = hx - Hxu @ k - K.T @ hu + K.T @ Huuk
                hu_k, kHk = hu_k + hu @ k, kHk + k @ Huuk
            else:
                p_new = hx - Hxu @ k
            ks, ps = ks.at[t].set(k), ps.at[t].set(p_new)
        else:
            p_new = p
        Ks, Ps = Ks.at[t].set(K), Ps.at[t].set(P_new)
        return Ks, ks, Ps, ps, P_new, p_new, hu_k, kHk, ok_all & ok

    Q_T = 0.5 * (Q_T + Q_T.T)
    q_T = jnp.zeros((n,), dt) if q_T is None else q_T
    init = (
        jnp.zeros((T, m, n), dt),
        jnp.zeros((T, m), dt),
        jnp.zeros((T + 1, n, n), dt).at[T].set(Q_T),
        jnp.zeros((T + 1, n), dt).at[T].set(q_T),
        Q_T,
        q_T,
        zero,
        zero,
        jnp.asarray(True),
    )
    K, k, P, p, _, _, hu_k, kHk, ok = jax.lax.fori_loop(0, T, step, init)
    return TVLQRSolution(K, k, P, p), _BackwardAux(hu_k, kHk, ok)


@partial(jax.jit, static_argnames=("T",))
def _tvlqr(A, B, c, Q, q, R, r, M, Q_T, q_T, T) -> TVLQRSolution:
    """Jitted core, no checks. A per-step argument without its time axis is broadcast here, inside
    the jit (XLA then reads the one matrix at every step instead of a materialised [T, ...]
    copy); optional terms may be None (left out of the trace), ``Q_T=None`` is zero."""

    def full(x, core_ndim):
        if x is None or x.ndim == core_ndim + 1:
            return x
        return jnp.broadcast_to(x, (T, *x.shape))

    A, B, c, Q, q, R, r, M = (
        full(x, k) for x, k in zip((A, B, c, Q, q, R, r, M), (2, 2, 1, 2, 1, 2, 1, 2), strict=True)
    )
    if Q_T is None:
        Q_T = jnp.zeros(A.shape[-2:], A.dtype)
    sol, _ = backward_recursion(A, B, c, Q, q, R, r, M, Q_T, q_T, 0.0, regularized=False)
    return sol


def tvlqr(
    A,
    B,
    Q,
    R,
    *,
    c=None,
    q=None,
    r=None,
    M=None,
    Q_T=None,
    q_T=None,
    T: int | None = None,
) -> TVLQRSolution:
    """Finite-horizon time-varying LQR; see the module docstring for the problem and shapes.

    Args:
        A: ``[T, n, n]`` (or ``[n, n]``) dynamics.
        B: ``[T, n, m]`` (or ``[n, m]``) input matrices.
        Q: ``[T, n, n]`` (or ``[n, n]``) symmetric PSD state weights.
        R: ``[T, m, m]`` (or ``[m, m]``) symmetric PSD input weights.
        c: ``[T, n]`` affine drift (default 0).
        q, r: ``[T, n]``, ``[T, m]`` linear cost terms (cost 2qᵀx + 2rᵀu; default 0).
        M: ``[T, n, m]`` cross weights (cost 2xᵀMu; default 0).
        Q_T, q_T: ``[n, n]``, ``[n]`` terminal cost x_TᵀQ_T x_T + 2q_Tᵀx_T (default 0).
        T: horizon, needed only when no argument has a time axis.

    Returns:
        :class:`TVLQRSolution` with u_t = -K_t x_t - k_t.

    Shape checks also run on tracers, value checks (symmetry, PSD, finite) only on concrete
    arrays, so this function can be called inside ``jit``/``vmap``/``scan`` directly.
    """
    sA = shape_of("A", A)
    if len(sA) not in (2, 3) or sA[-1] != sA[-2]:
        raise ValueError(f"A must have shape [T, n, n] or [n, n], got shape {sA}")
    n = sA[-1]
    sB = shape_of("B", B)
    if len(sB) not in (2, 3) or sB[-2] != n:
        raise ValueError(f"B must have shape [T, {n}, m] or [{n}, m], got shape {sB}")
    m = sB[-1]
    per_step = {
        "A": (A, (n, n)),
        "B": (B, (n, m)),
        "Q": (Q, (n, n)),
        "R": (R, (m, m)),
        "c": (c, (n,)),
        "q": (q, (n,)),
        "r": (r, (m,)),
        "M": (M, (n, m)),
    }
    horizons = {}
    for name, (x, core) in per_step.items():
        if x is None:
            continue
        s = check_shape(name, x, core)
        if len(s) == len(core) + 1:
            horizons[name] = s[0]
        elif len(s) != len(core):
            want = "[T, " + ", ".join(map(str, core)) + "]"
            raise ValueError(f"{name} must have shape {want} or without T, got shape {s}")
    if len(set(horizons.values())) > 1:
        raise ValueError(f"time axes differ: {horizons}")
    if T is not None and (int(T) < 1 or any(h != T for h in horizons.values())):
        raise ValueError(f"T must be a positive int equal to the arguments' time axes, got {T}")
    if horizons:
        T = next(iter(horizons.values()))
    if T is None or T < 1:
        raise ValueError("T is required (and positive) when no argument has a time axis")
    if Q_T is not None and check_shape("Q_T", Q_T, (n, n)) != (n, n):
        raise ValueError(f"Q_T must have shape [{n}, {n}], got shape {shape_of('Q_T', Q_T)}")
    if q_T is not None and check_shape("q_T", q_T, (n,)) != (n,):
        raise ValueError(f"q_T must have shape [{n}], got shape {shape_of('q_T', q_T)}")
    for name in ("A", "B", "c", "q", "r", "M"):
        check_finite(name, per_step[name][0])
    check_finite("q_T", q_T)
    check_psd("Q", Q)
    check_psd("R", R)
    check_psd("Q_T", Q_T)

    def f64(x):  # absent optional terms stay None: left out of the trace
        return None if x is None else jnp.asarray(x, dtype=jnp.float64)

    A_, B_, Q_, R_, c_, q_, r_, M_ = (f64(x) for x, _ in per_step.values())
    return _tvlqr(A_, B_, c_, Q_, q_, R_, r_, M_, f64(Q_T), f64(q_T), T=int(T))
