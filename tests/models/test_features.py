"""Feature models (issue 19): polynomial and random Fourier maps, fitted by the convex learners."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sklearn.linear_model import Ridge
from sklearn.preprocessing import PolynomialFeatures

from loopid.control import ilqr
from loopid.learners import ftrl_least_squares, ogd
from loopid.models import LinearOffsetModel, hover_nominal, polynomial, random_fourier
from loopid.models import linear_offset as lo
from loopid.models.feature_maps import DEFAULT_DEGREE
from loopid.models.feature_model import (
    dynamics,
    features,
    per_sample_loss,
    predict,
    residual_targets,
)

N, M = 5, 2  # Δx with its constant 1, Δu
K = N - 1 + M


def _rows(rng, b, n=N, m=M, scale=0.7):
    dx = scale * rng.normal(size=(b, n))
    dx[:, -1] = 1.0
    return dx, scale * rng.normal(size=(b, m))


def _nominal(rng, n=N, m=M):
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    A[-1] = 0.0
    A[-1, -1] = 1.0
    B = 0.1 * rng.normal(size=(n, m))
    B[-1] = 0.0
    return LinearOffsetModel(jnp.asarray(A), jnp.asarray(B))


def test_polynomial_features_are_sklearns_monomials_after_the_linear_terms(rng):
    """φ = [Δx; Δu; the degree-2..d columns of sklearn's PolynomialFeatures on v], same order."""
    dx, du = _rows(rng, 30)
    v = np.concatenate([dx[:, :-1], du], 1)
    for degree in (1, 2, 3, 4):
        fmap = polynomial(N, M, degree)
        phi = np.asarray(features(fmap, dx, du))
        oracle = PolynomialFeatures(degree, include_bias=False).fit_transform(v)[:, K:]
        expected = N + M + sum(math.comb(K + d - 1, d) for d in range(2, degree + 1))
        assert fmap.size == phi.shape[1] == expected
        np.testing.assert_array_equal(phi[:, : N + M], np.concatenate([dx, du], 1))
        np.testing.assert_allclose(phi[:, N + M :], oracle, rtol=1e-14, atol=1e-14)
    # leading axes broadcast: [2, 15, n] rows give [2, 15, F]
    fmap = polynomial(N, M, 3)
    stacked = np.asarray(fmap(dx.reshape(2, 15, N), du.reshape(2, 15, M)))
    np.testing.assert_array_equal(stacked.reshape(30, -1), np.asarray(fmap(dx, du)))


@pytest.mark.parametrize("degree", [DEFAULT_DEGREE, 3])
def test_feature_model_recovers_a_polynomial_system(rng, degree):
    """Noise-free data from Δx' = A*Δx + B*Δu + C*ψ(v) (random coefficients, constant kept 1):
    FTRL with a tiny λ over four masked batches recovers W* = [A*−A, B*−B, C*]ᵀ and predicts
    held-out rows to 1e-8."""
    model = _nominal(rng)
    fmap = polynomial(N, M, degree)
    W_true = 0.2 * rng.normal(size=(fmap.size, N))
    W_true[:, -1] = 0.0  # the constant coordinate has no residual

    def system(dx, du):
        return (
            np.asarray(lo.predict(model, np.zeros((N + M, N)), dx, du))
            + np.asarray(fmap(dx, du)) @ W_true
        )

    learner = ftrl_least_squares(1e-10)
    state = learner.init(fmap.size, N)
    for _ in range(4):
        dx, du = _rows(rng, 150)
        dx_next = system(dx, du)
        mask = rng.random(150) < 0.8
        dx_next[~mask] = np.nan  # masked rows may hold anything
        y = residual_targets(model, dx, du, dx_next)
        state = learner.update(state, features(fmap, dx, du), y, mask)
    W = np.asarray(learner.weights(state))
    np.testing.assert_allclose(W, W_true, atol=1e-6)
    dx, du = _rows(rng, 200)
    np.testing.assert_allclose(
        np.asarray(predict(model, fmap, W, dx, du)), system(dx, du), atol=1e-8
    )
    assert float(np.max(per_sample_loss(model, fmap, W, dx, du, system(dx, du)))) < 1e-15


def _nonlinear_data(rng, b):
    dx, du = _rows(rng, b)
    x = dx[:, :-1]
    nxt = np.column_stack(
        [np.sin(x[:, 0]) + du[:, 0] * x[:, 1], np.cos(x[:, 1] + du[:, 1]), x[:, 2] * x[:, 3]]
    )
    nxt = np.column_stack([nxt, np.tanh(x[:, 0]), np.ones(b)]) + 0.01 * rng.normal(size=(b, N))
    nxt[:, -1] = 1.0
    return dx, du, nxt


@pytest.mark.parametrize(
    "fmap",
    [polynomial(N, M, 3), random_fourier(N, M, 60, 0.8, seed=3)],
    ids=["poly3", "rff60"],
)
def test_ftrl_solution_is_the_closed_form_ridge_on_the_features(rng, fmap):
    """FTRL over three masked batches of a nonlinear system equals argmin ||Y − ΦW||² + λ√N||W||²
    on the kept rows: scikit-learn's Ridge(alpha=λ√N, fit_intercept=False) and a NumPy solve."""
    lam = 0.05
    model = hover_nominal(N, 2)
    learner = ftrl_least_squares(lam)
    state = learner.init(fmap.size, N)
    Phi, Y = [], []
    for b in (80, 50, 120):
        dx, du, dx_next = _nonlinear_data(rng, b)
        mask = rng.random(b) < 0.7
        phi = np.asarray(features(fmap, dx, du))
        y = np.asarray(residual_targets(model, dx, du, dx_next))
        state = learner.update(state, np.where(mask[:, None], phi, np.nan), y, mask)
        Phi.append(phi[mask])
        Y.append(y[mask])
    Phi, Y = np.concatenate(Phi), np.concatenate(Y)
    alpha = lam * math.sqrt(len(Phi))
    W = np.asarray(learner.weights(state))
    W_np = np.linalg.solve(Phi.T @ Phi + alpha * np.eye(fmap.size), Phi.T @ Y)
    W_sk = Ridge(alpha=alpha, fit_intercept=False, solver="cholesky").fit(Phi, Y).coef_.T
    np.testing.assert_allclose(W, W_np, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(W, W_sk, rtol=1e-7, atol=1e-9)


def test_ogd_learns_the_features_unchanged(rng):
    """The existing OGD learner takes φ rows as they are; its held-out loss falls far below the
    nominal's."""
    fmap = polynomial(N, M, 2)
    model = hover_nominal(N, 2)
    learner = ogd(step_size=0.3)
    state = learner.init(fmap.size, N)
    for _ in range(60):
        dx, du, dx_next = _nonlinear_data(rng, 64)
        y = residual_targets(model, dx, du, dx_next)
        state = learner.update(state, features(fmap, dx, du), y)
    dx, du, dx_next = _nonlinear_data(rng, 500)
    before = float(np.mean(per_sample_loss(model, fmap, np.zeros((fmap.size, N)), dx, du, dx_next)))
    after = float(np.mean(per_sample_loss(model, fmap, learner.weights(state), dx, du, dx_next)))
    assert after < 0.1 * before


def test_degree_one_is_the_linear_offset_model(rng):
    """polynomial(n, m, 1) is z = [Δx; Δu]: features, predictions and losses equal linear_offset's
    bit for bit, time-invariant and time-varying nominal alike."""
    fmap = polynomial(N, M, 1)
    dx, du = _rows(rng, 40)
    dx_next = rng.normal(size=(40, N))
    W = rng.normal(size=(N + M, N))
    np.testing.assert_array_equal(np.asarray(fmap(dx, du)), np.asarray(lo.features(dx, du)))
    tv = lo.time_varying_nominal(_nominal(rng).A, _nominal(rng).B, rng.normal(size=(7, N)))
    t = rng.integers(0, 7, size=40).astype(np.int32)
    for model, tt in ((_nominal(rng), None), (tv, t)):
        np.testing.assert_array_equal(
            np.asarray(predict(model, fmap, W, dx, du, tt)),
            np.asarray(lo.predict(model, W, dx, du, tt)),
        )
        np.testing.assert_array_equal(
            np.asarray(per_sample_loss(model, fmap, W, dx, du, dx_next, tt)),
            np.asarray(lo.per_sample_loss(model, W, dx, du, dx_next, tt)),
        )


def test_random_fourier_features_approximate_the_gaussian_kernel(rng):
    """ψ(v)ᵀψ(v') → exp(−||(v − v')/σ||²/2) (per-input σ): with 20,000 features the error of each
    entry is O(1/√count) ≈ 0.007, checked at 0.03; ψ(v)ᵀψ(v) ≈ 1."""
    count = 20_000
    sigma = np.array([0.5, 1.0, 2.0, 0.7, 1.5, 3.0])
    fmap = random_fourier(N, M, count, sigma, seed=1)
    assert fmap.size == N + M + count
    dx, du = _rows(rng, 12, scale=0.6)
    psi = np.asarray(fmap(dx, du))[:, N + M :]
    v = np.concatenate([dx[:, :-1], du], 1) / sigma
    kernel = np.exp(-0.5 * np.sum((v[:, None] - v[None]) ** 2, -1))
    assert kernel.min() < 0.5 < kernel[~np.eye(12, dtype=bool)].max()  # a spread of values
    np.testing.assert_allclose(psi @ psi.T, kernel, atol=0.03)
    # a different seed is a different draw; the same seed the same one
    same = np.asarray(random_fourier(N, M, 50, 1.0, seed=4)(dx, du))
    np.testing.assert_array_equal(same, np.asarray(random_fourier(N, M, 50, 1.0, seed=4)(dx, du)))
    other = np.asarray(random_fourier(N, M, 50, 1.0, seed=5)(dx, du))
    assert not np.allclose(same, other)


@pytest.mark.parametrize(
    "fmap", [polynomial(N, M, 3), random_fourier(N, M, 30, 1.0)], ids=["poly3", "rff30"]
)
def test_dynamics_jacobian_matches_finite_differences_and_keeps_the_constant(rng, fmap):
    """jax.jacfwd of the planner's f(Δx, Δu, t) equals central differences (time-varying nominal,
    traced t); f equals predict row by row apart from the last entry, which is exactly 1 even
    when W's last column is not zero, along a 30-step rollout too."""
    base = _nominal(rng)
    model = lo.time_varying_nominal(base.A, base.B, 0.1 * rng.normal(size=(6, N)))
    W = 0.1 * rng.normal(size=(fmap.size, N))  # last column nonzero on purpose
    f = jax.jit(dynamics(model, fmap, W))
    dx, du = _rows(rng, 1)
    dx, du, t = dx[0], du[0], jnp.int32(4)
    Jx, Ju = jax.jacfwd(f, argnums=(0, 1))(dx, du, t)
    h = 1e-6
    fd_x = np.stack([(f(dx + h * e, du, t) - f(dx - h * e, du, t)) / (2 * h) for e in np.eye(N)], 1)
    fd_u = np.stack([(f(dx, du + h * e, t) - f(dx, du - h * e, t)) / (2 * h) for e in np.eye(M)], 1)
    np.testing.assert_allclose(np.asarray(Jx), fd_x, atol=1e-7)
    np.testing.assert_allclose(np.asarray(Ju), fd_u, atol=1e-7)
    assert np.all(np.asarray(Jx)[-1] == 0) and np.all(np.asarray(Ju)[-1] == 0)
    rows = predict(model, fmap, W, dx[None], du[None], np.array([4], np.int32))[0]
    out = f(dx, du, t)
    np.testing.assert_allclose(np.asarray(out[:-1]), np.asarray(rows[:-1]), rtol=1e-13)
    assert float(out[-1]) == 1.0 and float(rows[-1]) != 1.0

    def step(x, t):
        x = f(x, 0.1 * jnp.ones(M), t)
        return x, x[-1]

    _, last = jax.lax.scan(step, jnp.asarray(dx), jnp.arange(30) % 6)
    assert np.all(np.asarray(last) == 1.0)


def _varying(rng, steps, n=N, m=M, decay=1.0):
    """A time-varying nominal whose every A_t, B_t differs (constant row kept e_n); ``decay``
    scales A_t's state block (< 1: a stable open loop)."""
    models = [_nominal(rng, n, m) for _ in range(steps)]
    A = jnp.stack([a.A for a in models]).at[:, :-1, :-1].multiply(decay)
    return LinearOffsetModel(A, jnp.stack([a.B for a in models]))


def _plain(model, fmap, W):
    """The planner's f written out, without the analytic derivative: autodiff's reference."""
    A, B = (jnp.asarray(a) for a in model)
    W = jnp.asarray(W)

    def f(dx, du, t=0):
        At, Bt = (A[t], B[t]) if model.time_varying else (A, B)
        return (At @ dx + Bt @ du + fmap.fn(dx, du) @ W).at[-1].set(1.0)

    return f


@pytest.mark.parametrize("degree", [2, 3])
@pytest.mark.parametrize("time_varying", [False, True], ids=["invariant", "varying"])
def test_analytic_jacobian_equals_autodiff_and_finite_differences(rng, degree, time_varying):
    """Polynomial maps carry an analytic derivative (random Fourier maps do not). Through it,
    jax.jacfwd and jax.jacrev of dynamics' f equal jax.jacfwd of the plain expression to 1e-12
    and central differences to 1e-7 at random W, Δx, Δu and traced t; f's values equal the plain
    expression's bit for bit; the derivatives w.r.t. W and the second derivatives agree too."""
    fmap = polynomial(N, M, degree)
    assert fmap.jacobian is not None and random_fourier(N, M, 10).jacobian is None
    model = _varying(rng, 6) if time_varying else _nominal(rng)
    W = jnp.asarray(rng.normal(size=(fmap.size, N)))
    f, g = dynamics(model, fmap, W), _plain(model, fmap, W)

    @jax.jit
    def derivatives(dx, du, t):
        """Per f: jacfwd, jacrev (each ∂/∂Δx, ∂/∂Δu), ∂/∂W, the Hessian of f₀ in Δx."""

        def of(make):
            h = make(model, fmap, W)
            by_W = jax.jacfwd(lambda W: make(model, fmap, W)(dx, du, t))(W)
            hess = jax.hessian(lambda x: h(x, du, t)[0])(dx)
            fwd, rev = (jac(h, argnums=(0, 1))(dx, du, t) for jac in (jax.jacfwd, jax.jacrev))
            return (*fwd, *rev, by_W, hess)

        return of(dynamics), of(_plain)

    h = 1e-6
    fd = jax.jit(
        lambda x, u, t, e, d: (f(x + h * e, u + h * d, t) - f(x - h * e, u - h * d, t)) / (2 * h)
    )
    for dx, du in zip(*_rows(rng, 2, scale=1.5), strict=True):
        t = jnp.int32(rng.integers(6))
        np.testing.assert_array_equal(
            np.asarray(jax.jit(f)(dx, du, t)), np.asarray(jax.jit(g)(dx, du, t))
        )
        ours, plain = derivatives(dx, du, t)
        # each against the plain expression's, our jacrev against its jacfwd as well
        for a, b in zip(ours + ours[2:4], plain + plain[:2], strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)
        fd_x = [fd(dx, du, t, e, np.zeros(M)) for e in np.eye(N)]
        fd_u = [fd(dx, du, t, np.zeros(N), e) for e in np.eye(M)]
        np.testing.assert_allclose(np.asarray(ours[0]), np.stack(fd_x, 1), atol=1e-7)
        np.testing.assert_allclose(np.asarray(ours[1]), np.stack(fd_u, 1), atol=1e-7)


def test_ilqr_plan_on_the_feature_model_is_unchanged_by_the_analytic_jacobian(rng):
    """iLQR on dynamics(model, fmap, W) (analytic Jacobians) and on the plain expression
    (autodiff) runs the same iterations to the same plan and gains, to 1e-9."""
    T = 25
    fmap = polynomial(N, M, 2)
    model = _varying(rng, T, decay=0.8)
    W = 0.05 * rng.normal(size=(fmap.size, N))
    W[:, -1] = 0.0

    def cost(x, u, t):
        return x[:-1] @ x[:-1] + 0.1 * (u @ u)

    x0 = jnp.asarray(np.append(0.5 * rng.normal(size=N - 1), 1.0))
    U0 = jnp.zeros((T, M))
    a, b = (ilqr(make(model, fmap, W), cost, x0, U0, max_iter=30) for make in (dynamics, _plain))
    assert int(a.iterations) == int(b.iterations) > 1 and bool(a.converged)
    for x, y in ((a.X, b.X), (a.U, b.U), (a.K, b.K), (a.cost, b.cost)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(
    ("make", "word"),
    [
        (lambda: polynomial(N, M, 0), "degree"),
        (lambda: polynomial(N, M, 2.0), "degree"),
        (lambda: polynomial(21, 4, 6), "degree=6 gives"),
        (lambda: polynomial(0, M, 2), "n"),
        (lambda: polynomial(N, -1, 2), "m"),
        (lambda: random_fourier(N, M, 0), "count"),
        (lambda: random_fourier(N, M, 10, 0.0), "bandwidth"),
        (lambda: random_fourier(N, M, 10, -1.0), "bandwidth"),
        (lambda: random_fourier(N, M, 10, np.inf), "bandwidth"),
        (lambda: random_fourier(N, M, 10, np.ones(K + 1)), "bandwidth"),
        (lambda: random_fourier(N, M, 10, 1.0, seed=1.5), "seed"),
    ],
)
def test_bad_settings_raise_one_line(make, word):
    with pytest.raises(ValueError, match=word) as info:
        make()
    assert "\n" not in str(info.value)


def test_shape_mismatches_name_the_argument(rng):
    fmap = polynomial(N, M, 2)
    model = _nominal(rng)
    dx, du = _rows(rng, 4)
    with pytest.raises(ValueError, match="W must have shape"):
        predict(model, fmap, np.zeros((N + M, N)), dx, du)
    with pytest.raises(ValueError, match="feature map is for"):
        predict(_nominal(rng, N + 1), fmap, np.zeros((fmap.size, N)), dx, du)
    with pytest.raises(ValueError, match="du must have shape"):
        fmap(dx, du[:, :1])
