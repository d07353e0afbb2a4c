"""Finite-MDP constructors: structure, closed-form values, validation."""

import jax
import numpy as np
import pytest

from loopid.control.value_iteration import evaluate, policy_iteration
from loopid.systems.mdp import TRAP_JUMP, TRAP_WALK, gridworld, make_mdp, random_mdp, trap_mdp


def test_random_mdp_rows_and_batch():
    m = random_mdp(jax.random.split(jax.random.key(0), 3), 12, 3, gamma=0.95)
    assert m.P.shape == (3, 12, 3, 12) and m.C.shape == (3, 12, 3) and m.gamma.shape == (3,)
    np.testing.assert_allclose(np.asarray(m.P).sum(-1), 1.0, atol=1e-12)
    assert (np.asarray(m.C) >= 0).all() and (np.asarray(m.C) <= 1).all()
    # different keys give different MDPs
    assert not np.allclose(m.P[0], m.P[1])


def test_deterministic_gridworld_value_is_discounted_distance():
    g = gridworld(3, 4, slip=0.0, gamma=0.9, step_cost=0.1)
    V = np.asarray(policy_iteration(g.P, g.C, g.gamma).V)
    for r in range(3):
        for c in range(4):
            k = (2 - r) + (3 - c)
            assert abs(V[r * 4 + c] - 0.1 * (1 - 0.9**k) / 0.1) < 1e-10


def test_slippery_gridworld_moves():
    g = gridworld(3, 3, slip=0.2)
    P = np.asarray(g.P)
    # from the centre (4), "N" (0): up with 0.8, left/right 0.1 each
    assert P[4, 0, 1] == pytest.approx(0.8) and P[4, 0, 3] == pytest.approx(0.1)
    assert P[4, 0, 5] == pytest.approx(0.1)
    assert P[8, :, 8].min() == 1.0  # goal absorbing


def test_trap_values_closed_form():
    m = trap_mdp(length=4, slip=0.25, gamma=0.9, walk_cost=0.5)
    opt = policy_iteration(m.P, m.C, m.gamma)
    assert (np.asarray(opt.policy)[:4, TRAP_WALK] == 1).all()
    V = 0.0  # walking: V(k) = (c + γ(1−slip)V(k+1)) / (1 − γ slip), V(goal) = 0
    for _ in range(4):
        V = (0.5 + 0.9 * 0.75 * V) / (1 - 0.9 * 0.25)
    assert abs(float(opt.V[0]) - V) < 1e-10
    jump = np.zeros((m.n_states, 2))
    jump[:, TRAP_JUMP] = 1
    J_jump = float(m.mu @ evaluate(m.P, m.C, m.gamma, jump))
    assert abs(J_jump - 0.9**2 / 0.1) < 1e-10


def test_make_mdp_validates():
    P = np.full((2, 1, 2), 0.5)
    C = np.zeros((2, 1))
    with pytest.raises(ValueError, match="P rows"):
        make_mdp(P * 2, C, 0.9, [1, 0])
    with pytest.raises(ValueError, match="gamma"):
        make_mdp(P, C, 1.0, [1, 0])
    with pytest.raises(ValueError, match="mu"):
        make_mdp(P, C, 0.9, [1, 1])
    with pytest.raises(ValueError, match="within"):
        make_mdp(P, C + 2, 0.9, [1, 0], 0.0, 1.0)
    with pytest.raises(ValueError, match="outside"):
        gridworld(3, 3, holes=((5, 5),))
