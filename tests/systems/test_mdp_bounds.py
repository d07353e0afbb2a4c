"""The finite-MDP bounds (:mod:`loopid.systems.mdp_bounds`): Lemma 3.1, the simulation lemma,
c_ν, and Theorem 3.1 / Lemma 4.1 on random instances."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from loopid.control.value_iteration import evaluate, occupancy, policy_iteration, value_iteration
from loopid.systems import mdp_bounds
from loopid.systems.mdp import horizon_factor, random_mdp


@functools.cache
def _mdp():
    return jax.tree_util.tree_map(lambda a: a[0], random_mdp(jax.random.key(5)[None], 12, 3))


def _models(rng, k, S, A):
    return jnp.asarray(rng.dirichlet(np.full(S, 0.3), size=(k, S, A)))


def test_lemma_3_1_relations(rng):
    m = _mdp()
    S, A = m.n_states, m.n_actions
    d = jnp.asarray(rng.dirichlet(np.ones(S * A)).reshape(S, A))
    for T_hat in _models(rng, 5, S, A):
        l1 = mdp_bounds.l1_error(m.P, T_hat, d)
        kl = mdp_bounds.kl_error(m.P, T_hat, d)
        assert l1 <= np.sqrt(2 * kl) + 1e-12
    pred = jnp.asarray(rng.integers(0, S, (S, A)))
    det = jax.nn.one_hot(pred, S, dtype=jnp.float64)
    assert abs(mdp_bounds.l1_error(m.P, det, d) - 2 * mdp_bounds.cls_error(m.P, pred, d)) < 1e-12
    scores = jnp.asarray(rng.normal(size=(S, A, S)))
    det = jax.nn.one_hot(jnp.argmax(scores, -1), S, dtype=jnp.float64)
    assert mdp_bounds.l1_error(m.P, det, d) <= 2 * mdp_bounds.expected_hinge(m.P, scores, d) + 1e-12
    assert mdp_bounds.kl_error(m.P, det, d) == np.inf  # deterministic model, stochastic system
    best = mdp_bounds.best_in_class_deterministic(m.P)
    assert mdp_bounds.l1_error(m.P, best, d) <= mdp_bounds.l1_error(m.P, det, d)


def test_simulation_lemma_is_an_identity(rng):
    m = _mdp()
    S, A = m.n_states, m.n_actions
    T_hat = _models(rng, 1, S, A)[0]
    pi = jnp.asarray(rng.dirichlet(np.ones(A), size=S))
    D = occupancy(m.P, m.mu, m.gamma, pi)
    lhs, rhs = mdp_bounds.simulation_gap(m.P, T_hat, m.C, m.gamma, m.mu, pi, D)
    assert abs(lhs - rhs) < 1e-10 and abs(lhs) > 1e-3


def test_mismatch_handles_missing_mass():
    D = jnp.asarray([[0.5, 0.0], [0.5, 0.0]])
    assert mdp_bounds.mismatch(D, jnp.asarray([[0.25, 0.25], [0.25, 0.25]])) == 2.0
    assert mdp_bounds.mismatch(D, jnp.asarray([[1.0, 0.0], [0.0, 0.0]])) == np.inf
    assert mdp_bounds.mismatch(D, jnp.asarray([[0.5, 0.0], [0.5, 0.0]])) == 1.0  # 0/0 is 0


def test_theorem_3_1_and_lemma_4_1_hold_on_random_models(rng):
    """The bounds hold for arbitrary models (and are not trivially loose: the proofs' model
    terms are comparable to the actual gaps)."""
    m = _mdp()
    S, A = m.n_states, m.n_actions
    H = horizon_factor(m)
    opt = policy_iteration(m.P, m.C, m.gamma)
    j_star = float(m.mu @ opt.V)
    nu = jnp.asarray(rng.dirichlet(np.ones(S * A)).reshape(S, A))
    c_star = mdp_bounds.mismatch(occupancy(m.P, m.mu, m.gamma, opt.policy), nu)
    models = _models(rng, 12, S, A)
    pis = value_iteration(models, m.C, m.gamma).policy
    J = jax.vmap(lambda p: m.mu @ evaluate(m.P, m.C, m.gamma, p))(pis)
    D = jax.vmap(lambda p: occupancy(m.P, m.mu, m.gamma, p))(pis)
    oc = jax.vmap(lambda T, p: mdp_bounds.oc_error(T, m.C, m.gamma, m.mu, p, opt.policy))(
        models, pis
    )
    l1_nu = jax.vmap(lambda T: mdp_bounds.l1_error(m.P, T, nu))(models)
    c_hat = jax.vmap(lambda d: mdp_bounds.mismatch(d, nu))(D)
    batch = mdp_bounds.batch_bound(j_star, oc, c_hat, c_star, H, l1_nu)
    assert bool(jnp.all(J <= batch + 1e-10))
    rho = 0.5 * nu + 0.5 * D
    l1_rho = jax.vmap(lambda T, r: mdp_bounds.l1_error(m.P, T, r))(models, rho)
    for n in range(1, 13):
        lemma = mdp_bounds.dagger_bound(j_star, jnp.mean(oc[:n]), c_star, H, jnp.mean(l1_rho[:n]))
        assert jnp.min(J[:n]) <= jnp.mean(J[:n]) <= lemma + 1e-10
    assert mdp_bounds.dagger_constant(2.0, 3.0) == 6.0  # c H at q = 1/2
    assert mdp_bounds.batch_bound(1.0, 0.0, np.inf, 1.0, 1.0, 0.0) == np.inf  # ∞·0 counts as ∞
