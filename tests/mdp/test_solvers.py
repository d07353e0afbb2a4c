"""Value iteration, policy iteration, exact evaluation and D_{μ,π} against independent oracles."""

import functools

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
