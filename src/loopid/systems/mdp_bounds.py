r"""The paper's quantities, exactly, on finite MDPs (sections 3-4 of Ross & Bagnell 2012).

Notation (paper section 2-3): true model ``T`` (``P [S, A, S]``), learnt model ``T̂``, costs
``C ∈ [C_min, C_max]``, ``H = γ C_rng / (1−γ)²``, ``D_{μ,π}`` the discounted state-action
distribution (:func:`loopid.control.value_iteration.occupancy`), ν an exploration distribution
over state-action pairs ``[S, A]``.

Prediction errors under a distribution ``d [S, A]`` (Lemma 3.1 relates them):

- ``ε^{L1} = E_{(s,a)∼d} ‖T_sa − T̂_sa‖₁`` (:func:`l1_error`);
- ``ε^{KL} = E_{d, s'∼T_sa}[log T_sa(s') − log T̂_sa(s')]`` (:func:`kl_error`, +∞ where T̂ misses
  mass of T);
- ``ε^{cls} = E_{d, s'∼T_sa}[ℓ]`` with ℓ the 0-1 loss of a deterministic model predicting
  ``ŝ(s, a)`` (:func:`cls_error`); Lemma 3.1: ``ε^{L1} ≤ √(2 ε^{KL})`` and ``ε^{L1} ≤ 2 ε^{cls}``
  with equality for the 0-1 loss.

Mismatch ``c_ν^π = sup_{s,a} D_{μ,π}(s,a) / ν(s,a)`` (:func:`mismatch`; +∞ where ν misses mass
of D, 0/0 counts as 0). Both bounds hold deterministically for any models and policies (their
proofs use only the simulation lemma, :func:`simulation_gap`), so on exact quantities they can
never be violated; a bad learner shows up as a large right-hand side:

- Theorem 3.1 (Batch, model ``T̂`` fit on ν, ``π̂`` its policy), :func:`batch_bound`:
  ``J(π̂) ≤ J(π') + ε_oc^{π'} + (c_ν^{π̂} + c_ν^{π'})/2 · H · ε^{L1}_ν``.
- Lemma 4.1 (DAgger), :func:`dagger_bound`: with ``ρ_i = ½ν + ½D_{μ,π_i}``,
  ``min_i J(π_i) ≤ (1/N) Σ_i J(π_i) ≤ J(π') + ε̄_oc^{π'} + c_ν^{π'} H ε̄^{L1}_ρ``.
  For a mixing weight q ≠ ½ in ρ_i the same proof gives the constant
  ``(H/2) max(1/q, c_ν^{π'}/(1−q))`` (= ``c H`` at q = ½ since c ≥ 1).

``ε_oc^{π'} = E_{s∼μ}[V̂^{π̂}(s) − V̂^{π'}(s)]`` on the learnt model (:func:`oc_error`).
"""

import jax
import jax.numpy as jnp

from loopid.control.value_iteration import evaluate

__all__ = [
    "batch_bound",
    "best_in_class_deterministic",
    "cls_error",
    "dagger_bound",
    "dagger_constant",
    "expected_hinge",
    "kl_error",
    "l1_error",
    "mismatch",
    "oc_error",
    "row_l1",
    "simulation_gap",
]


def row_l1(P: jax.Array, P_hat: jax.Array) -> jax.Array:
    """``‖T_sa − T̂_sa‖₁`` for every pair: ``[..., S, A]``."""
    return jnp.sum(jnp.abs(P - P_hat), axis=-1)


def l1_error(P, P_hat, d) -> jax.Array:
    """``E_{(s,a)∼d} ‖T_sa − T̂_sa‖₁`` (``d [..., S, A]`` need not be normalised: a weighted sum)."""
    return jnp.sum(d * row_l1(P, P_hat), axis=(-2, -1))


def kl_error(P, P_hat, d) -> jax.Array:
    """``E_{d, s'∼T}[log T(s') − log T̂(s')]``; +∞ when T̂ gives 0 where T and d do not."""
    pos = P > 0
    ratio = jnp.where(pos, jnp.log(jnp.where(pos, P, 1.0)) - jnp.log(jnp.where(pos, P_hat, 1.0)), 0)
    missing = pos & (P_hat <= 0)
    row = jnp.where(jnp.any(missing, axis=-1), jnp.inf, jnp.sum(jnp.where(pos, P * ratio, 0), -1))
    return jnp.sum(jnp.where(d > 0, d * row, 0.0), axis=(-2, -1))


def cls_error(P, predicted, d) -> jax.Array:
    """0-1 loss of a deterministic model predicting state ``predicted [..., S, A]`` (int):
    ``E_{(s,a)∼d} [1 − T_sa(ŝ(s,a))]``."""
    hit = jnp.take_along_axis(P, predicted[..., None].astype(jnp.int32), axis=-1)[..., 0]
    return jnp.sum(d * (1.0 - hit), axis=(-2, -1))


def expected_hinge(P, scores, d) -> jax.Array:
    """Expected multi-class (Crammer-Singer) hinge loss ``E_{d, s'∼T} max(0, 1 + max_{y≠s'}
    w_y − w_{s'})`` of per-pair scores ``[..., S, A, S]``: an upper bound on the 0-1 loss."""
    S = scores.shape[-1]
    eye = jnp.eye(S, dtype=bool)
    other = jnp.max(jnp.where(eye, -jnp.inf, scores[..., None, :]), axis=-1)  # [.., S, A, S]
    loss = jnp.maximum(0.0, 1.0 + other - scores)
    return jnp.sum(d * jnp.sum(P * loss, axis=-1), axis=(-2, -1))


def best_in_class_deterministic(P) -> jax.Array:
    """The best deterministic model of a tabular class in L1 / 0-1 loss, for every pair at
    once: one-hot on ``argmax_{s'} T_sa(s')``. Its L1 error ``2(1 − max T_sa)`` is the
    modelling error ``ε_mdl`` of the deterministic class."""
    return jax.nn.one_hot(jnp.argmax(P, axis=-1), P.shape[-1], dtype=jnp.float64)


def mismatch(D, nu) -> jax.Array:
    """``c_ν^π = max_{s,a} D(s,a)/ν(s,a)``: +∞ where ν(s,a) = 0 < D(s,a); 0/0 counts as 0."""
    ratio = jnp.where(nu > 0, D / jnp.where(nu > 0, nu, 1.0), jnp.where(D > 0, jnp.inf, 0.0))
    return jnp.max(ratio, axis=(-2, -1))


def oc_error(P_hat, C, gamma, mu, pi_hat, pi_ref) -> jax.Array:
    """``ε_oc^{π'} = E_{s∼μ}[V̂^{π̂}(s) − V̂^{π'}(s)]`` on the learnt model ``P_hat``."""
    return mu @ (evaluate(P_hat, C, gamma, pi_hat) - evaluate(P_hat, C, gamma, pi_ref))


def simulation_gap(P, P_hat, C, gamma, mu, pi, D) -> tuple[jax.Array, jax.Array]:
    """Both sides of the simulation lemma for one policy: ``(J(π) − Ĵ(π),
    γ/(1−γ) E_{(s,a)∼D_{μ,π}} [(T_sa − T̂_sa)·V̂^π])`` — equal for exact D."""
    V = evaluate(P, C, gamma, pi)
    V_hat = evaluate(P_hat, C, gamma, pi)
    lhs = mu @ (V - V_hat)
    rhs = gamma / (1.0 - gamma) * jnp.sum(D * ((P - P_hat) @ V_hat))
    return lhs, rhs


def _times(c, e):
    """``c · e`` with ∞·0 = ∞ (a bound that needs an infinite mismatch is vacuous)."""
    return jnp.where(jnp.isinf(c), jnp.inf, c * e)


def batch_bound(j_ref, eps_oc, c_hat, c_ref, H, eps_l1_nu) -> jax.Array:
    """Theorem 3.1's right-hand side ``J(π') + ε_oc + (c^π̂ + c^π')/2 · H · ε^{L1}_ν``."""
    return j_ref + eps_oc + _times((c_hat + c_ref) / 2.0, H * eps_l1_nu)


def dagger_constant(c_ref, H, q=0.5) -> jax.Array:
    """The factor in front of ``ε̄^{L1}_ρ`` in Lemma 4.1 when ``ρ_i = (1−q)ν + q D_{μ,π_i}``:
    ``(H/2) max(1/q, c/(1−q))``; equals the paper's ``c H`` at q = ½ (c ≥ 1 always)."""
    return H / 2.0 * jnp.maximum(1.0 / q, c_ref / (1.0 - q))


def dagger_bound(j_ref, mean_eps_oc, c_ref, H, mean_eps_l1_rho, q=0.5, q_max=None) -> jax.Array:
    """Lemma 4.1's right-hand side ``J(π') + ε̄_oc + c_ν^{π'} H ε̄^{L1}_ρ`` (q = ½).

    When the policy share of ``ρ_i`` varies over the iterations within ``[q, q_max]``, the
    constant is the worst over that range, which is at one of its ends (``1/q`` falls and
    ``c/(1−q)`` rises with q); it is ∞ at ``q_max = 1`` (no ν in ρ: no guarantee)."""
    q_max = q if q_max is None else q_max
    constant = jnp.maximum(dagger_constant(c_ref, H, q), dagger_constant(c_ref, H, q_max))
    return j_ref + mean_eps_oc + _times(constant, mean_eps_l1_rho)
