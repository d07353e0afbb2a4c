"""spectral_radius: Gelfand's squaring against exact radii and NumPy's eigenvalues, the backend's
choice, and the LQR's stability check on the accelerator's path."""

import jax
import numpy as np
import pytest

from loopid.control import dlqr_affine
from loopid.control.spectral import spectral_radius
from loopid.systems import helicopter
from loopid.systems.helicopter import tasks


def similar(rng, lam, kappa):
    """V diag(λ) V⁻¹ with cond(V) = kappa: [n, n]."""
    n = len(lam)
    U, _, Wt = np.linalg.svd(rng.standard_normal((n, n)))
    V = U @ np.diag(np.logspace(0, -np.log10(kappa), n)) @ Wt
    return V @ np.diag(lam) @ np.linalg.inv(V)


def squared(M):
    return np.asarray(spectral_radius(M, method="squaring"))


@pytest.mark.parametrize("n", [2, 5, 21, 40])
@pytest.mark.parametrize("scale", [1e-5, 1.0, 1e3])
def test_squaring_matches_numpy_on_random_matrices(n, scale):
    M = np.random.default_rng(n).standard_normal((30, n, n)) * scale / np.sqrt(n)
    ref = np.max(np.abs(np.linalg.eigvals(M)), axis=-1)
    np.testing.assert_allclose(squared(M), ref, rtol=1e-12)


def test_squaring_is_exact_to_rounding_on_known_radii():
    rng = np.random.default_rng(0)
    lam = rng.uniform(-0.97, 0.97, 21)
    lam[3] = 0.99  # the largest modulus, on a mode mixed in by V
    np.testing.assert_allclose(squared(similar(rng, lam, 1e2)), 0.99, rtol=1e-13)
    # a complex dominant pair of modulus 0.99 (the squares rotate instead of converging)
    th = 0.7
    M = 0.1 * rng.standard_normal((8, 8))
    M[:2, :2] = 0.99 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    M[2:, :2] = 0.0
    np.testing.assert_allclose(squared(M), np.max(np.abs(np.linalg.eigvals(M))), rtol=1e-13)
    assert squared(np.array([[0.0, -1.0], [1.0, 0.0]])) == 1.0  # a rotation: ρ = 1 exactly
    np.testing.assert_allclose(squared(np.diag([-3.0, 2.0, 1e-3])), 3.0, rtol=1e-15)


@pytest.mark.parametrize("n", [5, 21])
def test_squaring_error_grows_as_the_documented_bound(n):
    """The module docstring's accuracy: rounding error at most about κ(V)² n ε (checked with
    a factor 10, four draws per κ), more than geev's about κ(V) ε once κ is large."""
    eps = np.finfo(float).eps
    for kappa in (1e2, 1e3, 1e4, 1e5):
        errors, geev = [], []
        for seed in range(4):
            rng = np.random.default_rng(seed)
            lam = rng.uniform(-0.97, 0.97, n)
            M = similar(rng, lam, kappa)
            exact = np.max(np.abs(lam))
            errors.append(abs(squared(M) - exact) / exact)
            geev.append(abs(np.max(np.abs(np.linalg.eigvals(M))) - exact) / exact)
        assert max(errors) <= 10 * kappa**2 * n * eps, (kappa, max(errors))
    assert max(errors) > max(geev)  # at κ = 1e5 squaring loses more digits than geev


def test_degenerate_matrices():
    assert np.all(squared(np.zeros((2, 3, 3))) == 0.0)
    assert squared(np.array([[0.0, 1.0], [0.0, 0.0]])) == 0.0  # nilpotent
    assert np.isnan(squared(np.array([[np.nan, 1.0], [0.0, 0.0]])))
    assert np.isnan(squared(np.array([[np.inf, 1.0], [0.0, 0.0]])))
    assert squared(np.array([[0, 1], [2, 0]])) == pytest.approx(np.sqrt(2), rel=1e-15)  # integers
    assert squared(np.diag([1e300, 1.0])) == 1e300  # no rounding of log ‖M‖


def test_batches_jit_and_vmap():
    M = np.random.default_rng(2).standard_normal((2, 3, 6, 6))
    one = np.array([[squared(m) for m in row] for row in M])
    np.testing.assert_array_equal(squared(M), one)
    f = jax.jit(jax.vmap(lambda m: spectral_radius(m, method="squaring")))
    np.testing.assert_array_equal(f(M.reshape(6, 6, 6)), one.reshape(6))


def test_backend_picks_the_method(monkeypatch):
    M = np.random.default_rng(3).standard_normal((4, 9, 9))
    eig = np.asarray(spectral_radius(M, method="eigenvalues"))
    np.testing.assert_array_equal(eig, np.max(np.abs(np.asarray(jax.numpy.linalg.eigvals(M))), -1))
    here = eig if jax.default_backend() == "cpu" else squared(M)
    np.testing.assert_array_equal(np.asarray(spectral_radius(M)), here)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    np.testing.assert_array_equal(np.asarray(spectral_radius(M)), squared(M))


def test_bad_input():
    with pytest.raises(ValueError, match="'qr'"):
        spectral_radius(np.eye(3), method="qr")
    with pytest.raises(ValueError, match=r"\(3, 2\)"):
        spectral_radius(np.ones((3, 2)))


def on_both_paths(monkeypatch, solve):
    """``(solve() traced for this CPU, solve() traced as for a GPU)``: the second with
    ``jax.default_backend`` patched, between cleared caches so that no program traced for the
    GPU's path stays in this process."""
    cpu = solve()
    jax.clear_caches()
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    try:
        return cpu, solve()
    finally:
        jax.clear_caches()
        monkeypatch.undo()


def test_lqr_on_the_accelerators_path_gives_the_same_solution(monkeypatch):
    """dlqr_affine traced as for a GPU: the same gains bit for bit (the radius is not used to
    compute them), the radius within 1e-13 of the eigenvalues', the same stability verdicts."""
    x_star = helicopter.hover_target()
    A, B = (np.asarray(a) for a in helicopter.linearize(x_star, x_star))
    Q, R = (np.asarray(a) for a in tasks.cost_matrices(tasks.HOVER_WEIGHTS))
    rng = np.random.default_rng(4)
    As = A + 1e-3 * rng.standard_normal((6, *A.shape))
    As[:, -1] = A[-1]  # the constant coordinate stays constant
    As[0, :-1, :-1] = np.eye(A.shape[0] - 1)  # an integrator model: the LQR does not converge
    cpu, gpu = on_both_paths(monkeypatch, lambda: dlqr_affine(As, B, Q, R))
    np.testing.assert_array_equal(gpu.K, cpu.K)
    np.testing.assert_array_equal(gpu.converged, cpu.converged)
    assert np.any(cpu.converged) and not np.all(cpu.converged)
    ok = np.isfinite(cpu.spectral_radius)
    np.testing.assert_allclose(gpu.spectral_radius[ok], cpu.spectral_radius[ok], rtol=1e-13)


def test_the_stability_verdict_on_the_accelerators_path(monkeypatch):
    """A mode the input cannot reach and the cost does not see: the doubling meets its
    tolerance and the residual is tiny, so only ρ(A − BK) = 1.2 ≥ 1 makes ``converged`` False;
    the accelerator's path reads the same verdict and radius."""
    from loopid.control import dlqr

    A = np.diag([1.2, 0.5])
    B = np.array([[0.0], [1.0]])
    Q = np.diag([0.0, 1.0])
    R = np.eye(1)
    cpu, gpu = on_both_paths(monkeypatch, lambda: dlqr(A, B, Q, R))
    for sol in (cpu, gpu):
        assert sol.residual <= 1e-8 and not sol.converged
        assert float(sol.spectral_radius) == pytest.approx(1.2, rel=1e-14)
