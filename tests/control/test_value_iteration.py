"""Value iteration, policy iteration, exact evaluation and D_{μ,π} against independent oracles."""

import functools
import importlib

import jax
import numpy as np
import pytest

from loopid.control.value_iteration import (
    evaluate,
    greedy,
    occupancy,
    policy_iteration,
    value_iteration,
)
from loopid.systems.mdp import gridworld, random_mdp, trap_mdp

vi_module = importlib.import_module("loopid.control.value_iteration")


@functools.cache
def _cases():
    """A batch of 4 random MDPs (batched solvers), a slippery gridworld with holes, the trap."""
    batch = random_mdp(jax.random.split(jax.random.key(3), 4), 12, 3, gamma=0.95)
    grid = gridworld(4, 5, slip=0.3, gamma=0.97, holes=((1, 1), (2, 3)))
    return batch, grid, trap_mdp(gamma=0.9)


@pytest.mark.parametrize("case", range(3))
def test_value_iteration_equals_policy_iteration_and_linear_solve(case):
    m = _cases()[case]
    vi = value_iteration(m.P, m.C, m.gamma, tol=1e-12)
    pi = policy_iteration(m.P, m.C, m.gamma)
    assert np.all(vi.converged) and np.all(pi.converged)
    np.testing.assert_allclose(vi.V, pi.V, atol=1e-10, rtol=0)
    # the greedy policy of VI, evaluated exactly, is optimal too
    np.testing.assert_allclose(evaluate(m.P, m.C, m.gamma, vi.policy), pi.V, atol=1e-10, rtol=0)
    # Bellman optimality of PI's values (NumPy): V = min_a C + γ P V
    g = np.asarray(m.gamma)[..., None, None]
    Q = np.asarray(m.C) + g * np.einsum("...sat,...t->...sa", m.P, pi.V)
    np.testing.assert_allclose(Q.min(axis=-1), pi.V, atol=1e-10, rtol=0)


def test_evaluate_matches_numpy_solve_for_stochastic_policy(rng):
    m = jax.tree_util.tree_map(lambda a: a[0], _cases()[0])
    S, A = m.n_states, m.n_actions
    pi = rng.dirichlet(np.ones(A), size=S)
    P_pi = np.einsum("sa,sat->st", pi, m.P)
    V = np.linalg.solve(np.eye(S) - 0.95 * P_pi, (pi * np.asarray(m.C)).sum(1))
    np.testing.assert_allclose(evaluate(m.P, m.C, m.gamma, pi), V, atol=1e-11, rtol=0)


def test_batched_value_iteration_equals_one_by_one():
    batch = _cases()[0]
    vi = value_iteration(batch.P, batch.C, batch.gamma)
    assert vi.V.shape == (4, 12) and vi.policy.shape == (4, 12, 3)
    for i in (0, 3):
        one = value_iteration(batch.P[i], batch.C[i], batch.gamma[i])
        np.testing.assert_allclose(vi.V[i], one.V, atol=1e-10, rtol=0)


def test_tolerance_is_guaranteed_and_cap_reports_not_converged():
    m = _cases()[1]._replace(gamma=np.float64(0.99))
    exact = policy_iteration(m.P, m.C, m.gamma).V
    loose = value_iteration(m.P, m.C, m.gamma, tol=1e-3)
    assert bool(loose.converged)
    err = np.abs(np.asarray(loose.V) - np.asarray(exact)).max()
    assert 0 < err <= 1e-3
    capped = value_iteration(m.P, m.C, m.gamma, max_iter=5)
    assert not bool(capped.converged) and int(capped.iterations) == 5


def _numpy_optimal_values(P, C, gamma):
    """V* of one MDP by Howard's policy iteration in plain NumPy (an oracle independent of the
    module): exact evaluation by ``np.linalg.solve``, improvement on a strict gain only."""
    S = C.shape[0]
    policy = C.argmin(axis=1)
    while True:
        rows = np.arange(S)
        V = np.linalg.solve(np.eye(S) - gamma * P[rows, policy], C[rows, policy])
        Q = C + gamma * P @ V
        better = Q.min(axis=1) < Q[rows, policy] - 1e-12
        if not better.any():
            return V
        policy = np.where(better, Q.argmin(axis=1), policy)


def _mixed_batch(n):
    """``n`` random MDPs (S = 30, A = 4) with discounts 0.6..0.97, so their value iterations
    meet the stopping rule at very different counts."""
    m = random_mdp(jax.random.split(jax.random.key(11), n), 30, 4, gamma=0.9)
    return m._replace(gamma=np.linspace(0.6, 0.97, n))


@pytest.mark.parametrize(
    ("n", "cache_mdps", "chunking"),
    [(7, 1000, (7, 7)), (6, 1, (1, 6)), (6, 3, (3, 6)), (7, 3, (3, 9))],
    ids=["whole-batch", "one-at-a-time", "divisor", "padded"],
)
def test_value_iteration_against_numpy_oracle_whole_batch_and_chunked(
    monkeypatch, n, cache_mdps, chunking
):
    """Every chunking (whole batch, one MDP at a time, a divisor of n, n padded) returns the
    whole-batch loop's K-th iterate, and it is within tol of V* from an independent NumPy policy
    iteration; its greedy policy is optimal and its Bellman residual is within (1 − γ) tol."""
    m = _mixed_batch(n)
    tol = 1e-9
    reference = value_iteration(m.P, m.C, m.gamma, tol=tol)  # whole batch: P fits the cache
    mdp_bytes = 8 * 30 * 4 * 30
    monkeypatch.setattr(vi_module, "_CACHE_BYTES", cache_mdps * mdp_bytes)
    assert vi_module._chunking(n, mdp_bytes) == chunking
    vi = value_iteration(m.P, m.C, m.gamma, tol=tol)
    assert int(vi.iterations) == int(reference.iterations)
    np.testing.assert_allclose(vi.V, reference.V, atol=1e-12, rtol=0)
    np.testing.assert_allclose(vi.residual, reference.residual, atol=1e-12, rtol=0)
    np.testing.assert_array_equal(vi.converged, reference.converged)
    assert np.all(vi.converged)
    gammas = np.asarray(m.gamma)
    # the count is the first at which every MDP meets γδ/(1−γ) ≤ tol: one MDP was not met at K−1
    early = value_iteration(m.P, m.C, m.gamma, tol=tol, max_iter=int(vi.iterations) - 1)
    assert not np.all(early.converged)
    np.testing.assert_array_less(gammas * np.asarray(vi.residual) / (1 - gammas), tol)
    P, C = np.asarray(m.P), np.asarray(m.C)
    for i in range(n):
        V_star = _numpy_optimal_values(P[i], C[i], gammas[i])
        V = np.asarray(vi.V[i])
        assert np.abs(V - V_star).max() <= tol
        bellman = (C[i] + gammas[i] * P[i] @ V).min(axis=1) - V
        assert np.abs(bellman).max() <= (1 - gammas[i]) * tol + 1e-13
        # the returned greedy policy, evaluated exactly, is optimal
        pi = np.asarray(vi.policy[i]).argmax(axis=1)
        rows = np.arange(30)
        V_pi = np.linalg.solve(np.eye(30) - gammas[i] * P[i][rows, pi], C[i][rows, pi])
        np.testing.assert_allclose(V_pi, V_star, atol=1e-10, rtol=0)
    capped = value_iteration(m.P, m.C, m.gamma, tol=tol, max_iter=5)
    capped_reference = vi_module._value_iteration(
        m.P, m.C, jax.numpy.asarray(m.gamma), jax.numpy.zeros((n, 30)), tol, 5
    )
    assert int(capped.iterations) == 5 and not np.any(capped.converged)
    np.testing.assert_allclose(capped.V, capped_reference.V, atol=1e-12, rtol=0)


def test_occupancy_is_the_discounted_series():
    m = jax.tree_util.tree_map(lambda a: a[1], _cases()[0])
    pi = np.asarray(greedy(m.C))
    D = np.asarray(occupancy(m.P, m.mu, m.gamma, pi))
    P_pi = np.einsum("sa,sat->st", pi, m.P)
    d, x = np.zeros(m.n_states), np.asarray(m.mu)
    for t in range(2000):
        d += 0.05 * 0.95**t * x
        x = x @ P_pi
    np.testing.assert_allclose(D.sum(1), d, atol=1e-12)
    assert abs(D.sum() - 1) < 1e-12
    # J = E_D[C] / (1 − γ)
    J = float(np.asarray(m.mu) @ np.asarray(evaluate(m.P, m.C, m.gamma, pi)))
    assert abs(J - (D * np.asarray(m.C)).sum() / 0.05) < 1e-10


def test_bad_inputs_raise_value_error():
    m = _cases()[1]
    with pytest.raises(ValueError, match="P must have shape"):
        value_iteration(m.P[:, :, :-1], m.C, m.gamma)
    with pytest.raises(ValueError, match="C must have shape"):
        value_iteration(m.P, m.C[:, :1], m.gamma)
    with pytest.raises(ValueError, match="tol"):
        value_iteration(m.P, m.C, m.gamma, tol=0.0)
    with pytest.raises(ValueError, match="pi must have shape"):
        evaluate(m.P, m.C, m.gamma, np.ones((3, 3)))
