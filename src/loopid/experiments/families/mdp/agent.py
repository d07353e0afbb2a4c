r"""Finite MDPs through the same loop as the helicopter: plant, ν, agent, exact diagnostics.

- :func:`mdp_plant`: the real finite MDP as the loop's plant. ``rollout(K, key)`` runs the
  policy ``K [S, A]`` (probability rows; one-hot for deterministic policies) for ``horizon``
  steps from μ and returns :class:`MDPTransitions` ``[horizon]`` (all valid); in ``geometric``
  mode the loop keeps step ``L ∼`` geometric(γ) truncated to the horizon, an exact draw from
  ``D_{μ,π}`` up to ``γ^horizon``. The test "cost" is the exact ``J_μ(π)`` (a linear solve),
  so ``test_cost`` is exact; the test noise is a dummy ``[n_test, 1]``.
- :func:`explicit_nu` / :func:`policy_nu`: ν as an explicit distribution over (s, a) pairs, or
  ``D_{μ,π_0}`` of a base policy (computed exactly); draws (s, a) ∼ ν then s' ∼ T_sa.
- :func:`mdp_agent`: the tabular model class and its learner (:func:`counts_model`: the count
  estimator; :func:`classifier_model`: the deterministic model learnt by online hinge
  classification), and value iteration on the learnt model (greedy policy).
- :func:`mdp_diagnostics`: the exact theory each iteration
  (:mod:`loopid.systems.mdp_bounds`), as extra result columns.

Sampling uses inverse CDFs (one uniform per draw), so a step costs O(S) and no Gumbel noise.
"""

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.contracts import Agent, Diagnostics, SolverInfo
from loopid.control.value_iteration import evaluate, occupancy, policy_iteration, value_iteration
from loopid.learners.base import Learner
from loopid.learners.counts import count_estimator
from loopid.learners.hinge import hinge_loss, online_hinge
from loopid.systems import mdp_bounds
from loopid.systems.mdp import FiniteMDP, check_mdp, horizon_factor

__all__ = [
    "MDPModel",
    "MDPPlant",
    "MDPTransitions",
    "classifier_model",
    "counts_model",
    "explicit_nu",
    "mdp_agent",
    "mdp_diagnostics",
    "mdp_plant",
    "policy_nu",
    "stay_prior",
]

DIAGNOSTICS = (
    "j_policy",
    "j_best",
    "j_mixture",
    "j_optimal",
    "bound",
    "eps_prd_l1",
    "eps_prd_kl",
    "eps_mdl_l1",
    "eps_oc",
    "c_nu",
    "c_nu_policy",
)


class MDPTransitions(NamedTuple):
    """Transitions ``(s, a, s_next)`` (int32 ``[b]``), the step index ``t`` and ``mask``."""

    s: jax.Array
    a: jax.Array
    s_next: jax.Array
    t: jax.Array
    mask: jax.Array


def _categorical(p: jax.Array, u: jax.Array) -> jax.Array:
    """Inverse-CDF draw from probabilities ``p [n]`` with a uniform ``u``: never a 0-mass index."""
    cdf = jnp.cumsum(p)
    i = jnp.sum(cdf <= u * cdf[-1], dtype=jnp.int32)  # searchsorted(side="right"), O(n)
    return jnp.minimum(i, p.shape[0] - 1)


class MDPPlant(NamedTuple):
    """The real finite MDP as the loop's plant (module doc); implements
    :class:`loopid.algorithms.contracts.LoopPlant`."""

    mdp: FiniteMDP
    horizon: int
    rollout: Callable[[jax.Array, jax.Array], MDPTransitions]
    eval_one: Callable[[jax.Array, jax.Array], tuple[jax.Array, jax.Array]]

    def eval_noise(self, key: jax.Array, n_test: int) -> jax.Array:
        """A dummy ``[n_test, 1]``: the test is exact."""
        return jnp.zeros((n_test, 1), jnp.float64)

    def eval_costs(self, K: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``J_μ(π)`` repeated ``n_test`` times and no divergence."""
        J, _ = self.eval_one(K, noise[0])
        n = noise.shape[0]
        return jnp.full((n,), J), jnp.zeros((n,), bool)

    def eval_seeds(self, K: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """:meth:`eval_costs` of every seed: ``K [S, …]``, ``noise [1, S, n_test]`` (the column
        layout of :meth:`loopid.algorithms.plant.Plant.eval_seeds`). The seeds are evaluated in
        turn (``lax.map``), so a seed's exact cost has the same bits however many seeds are
        evaluated beside it (a ``vmap``'s batched linear solve changed its last bit with the
        batch)."""
        J = jax.lax.map(lambda k: self.eval_one(k, noise[:, 0, 0])[0], K)
        return jnp.broadcast_to(J[:, None], noise.shape[1:]), jnp.zeros(noise.shape[1:], bool)


def mdp_plant(mdp: FiniteMDP, horizon: int) -> MDPPlant:
    """The plant of one (unbatched) finite MDP with rollouts of ``horizon`` steps."""
    check_mdp(mdp)
    if mdp.P.ndim != 3:
        raise ValueError(f"mdp must be a single MDP (P [S, A, S]), got P {mdp.P.shape}")
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
        raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
    P, mu = mdp.P, mdp.mu

    def rollout(K: jax.Array, key: jax.Array) -> MDPTransitions:
        u = jax.random.uniform(key, (horizon + 1, 2), dtype=jnp.float64)  # one PRNG call
        s0, u = _categorical(mu, u[0, 0]), u[1:]

        def body(s, inp):
            ut, t = inp
            a = _categorical(K[s], ut[0])
            s_next = _categorical(P[s, a], ut[1])
            return s_next, (s, a, s_next, t)

        _, (s, a, s_next, t) = jax.lax.scan(body, s0, (u, jnp.arange(horizon, dtype=jnp.int32)))
        return MDPTransitions(s, a, s_next, t, jnp.ones((horizon,), bool))

    def eval_one(K: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        J = mu @ evaluate(P, mdp.C, mdp.gamma, K)
        return J, jnp.bool_(False)

    return MDPPlant(mdp, int(horizon), rollout, eval_one)


def explicit_nu(mdp: FiniteMDP, dist) -> Callable[[jax.Array, int], MDPTransitions]:
    """ν from an explicit distribution ``dist [S, A]`` over pairs: ``nu(key, count)`` draws
    (s, a) ∼ dist and s' ∼ T_sa. Raises ``ValueError`` if dist is not a distribution."""
    S, A = mdp.n_states, mdp.n_actions
    d = np.asarray(dist, dtype=np.float64)
    if d.shape != (S, A) or (d < 0).any() or not np.isclose(d.sum(), 1.0):
        raise ValueError(f"dist must be a [{S}, {A}] probability table, got shape {d.shape}")
    flat = jnp.asarray(d.reshape(-1))

    def nu(key: jax.Array, count: int) -> MDPTransitions:
        u = jax.random.uniform(key, (count, 2), dtype=jnp.float64)
        idx = jax.vmap(lambda v: _categorical(flat, v))(u[:, 0])
        s, a = idx // A, idx % A
        s_next = jax.vmap(lambda i, j, v: _categorical(mdp.P[i, j], v))(s, a, u[:, 1])
        zero = jnp.zeros((count,), jnp.int32)
        return MDPTransitions(s, a, s_next, zero, jnp.ones((count,), bool))

    return nu


def policy_nu(mdp: FiniteMDP, pi0) -> tuple[jax.Array, Callable]:
    """ν = ``D_{μ,π_0}`` of a base policy ``pi0 [S, A]`` (exact): returns ``(dist, nu)``."""
    dist = occupancy(mdp.P, mdp.mu, mdp.gamma, jnp.asarray(pi0, jnp.float64))
    dist = dist / jnp.sum(dist)
    return dist, explicit_nu(mdp, np.asarray(dist))


class MDPModel(NamedTuple):
    """A tabular model class: its online ``learner`` (features ``e_{(s,a)}``, targets
    ``e_{s'}``), ``transitions(W) -> T̂ [S, A, S]``, ``row_loss(W, batch) -> [b]`` (the loss
    reported per row) and ``best_in_class(T) -> T' [S, A, S]`` (its modelling-error witness)."""

    learner: Learner
    transitions: Callable[[jax.Array], jax.Array]
    row_loss: Callable[[jax.Array, MDPTransitions], jax.Array]
    best_in_class: Callable[[jax.Array], jax.Array]
    name: str


def stay_prior(n_states: int, n_actions: int, smoothing: float = 0.0) -> np.ndarray:
    """Prior rows ``[S·A, S]``: "an unseen action leaves the state unchanged", mixed with
    ``smoothing`` of the uniform distribution (> 0 keeps every KL error finite)."""
    if not 0.0 <= smoothing <= 1.0:
        raise ValueError(f"smoothing must lie in [0, 1], got {smoothing!r}")
    stay = np.repeat(np.eye(n_states), n_actions, axis=0)
    return (1.0 - smoothing) * stay + smoothing / n_states


def counts_model(n_states: int, n_actions: int, *, alpha: float = 0.1, prior=None) -> MDPModel:
    """The count estimator (:func:`loopid.learners.count_estimator`); prior default "stay"
    with 1% uniform smoothing (``stay_prior(S, A, 0.01)``). Row loss: ``−log T̂(s'|s,a)``,
    clipped to [0, 30]. The class holds every T: ε_mdl = 0."""
    S, A = n_states, n_actions
    prior = stay_prior(S, A, 0.01) if prior is None else prior
    learner = count_estimator(alpha, prior)

    def transitions(W):
        return W.reshape(S, A, S)

    def row_loss(W, batch):
        p = W[batch.s * A + batch.a, batch.s_next]
        return jnp.minimum(-jnp.log(jnp.maximum(p, 1e-300)), 30.0)

    return MDPModel(learner, transitions, row_loss, lambda T: T, f"counts(alpha={alpha:g})")


def classifier_model(n_states: int, n_actions: int, *, eta: float = 1.0, margin: float = 0.5):
    """Deterministic models ``T̂_sa = δ_{argmax_s' W[(s,a), s']}`` learnt by the online hinge
    classifier (:func:`loopid.learners.online_hinge`), initial scores ``margin · stay``.
    Row loss: the hinge loss. Best in class: the most likely successor of each pair."""
    S, A = n_states, n_actions
    learner = online_hinge(eta, margin * stay_prior(S, A))

    def transitions(W):
        return jax.nn.one_hot(jnp.argmax(W.reshape(S, A, S), axis=-1), S, dtype=jnp.float64)

    def row_loss(W, batch):
        return hinge_loss(W, jax.nn.one_hot(batch.s * A + batch.a, S * A), batch.s_next)

    best = mdp_bounds.best_in_class_deterministic
    return MDPModel(learner, transitions, row_loss, best, f"hinge(eta={eta:g})")


def mdp_agent(mdp: FiniteMDP, model: MDPModel, *, tol: float = 1e-10) -> Agent:
    """The loop's :class:`Agent` for a finite MDP: ``model``'s learner on one-hot (s, a) →
    s' rows; policy = greedy in value iteration (sup-norm error ≤ ``tol``) on ``T̂`` with the
    known cost; SolverInfo(converged, γ) (γ: the contraction factor of the discounted
    closed loop)."""
    S, A = mdp.n_states, mdp.n_actions
    learner = model.learner

    def rows(batch: MDPTransitions):
        X = jax.nn.one_hot(batch.s * A + batch.a, S * A, dtype=jnp.float64)
        return X, jax.nn.one_hot(batch.s_next, S, dtype=jnp.float64)

    def init():
        return learner.init(S * A, S)

    def update(state, batch):
        X, Y = rows(batch)
        return learner.update(state, X, Y, batch.mask)

    def policy(state):
        T_hat = model.transitions(learner.weights(state))
        sol = value_iteration(T_hat, mdp.C, mdp.gamma, tol=tol, max_iter=100_000)
        return sol.policy, SolverInfo(sol.converged, mdp.gamma)

    def loss(state, batch):
        return model.row_loss(learner.weights(state), batch)

    def params(state) -> dict:
        """The learned transition model ``T̂ [S, A, S]``."""
        return {"T_hat": model.transitions(learner.weights(state))}

    return Agent(init, update, policy, loss, params=params)


class _DiagState(NamedTuple):
    n: jax.Array
    policy_data: jax.Array
    sum_oc: jax.Array
    sum_l1: jax.Array
    sum_kl: jax.Array
    sum_mdl: jax.Array
    sum_j: jax.Array
    best_j: jax.Array
    q_min: jax.Array
    q_max: jax.Array


def mdp_diagnostics(
    mdp: FiniteMDP, nu_dist, model: MDPModel, *, rule: str = "auto", q: float = 0.5
) -> Diagnostics:
    """Exact per-iteration theory for the loop (:class:`Diagnostics`), against π' = π*.

    Columns (float64; +∞ allowed, never NaN): ``j_policy = J(π_n)``, ``j_best = min_{i≤n}
    J(π_i)``, ``j_mixture = (1/n) Σ_i J(π_i)`` (the uniform mixture), ``j_optimal = J(π*)``,
    ``bound``, the error terms that enter it (``eps_prd_l1``, ``eps_prd_kl``, ``eps_mdl_l1``,
    ``eps_oc``), ``c_nu = c_ν^{π*}`` and ``c_nu_policy = c_ν^{π_n}``.

    ``rule="lemma"`` (DAgger): errors averaged over i ≤ n on ``ρ_i = (1−q_i)ν + q_i D_{μ,π_i}``,
    bound = Lemma 4.1's RHS (bounds j_best and j_mixture), with ``q_i`` the policy fraction ``p``
    of the iteration (``q`` where no batch was learned yet, iteration 1) and the constant taken
    at the worst ``q_i`` (:func:`loopid.systems.mdp_bounds.dagger_constant`; ∞ once ν's
    share is 0, as for Abbeel's policy-only iterations: no guarantee). ``rule="theorem"`` (Batch):
    errors of the current model on ν, bound = Theorem 3.1's RHS (bounds j_policy, hence j_best).
    ``rule="auto"`` (default) follows the data: Theorem 3.1 while every batch so far came from
    ν alone (policy fraction ``p = 0``: Batch, and iteration 1 of every method), Lemma 4.1 once
    a policy contributed (DAgger from n = 2; Abbeel from n = 3). One compiled cell then serves
    every method.
    ``eps_mdl_l1`` is the L1 error of the class's best model on the same distribution (0 for
    counts). Both bounds hold for any learner: a learner that is not no-regret gives a larger
    bound, never a violated one.
    """
    if rule not in ("auto", "lemma", "theorem"):
        raise ValueError(f"rule must be 'auto', 'lemma' or 'theorem', got {rule!r}")
    if not 0.0 < q < 1.0:
        raise ValueError(f"q must lie in (0, 1), got {q!r}")
    P, C, g, mu = mdp.P, mdp.C, mdp.gamma, mdp.mu
    nu_dist = jnp.asarray(nu_dist, jnp.float64)
    if nu_dist.shape != C.shape:
        raise ValueError(f"nu_dist must have shape {C.shape}, got {nu_dist.shape}")
    opt = policy_iteration(P, C, g)
    pi_star, j_star = opt.policy, mu @ opt.V
    c_star = mdp_bounds.mismatch(occupancy(P, mu, g, pi_star), nu_dist)
    H = horizon_factor(mdp)
    T_best = model.best_in_class(P)

    def init():
        z = jnp.float64(0.0)
        inf = jnp.float64(jnp.inf)
        return _DiagState(jnp.int32(0), jnp.bool_(False), z, z, z, z, z, inf, inf, -inf)

    def update(state: _DiagState, learner_state: Any, K, p, n):
        T_hat = model.transitions(model.learner.weights(learner_state))
        D = occupancy(P, mu, g, K)
        j = mu @ evaluate(P, C, g, K)
        eps_oc = mdp_bounds.oc_error(T_hat, C, g, mu, K, pi_star)
        c_pol = mdp_bounds.mismatch(D, nu_dist)
        q_n = jnp.where(p > 0, p, q)  # this iteration's policy share of ρ
        rho = (1.0 - q_n) * nu_dist + q_n * D
        on_nu = [f(P, T_hat, nu_dist) for f in (mdp_bounds.l1_error, mdp_bounds.kl_error)]
        on_rho = [f(P, T_hat, rho) for f in (mdp_bounds.l1_error, mdp_bounds.kl_error)]
        state = _DiagState(
            state.n + 1,
            state.policy_data | (p > 0),
            state.sum_oc + eps_oc,
            state.sum_l1 + on_rho[0],
            state.sum_kl + on_rho[1],
            state.sum_mdl + mdp_bounds.l1_error(P, T_best, rho),
            state.sum_j + j,
            jnp.minimum(state.best_j, j),
            jnp.minimum(state.q_min, q_n),
            jnp.maximum(state.q_max, q_n),
        )
        count = state.n.astype(jnp.float64)
        batch_terms = (*on_nu, mdp_bounds.l1_error(P, T_best, nu_dist), eps_oc)
        batch = mdp_bounds.batch_bound(j_star, eps_oc, c_pol, c_star, H, on_nu[0])
        sums = (state.sum_l1, state.sum_kl, state.sum_mdl, state.sum_oc)
        dagger_terms = tuple(x / count for x in sums)
        dagger = mdp_bounds.dagger_bound(
            j_star, dagger_terms[3], c_star, H, dagger_terms[0], state.q_min, state.q_max
        )
        use_lemma = {"auto": state.policy_data, "lemma": True, "theorem": False}[rule]
        bound = jnp.where(use_lemma, dagger, batch)
        terms = [jnp.where(use_lemma, a, b) for a, b in zip(dagger_terms, batch_terms, strict=True)]
        values = (j, state.best_j, state.sum_j / count, j_star, bound, *terms, c_star, c_pol)
        values = [jnp.asarray(v, jnp.float64) for v in values]
        return state, dict(zip(DIAGNOSTICS, values, strict=True))

    return Diagnostics(init, update)
