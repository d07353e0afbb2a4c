"""What a static gain means for linear models of the helicopter near the hover trim.

Helpers of ``analysis/best_linear_gain/best_linear_gain.py`` (its sections 3 and 4): the hover
linearisation's one-step error over visited states, by block and by distance from the trim
(:func:`linearisation_error`, :func:`scaled_error`); an undelayed linear model whose LQR gain is a
given gain (:func:`model_with_gain`, with :func:`lyapunov`); inverse optimality, whether some cost
makes the gain the true linearisation's LQR gain (:func:`inverse_optimality`); and the least-squares
linear model of the true steps (:func:`least_squares_model`). Imported by that script's report; run
alone it does nothing.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
from linear_gain_flights import N_Z, STATE_BLOCKS, true_next  # beside this script

import loopid  # noqa: F401  (float64)
from loopid.systems import helicopter


def linearisation_error(A, B, dx, du, nxt) -> dict:
    """Per block: RMS error of the linear one-step prediction, RMS of the true increment."""
    pred = dx @ A.T + du @ B.T
    err, inc = pred - nxt, nxt - dx
    norm = np.linalg.norm(dx[:, :N_Z], axis=1)
    edges = np.quantile(norm, np.linspace(0, 1, 6))
    out = {"edges": edges, "n": dx.shape[0], "blocks": {}, "bins": []}
    for name, sl in STATE_BLOCKS:
        out["blocks"][name] = (
            np.sqrt(np.mean(err[:, sl] ** 2)),
            np.sqrt(np.mean(inc[:, sl] ** 2)),
        )
    for lo, hi in itertools.pairwise(edges):
        sel = (norm >= lo) & (norm <= hi)
        row = {"lo": lo, "hi": hi, "n": int(sel.sum()), "mean_norm": norm[sel].mean()}
        for name, sl in STATE_BLOCKS:
            e = np.sqrt(np.mean(err[sel][:, sl] ** 2))
            i = np.sqrt(np.mean(inc[sel][:, sl] ** 2))
            row[name] = (e, i)
        out["bins"].append(row)
    return out


def scaled_error(A, B, dx, du, x_star, scales) -> dict:
    """RMS error per block of the linear prediction when every visited deviation from the trim
    (Δx without the constant, and Δu) is scaled by s: {s: {block: rms}}."""
    out = {}
    for s in scales:
        d = np.array(dx)
        d[:, :N_Z] *= s
        x = jax.vmap(helicopter.from_error, in_axes=(0, None))(jnp.asarray(d), x_star)
        nxt = true_next(np.asarray(x), s * du, x_star)
        err = d @ A.T + (s * du) @ B.T - nxt
        out[s] = {name: float(np.sqrt(np.mean(err[:, sl] ** 2))) for name, sl in STATE_BLOCKS}
    return out


# ----------------------------------------------------------------------------- 3 representability
def lyapunov(Ac: jax.Array, M: jax.Array) -> jax.Array:
    """P with P = Acᵀ P Ac + M (a dense solve, n² unknowns)."""
    n = Ac.shape[0]
    lhs = jnp.eye(n * n) - jnp.kron(Ac.T, Ac.T)
    return jnp.linalg.solve(lhs, M.reshape(-1)).reshape(n, n)


def model_with_gain(A, B, Q, R, K, second_moment, row_scale, iterations: int = 150):
    """An undelayed affine model (Â, B) whose steady-state LQR gain (task's Q, R) is ``K``.

    Unknown: the change ``D = Â − A`` of the true linearisation's rows (B kept), only in the
    rows where ``row_scale [20]`` is positive. With the closed loop ``Ac = Â_z − B_z K_z``
    stable and ``P = Acᵀ P Ac + Q_z + K_zᵀ R K_z``, K is the LQR gain of (Â, B) iff
    ``(R + BᵀPB)⁻¹ Bᵀ P Â_z = K_z`` and the feedforward matches
    ``(R + BᵀPB)⁻¹ Bᵀ (I − Acᵀ)⁻¹ P c = k`` (c: Â's constant column; Q has no constant
    weight). Gauss-Newton from D = 0 with (damped) minimum-norm steps in the metric
    ``Σ_i tr(D_i Σ D_iᵀ) / row_scale_i²`` over the free rows i, Σ = ``second_moment`` of the
    visited [Δx_z; 1]: the smallest change of the mean squared one-step prediction, each row
    in units of ``row_scale`` (e.g. its process-noise std). Returns (Â [21, 21], the max
    residual after each step; it stops when no damped step lowers the residual)."""
    Az, Bz, Qz = A[:N_Z, :N_Z], B[:N_Z], Q[:N_Z, :N_Z]
    c0, Kz, kff = A[:N_Z, N_Z], K[:, :N_Z], K[:, N_Z]
    L = jnp.linalg.cholesky(second_moment + 1e-12 * jnp.eye(N_Z + 1))
    Linv = jnp.linalg.inv(L)
    rows = np.flatnonzero(np.asarray(row_scale) > 0)
    scale = jnp.asarray(np.asarray(row_scale)[rows])

    def change(Y):  # Σ_i tr(D_i Σ D_iᵀ) / scale_i² = ‖Y‖²
        return jnp.zeros((N_Z, N_Z + 1)).at[rows].set(scale[:, None] * (Y @ Linv))

    def residual(Y):
        D = change(Y)
        A_hat = Az + D[:, :N_Z]
        c = c0 + D[:, N_Z]
        Ac = A_hat - Bz @ Kz
        P = lyapunov(Ac, Qz + Kz.T @ R @ Kz)
        S = R + Bz.T @ P @ Bz
        fb = jnp.linalg.solve(S, Bz.T @ P @ A_hat) - Kz
        ff = jnp.linalg.solve(S, Bz.T @ jnp.linalg.solve(jnp.eye(N_Z) - Ac.T, P @ c)) - kff
        return jnp.concatenate([fb.reshape(-1), ff])

    res = jax.jit(residual)
    jac = jax.jit(lambda Y: jax.jacfwd(residual)(Y).reshape(-1, Y.size))
    Y = jnp.zeros((rows.size, N_Z + 1))
    r = res(Y)
    trace, mu = [float(jnp.max(jnp.abs(r)))], 0.0
    for _ in range(iterations):  # damped minimum-norm steps, −Jᵀ(JJᵀ + μI)⁻¹r; μ adapts
        J = jac(Y)
        JJ = J @ J.T
        for _ in range(30):
            step = -J.T @ jnp.linalg.solve(JJ + mu * jnp.eye(r.size), r)
            r_new = res(Y + step.reshape(Y.shape))
            if bool(jnp.all(jnp.isfinite(r_new))) and float(r_new @ r_new) < float(r @ r):
                mu = mu / 10
                break
            mu = max(10 * mu, 1e-12 * float(jnp.trace(JJ)))
        else:
            break  # no step lowers the residual
        Y, r = Y + step.reshape(Y.shape), r_new
        trace.append(float(jnp.max(jnp.abs(r))))
        if trace[-1] < 1e-12:
            break
    A_hat = np.array(A)
    A_hat[:N_Z] += np.asarray(change(Y))
    return A_hat, trace


def inverse_optimality(A, B, Q, R, K, margin: float = 1e-3):
    """Is ``K_z`` the stabilising LQR gain of the true (A_z, B_z) for some Q' ⪰ 0, R' ≻ 0?

    With Ac = A_z − B_z K_z Schur stable, K_z is the stabilising LQR gain of (A_z, B_z, Q', R')
    iff ``B_zᵀ P Ac = R' K_z`` with ``P = Acᵀ P Ac + Q' + K_zᵀ R' K_z``: linear in (Q', R').
    Variables are scaled by the task's ‖Q‖_F, ‖R‖_F (the task's cost is then a unit-sized
    point, R̃ = I/2) and normalised by tr Q̃' = the task's tr Q̃ (the problem is homogeneous;
    the scale is fixed on Q', since a normalisation that let Q̃' shrink would let an
    indefinite Q̃' of vanishing size pass). On that affine set the convex, once-differentiable
    function ``dist(Q̃', PSD)² + dist(R̃' − margin·I, PSD)²`` is minimised (scipy L-BFGS-B):
    its minimum is 0 iff some (Q', R') with R̃' ⪰ margin·I makes K_z optimal.

    A structural fact it meets: A's du_prev columns are zero (the last change does not drive
    the dynamics), so every LQR gain of the true (A, B), K = (R' + BᵀPB)⁻¹BᵀPA, has zero
    du_prev columns whatever (Q', R'); a gain with nonzero ones cannot pass.

    Returns None when Ac is not stable (then no (Q', R') can), else the minimum's square root,
    the final gradient norm, the solution set's dimension and the smallest eigenvalues of
    Q̃', R̃' at the minimiser."""
    from scipy.optimize import minimize

    Az, Bz, Kz = (np.asarray(M, np.float64) for M in (A[:N_Z, :N_Z], B[:N_Z], K[:, :N_Z]))
    Qz, R = np.asarray(Q, np.float64)[:N_Z, :N_Z], np.asarray(R, np.float64)
    Ac = Az - Bz @ Kz
    if np.max(np.abs(np.linalg.eigvals(Ac))) >= 1:
        return None
    n, m = N_Z, Bz.shape[1]
    sq, sr = np.linalg.norm(Qz), np.linalg.norm(R)
    lyap = np.linalg.inv(np.eye(n * n) - np.kron(Ac.T, Ac.T))
    iu_n, iu_m = np.triu_indices(n, 1), np.triu_indices(m, 1)

    def constraint(v):
        Qp, Rp = sq * v[: n * n].reshape(n, n), sr * v[n * n :].reshape(m, m)
        P = (lyap @ (Qp + Kz.T @ Rp @ Kz).reshape(-1)).reshape(n, n)
        eq = (Bz.T @ P @ Ac - Rp @ Kz).reshape(-1) / sr
        sym = np.concatenate([(Qp - Qp.T)[iu_n] / sq, (Rp - Rp.T)[iu_m] / sr])
        return np.concatenate([eq, sym, [np.trace(Qp) / sq]])

    dim = n * n + m * m
    C = np.stack([constraint(e) for e in np.eye(dim)], axis=1)  # the map is linear
    target = np.zeros(C.shape[0])
    target[-1] = np.trace(Qz) / sq
    scale = np.linalg.norm(C, axis=1)  # equilibrate the rows (the blocks' units differ)
    keep = scale > 0  # rows that vanish identically (e.g. a zero column of Ac and of K)
    C, target = C[keep] / scale[keep, None], target[keep] / scale[keep]
    U, sv, Vt = np.linalg.svd(C)
    rank = int(np.sum(sv > 1e-10 * sv[0]))
    v0 = Vt[:rank].T @ ((U[:, :rank].T @ target) / sv[:rank])
    N = Vt[rank:].T  # [dim, k]: the solution set is v0 + N y

    def negative(M):
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        return (V * np.minimum(w, 0.0)) @ V.T

    def parts(y):
        v = v0 + N @ y
        return v[: n * n].reshape(n, n), v[n * n :].reshape(m, m)

    def f(y):
        Qt, Rt = parts(y)
        nq, nr = negative(Qt), negative(Rt - margin * np.eye(m))
        g = N.T @ np.concatenate([2 * nq.reshape(-1), 2 * nr.reshape(-1)])
        return float(np.sum(nq * nq) + np.sum(nr * nr)), g

    options = {"maxiter": 20000, "maxfun": 40000, "ftol": 0.0, "gtol": 1e-14}
    sol = minimize(f, np.zeros(N.shape[1]), jac=True, method="L-BFGS-B", options=options)
    Qt, Rt = parts(sol.x)
    return {
        "dist": float(np.sqrt(sol.fun)),
        "grad": float(np.linalg.norm(sol.jac)),
        "iterations": int(sol.nit),
        "dim": int(N.shape[1]),
        "min_eig_Q": float(np.linalg.eigvalsh(0.5 * (Qt + Qt.T))[0]),
        "min_eig_R": float(np.linalg.eigvalsh(0.5 * (Rt + Rt.T))[0]),
        "residual": float(np.linalg.norm(C @ (v0 + N @ sol.x) - target)),
    }


def least_squares_model(A, B, dx, du, nxt):
    """The affine model fitted by least squares to the true noise-free steps (rows of
    [Δx; Δu] -> Δx'), the constant row kept exact: (Â [21, 21], B̂ [21, 4])."""
    Z = np.concatenate([dx, du], axis=1)
    W, *_ = np.linalg.lstsq(Z, nxt, rcond=None)
    A_hat, B_hat = np.array(W[:21].T), np.array(W[21:].T)
    A_hat[N_Z] = np.asarray(A)[N_Z]
    B_hat[N_Z] = 0.0
    return A_hat, B_hat


if __name__ == "__main__":
    print("helpers of analysis/best_linear_gain/best_linear_gain.py: run that script")
