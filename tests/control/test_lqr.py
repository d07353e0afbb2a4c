"""dlqr / dlqr_affine against closed forms, SciPy, python-control and the SPEC's hover figures."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sl

import control
from loopid.control import dlqr, dlqr_affine, tvlqr
from loopid.systems import helicopter
from loopid.systems.helicopter import tasks


def random_system(rng, n=21, m=4, scale=1.1):
    A = rng.standard_normal((n, n)) / np.sqrt(n) * scale  # spectral radius around 1.1
    B = rng.standard_normal((n, m))
    M = rng.standard_normal((n, n))
    Q = M @ M.T / n + 0.1 * np.eye(n)
    Mr = rng.standard_normal((m, m))
    R = Mr @ Mr.T / m + 0.1 * np.eye(m)
    return A, B, Q, R


def scipy_lqr(A, B, Q, R, N=None):
    P = sl.solve_discrete_are(A, B, Q, R, s=N)
    Nt = 0.0 if N is None else N.T
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + Nt)
    return K, P


def rel(a, b):
    return np.linalg.norm(np.asarray(a) - b) / np.linalg.norm(b)


def hover_problem():
    x_star = helicopter.hover_target()
    A, B = helicopter.linearize(x_star, x_star)
    Q, R = tasks.cost_matrices(tasks.HOVER_WEIGHTS)
    return np.asarray(A), np.asarray(B), np.asarray(Q), np.asarray(R)


@pytest.mark.parametrize(
    ("a", "b", "q", "r"), [(0.9, 1.0, 1.0, 1.0), (1.5, 0.3, 2.0, 0.1), (-2.0, 1.0, 1.0, 5.0)]
)
def test_scalar_closed_form(a, b, q, r):
    # P solves b²P² + (r - a²r - qb²)P - qr = 0 (positive root); K = abP / (r + b²P)
    c1 = r - a * a * r - q * b * b
    P = (-c1 + np.sqrt(c1 * c1 + 4 * b * b * q * r)) / (2 * b * b)
    K = a * b * P / (r + b * b * P)
    sol = dlqr([[a]], [[b]], [[q]], [[r]])
    np.testing.assert_allclose(sol.P[0, 0], P, rtol=1e-12)
    np.testing.assert_allclose(sol.K[0, 0], K, rtol=1e-12)
    np.testing.assert_allclose(sol.spectral_radius, abs(a - b * K), rtol=1e-12)
    assert bool(sol.converged)


def test_matches_scipy_on_100_random_21x4_systems(rng):
    systems = [random_system(rng) for _ in range(100)]
    A, B, Q, R = (np.stack(z) for z in zip(*systems, strict=True))
    sol = dlqr(A, B, Q, R)  # batched: one call for all 100
    assert sol.K.shape == (100, 4, 21) and sol.P.shape == (100, 21, 21)
    assert bool(jnp.all(sol.converged))
    for i in range(100):
        K, P = scipy_lqr(A[i], B[i], Q[i], R[i])
        assert rel(sol.P[i], P) < 1e-8, i
        assert rel(sol.K[i], K) < 1e-8, i
        rho = np.max(np.abs(np.linalg.eigvals(A[i] - B[i] @ K)))
        np.testing.assert_allclose(sol.spectral_radius[i], rho, rtol=1e-8)
    assert float(jnp.max(sol.residual)) < 1e-12


def test_cross_term_matches_python_control(rng):
    A, B, Q, R = random_system(rng, n=6, m=2)
    N = 0.05 * rng.standard_normal((6, 2))
    K_c, P_c, E_c = control.dlqr(A, B, Q, R, N)
    sol = dlqr(A, B, Q, R, N=N)
    assert rel(sol.K, K_c) < 1e-8
    assert rel(sol.P, P_c) < 1e-8
    np.testing.assert_allclose(sol.spectral_radius, np.max(np.abs(E_c)), rtol=1e-8)
    K_s, P_s = scipy_lqr(A, B, Q, R, N)
    assert rel(sol.K, K_s) < 1e-8
    assert rel(sol.P, P_s) < 1e-8


def test_batched_equals_looped_and_broadcasts(rng):
    systems = [random_system(rng, n=5, m=2) for _ in range(6)]
    A, B, Q, R = (np.stack(z) for z in zip(*systems, strict=True))
    A = A.reshape(2, 3, 5, 5)
    B = B.reshape(2, 3, 5, 2)
    sol = dlqr(A, B, Q[0], R[0])  # Q, R shared (broadcast)
    assert sol.K.shape == (2, 3, 2, 5) and sol.converged.shape == (2, 3)
    for i in range(2):
        for j in range(3):
            one = dlqr(A[i, j], B[i, j], Q[0], R[0])
            np.testing.assert_allclose(sol.K[i, j], one.K, rtol=1e-12, atol=1e-14)
            np.testing.assert_allclose(sol.P[i, j], one.P, rtol=1e-12, atol=1e-14)
            assert int(sol.iterations[i, j]) == int(one.iterations)


def test_usable_inside_jit_and_vmap(rng):
    A, B, Q, R = random_system(rng, n=5, m=2)
    f = jax.jit(lambda A: dlqr(A, B, Q, R).K)
    np.testing.assert_allclose(f(A), dlqr(A, B, Q, R).K, rtol=1e-12)
    As = jnp.stack([A, 0.5 * A])
    Ks = jax.vmap(lambda A: dlqr(A, B, Q, R).K)(As)
    np.testing.assert_allclose(Ks[1], dlqr(0.5 * A, B, Q, R).K, rtol=1e-12)


@pytest.mark.parametrize("a_unctrl", [1.0, 1.5])
def test_unstabilisable_pair_is_flagged_with_finite_numbers(a_unctrl):
    # the first state has no control path and eigenvalue >= 1, with cost on it
    A = np.diag([a_unctrl, 0.5, 1.2])
    B = np.array([[0.0], [1.0], [1.0]])
    sol = dlqr(A, B, np.eye(3), np.eye(1))
    assert not bool(sol.converged)
    assert np.all(np.isfinite(sol.K)) and np.all(np.isfinite(sol.P))
    assert np.isfinite(sol.residual) and np.isfinite(sol.spectral_radius)
    assert float(sol.spectral_radius) >= 1.0


def test_paper_initial_hover_model_tiny_R():
    # the paper's initial model: A = I, B adds Δu into u_prev and du_prev; hover Q, R = dt·1e-6·I
    Q, R = tasks.cost_matrices(tasks.HOVER_WEIGHTS)
    A = np.eye(21)
    B = np.zeros((21, 4))
    B[0:4] = np.eye(4)
    B[4:8] = np.eye(4)
    for solver in (dlqr, dlqr_affine):
        sol = solver(A, B, Q, R)
        assert not bool(sol.converged)  # velocity, position, rate, attitude: eigenvalue 1, no path
        assert np.all(np.isfinite(sol.K)) and np.all(np.isfinite(sol.P))
        assert int(sol.iterations) <= 64
    # the controllable part is still solved: du_prev is driven to zero (x_du' = u), u_prev free
    K = np.asarray(dlqr(A, B, Q, R).K)
    np.testing.assert_allclose(K[:, 4:8], np.eye(4), atol=1e-6)
    # SPEC §4.4 fallback: the first gain of the finite-horizon LQR over the task horizon
    fallback = tvlqr(A, B, Q, R, Q_T=Q, T=400)
    assert np.all(np.isfinite(fallback.K)) and np.all(np.isfinite(fallback.P))


def test_true_hover_linearisation_matches_spec_and_scipy():
    A, B, Q, R = hover_problem()
    sol = dlqr_affine(A, B, Q, R)
    assert bool(sol.converged)
    np.testing.assert_allclose(sol.spectral_radius, 0.9751, atol=1e-4)  # SPEC §3 sanity figure
    K, P = scipy_lqr(A[:-1, :-1], B[:-1], Q[:-1, :-1], R)
    assert rel(sol.P[:-1, :-1], P) < 1e-8
    assert rel(sol.K[:, :-1], K) < 1e-8
    # at the trim the drift is zero, so no feedforward is needed
    np.testing.assert_allclose(sol.K[:, -1], 0.0, atol=1e-10)


def test_dlqr_affine_equals_long_horizon_tvlqr(rng):
    n, m = 5, 2
    F, G, _, R = random_system(rng, n=n, m=m, scale=1.2)
    c = rng.standard_normal(n)
    z_star = rng.standard_normal(n)
    W = np.diag(rng.uniform(0.5, 2.0, n))
    A = np.block([[F, c[:, None]], [np.zeros((1, n)), np.ones((1, 1))]])
    B = np.vstack([G, np.zeros((1, m))])
    # (z - z*)ᵀW(z - z*) written on x = [z; 1]: a cross term between z and the constant
    Wz = W @ z_star
    Q = np.block([[W, -Wz[:, None]], [-Wz[None], np.array([[z_star @ Wz]])]])
    sol = dlqr_affine(A, B, Q, R)
    assert bool(sol.converged) and sol.K.shape == (m, n + 1)
    assert np.max(np.abs(sol.K[:, -1])) > 0.1  # the feedforward is not trivially zero
    tv = tvlqr(A, B, Q, R, Q_T=Q, T=2000)
    np.testing.assert_allclose(tv.K[0], sol.K, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(tv.P[0][:-1, :], sol.P[:-1, :], rtol=1e-9, atol=1e-9)
    # the z block is plain dlqr on (F, G, W, R)
    np.testing.assert_allclose(sol.K[:, :-1], dlqr(F, G, W, R).K, rtol=1e-12)


def test_dlqr_affine_rejects_non_affine_layout():
    A = np.eye(3)
    A[2, 0] = 0.1
    with pytest.raises(ValueError, match="A's last row"):
        dlqr_affine(A, np.zeros((3, 1)), np.eye(3), np.eye(1))
    B = np.ones((3, 1))
    with pytest.raises(ValueError, match="B's last row"):
        dlqr_affine(np.eye(3), B, np.eye(3), np.eye(1))


# Benner, Laub & Mehrmann's DAREX collection (SPC 95_23, 1995), as in SciPy's
# linalg/tests/test_solvers.py: ill-conditioned A, singular R, eigenvalues near 1.
DAREX = {
    "gh-2251": (
        [
            [0.63399379, 0.54906824, 0.76253406],
            [0.5404729, 0.53745766, 0.08731853],
            [0.27524045, 0.84922129, 0.4681622],
        ],
        [[0.96861695], [0.05532739], [0.78934047]],
        np.eye(3),
        [[1.0]],
    ),
    "darex1": ([[4, 3], [-4.5, -3.5]], [[1], [-1]], [[9, 6], [6, 4]], [[1]]),
    "darex3-singular-R": ([[2, -1], [1, 0]], [[1], [0]], [[0, 0], [0, 1]], [[0]]),
    "darex5": ([[0, 1], [0, 0]], [[0], [1]], [[1, 2], [2, 4]], [[1]]),
    "darex8-near-unit": (
        [
            [-0.6, -2.2, -3.6, -5.400018],
            [1.0, 0.6, 0.8, 3.399982],
            [0.0, 1.0, 1.8, 3.799982],
            [0.0, 0.0, 0.0, -0.999982],
        ],
        [
            [1.0, -1.0, -1.0, -1.0],
            [0.0, 1.0, -1.0, -1.0],
            [0.0, 0.0, 1.0, -1.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
        [[2, 1, 3, 6], [1, 2, 2, 5], [3, 2, 6, 11], [6, 5, 11, 22]],
        np.eye(4),
    ),
    "darex10": (
        np.kron(np.eye(2), np.diag([1, 1], k=1)),
        np.kron(np.eye(2), [[0], [0], [1]]),
        [
            [1, 1, 0, 0, 0, 0],
            [1, 1, 0, 0, 0, 0],
            [0, 0, 0, 0, 0, 0],
            [0, 0, 0, 1, -1, 0],
            [0, 0, 0, -1, 1, 0],
            [0, 0, 0, 0, 0, 0],
        ],
        [[3, 0], [0, 1]],
    ),
    "darex12-1e6": ([[0, 1e6], [0, 0]], [[0], [1]], np.eye(2), [[1]]),
    "darex13-1e6": (
        np.array([[16, 10, -2], [10, 13, -8], [-2, -8, 7]]) / 9,
        np.eye(3),
        1e6 * np.eye(3),
        1e6 * np.eye(3),
    ),
    "darex14-1-1e-8": (
        [[1 - 1e-8, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]],
        [[1e-8], [0], [0], [0]],
        np.diag([0, 0, 0, 1]),
        [[0.25]],
    ),
    "darex15-shift-100": (np.eye(100, k=1), np.flipud(np.eye(100, 1)), np.eye(100), [[1]]),
}


@pytest.mark.parametrize("name", sorted(DAREX))
def test_darex_benchmarks(name):
    a, b, q, r = (np.asarray(x, dtype=np.float64) for x in DAREX[name])
    sol = dlqr(a, b, q, r)
    assert np.all(np.isfinite(sol.K)) and np.all(np.isfinite(sol.P))
    assert bool(sol.converged)
    assert float(sol.residual) < 1e-12
    P = sl.solve_discrete_are(a, b, q, r)
    assert rel(sol.P, P) < 1e-6


def test_input_checks_name_the_argument():
    A, B, Q, R = np.eye(3), np.ones((3, 1)), np.eye(3), np.eye(1)
    with pytest.raises(ValueError, match=r"A must be square.*\(3, 2\)"):
        dlqr(np.ones((3, 2)), B, Q, R)
    with pytest.raises(ValueError, match=r"B must have shape.*\(2, 1\)"):
        dlqr(A, np.ones((2, 1)), Q, R)
    with pytest.raises(ValueError, match=r"Q must have shape"):
        dlqr(A, B, np.eye(2), R)
    with pytest.raises(ValueError, match=r"Q must be symmetric"):
        dlqr(A, B, np.triu(np.ones((3, 3))), R)
    with pytest.raises(ValueError, match=r"R must be positive semidefinite.*-1"):
        dlqr(A, B, Q, -np.eye(1))
    with pytest.raises(ValueError, match=r"batch axes"):
        dlqr(np.stack([A, A]), np.stack([B, B, B]), Q, R)
    with pytest.raises(ValueError, match=r"A must be finite"):
        dlqr(np.full((3, 3), np.nan), B, Q, R)
    with pytest.raises(TypeError, match=r"R is required"):
        dlqr(A, B, Q, None)


@pytest.mark.slow
def test_dlqr_affine_and_tvlqr_inside_scan():
    # the loop's use: solvers called on traced models inside lax.scan (value checks skipped)
    A, B, Q, R = hover_problem()

    def body(carry, scale):
        Ai = jnp.asarray(A).at[:-1, :-1].multiply(scale)
        sol = dlqr_affine(Ai, B, Q, R)
        fallback = tvlqr(Ai, B, Q, R, Q_T=Q, T=50)
        return carry, (sol.K, sol.converged, fallback.K[0])

    _, (K, conv, K0) = jax.lax.scan(body, 0.0, jnp.array([1.0, 0.999]))
    K_ref, _ = scipy_lqr(A[:-1, :-1], B[:-1], Q[:-1, :-1], R)
    assert rel(K[0][:, :-1], K_ref) < 1e-8
    assert bool(jnp.all(conv)) and np.all(np.isfinite(K0))
