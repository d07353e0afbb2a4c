"""The policy-gradient baseline's parts (:mod:`loopid.algorithms.policy_gradient`) on problems
whose answer is known: the footnote's linear system recovers the gradient of a quadratic
exactly (and ignores the empty rows of the probe memory), and the budget never spends more than
m transitions. Its runs on the helicopter's panels are tested in
``tests/experiments/test_policy_gradient_helicopter.py``, its ``rollouts`` reading in
``test_policy_gradient_rollouts.py``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.policy_gradient_step import budget, fd_gradient


def test_fd_gradient_is_exact_on_a_quadratic():
    """Antithetic differences of a quadratic are exactly ⟨∇c, δ⟩: with P ≥ d probes the linear
    system returns the autodiff gradient, with P < d its projection on the probed directions."""
    rng = np.random.default_rng(0)
    d = 6
    A = rng.normal(size=(d, d))
    H = A @ A.T + np.eye(d)
    b = rng.normal(size=d)

    def c(x):
        return 0.5 * x @ H @ x + b @ x + 3.0

    theta = jnp.asarray(rng.normal(size=d))
    exact = jax.grad(c)(theta)
    for P in (d, 2 * d):
        delta = jnp.asarray(rng.normal(size=(P, d)))
        half = jax.vmap(lambda dl: (c(theta + dl) - c(theta - dl)) / 2.0)(delta)
        np.testing.assert_allclose(fd_gradient(delta, half), exact, rtol=1e-9, atol=1e-9)
    delta = jnp.asarray(rng.normal(size=(2, d)))
    half = jax.vmap(lambda dl: (c(theta + dl) - c(theta - dl)) / 2.0)(delta)
    D = np.asarray(delta)
    projection = D.T @ np.linalg.solve(D @ D.T, D @ np.asarray(exact))
    np.testing.assert_allclose(fd_gradient(delta, half), projection, rtol=1e-9, atol=1e-9)


def test_fd_gradient_ignores_empty_memory_rows():
    """Zero rows (empty memory slots) leave the minimum-norm solution unchanged."""
    rng = np.random.default_rng(1)
    D = jnp.asarray(rng.normal(size=(3, 2, 5)))
    y = jnp.asarray(rng.normal(size=3))
    padded = jnp.concatenate([D, jnp.zeros((7, 2, 5))])
    np.testing.assert_allclose(
        fd_gradient(padded, jnp.concatenate([y, jnp.zeros(7)])), fd_gradient(D, y), atol=1e-12
    )


def test_budget_never_exceeds_m():
    for m in (4, 7, 100, 101, 500, 999):
        for horizon in (1, 25, 125, 400, 600):
            H, P = budget(m, horizon, 400)
            assert 1 <= H <= min(horizon, 400) and P >= 2
            assert (P + 2) * H <= m
    assert budget(500, 600, 400) == (125, 2)
    assert budget(100, 600, 400) == (25, 2)
    with pytest.raises(ValueError, match="samples >= 4"):
        budget(3, 400, 400)
