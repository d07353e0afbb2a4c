r"""The empirical count estimator of a finite MDP's transitions (the paper's no-regret
estimator in L1, section 4 and its finite-sample discussion), as a :class:`Learner`.

Rows are one-hot features ``x = e_{(s,a)} [f = S·A]`` and one-hot targets ``y = e_{s'} [t = S]``
(any non-negative rows work: the statistics are weighted sums). After the rows seen so far::

    N = Σ_j x_j y_jᵀ  [f, t],       T̂_sa = (N_sa + α p_sa) / (Σ_{s'} N_sa(s') + α),

the empirical distribution with ``α`` pseudo-counts on a prior row ``p_sa`` (default uniform;
:func:`loopid.experiments.families.mdp.agent.stay_prior` is "stay where you are"). With α → 0 it is
the empirical estimator wherever a pair was seen and the prior elsewhere; its L1 error on a pair
seen n times falls like ``O(√(S/n))``. The online losses ``L_i(T̂) = E_{ρ_i}‖T_sa − T̂_sa‖₁``
of the refit on all data so far have vanishing average regret (the paper's supplementary
argument): this is FTRL on counts. ``weights(state)`` is T̂ as ``[f, t]`` (rows sum to 1).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.learners.base import Learner, check_batch, check_dims, zero_dropped

__all__ = ["CountState", "count_estimator"]


class CountState(NamedTuple):
    """Counts ``N [f, t]`` of (feature, target) weight seen and the prior rows ``prior [f, t]``."""

    N: jax.Array
    prior: jax.Array


def count_estimator(alpha: float = 1.0, prior=None) -> Learner:
    """The count estimator with ``alpha`` > 0 pseudo-counts on ``prior`` (module doc).

    Args:
      alpha: prior weight, > 0 (keeps unseen rows defined).
      prior: ``[f, t]`` rows of probabilities, or None for uniform rows.

    Returns:
      A :class:`Learner`; state :class:`CountState`; ``weights`` gives T̂ ``[f, t]``.
    """
    try:
        alpha = float(alpha)
    except (TypeError, ValueError):
        raise ValueError(f"alpha must be a real number > 0, got {alpha!r}") from None
    if not (alpha > 0 and math.isfinite(alpha)):
        raise ValueError(f"alpha must be a finite number > 0, got {alpha!r}")
    if prior is not None:
        prior = np.asarray(prior, dtype=np.float64)
        if prior.ndim != 2 or (prior < 0).any() or not np.allclose(prior.sum(-1), 1.0):
            raise ValueError(f"prior must be [f, t] rows of probabilities, got shape {prior.shape}")

    def init(n_features, n_targets) -> CountState:
        f, t = check_dims(n_features, n_targets)
        if prior is None:
            p = jnp.full((f, t), 1.0 / t, jnp.float64)
        elif prior.shape != (f, t):
            raise ValueError(f"prior has shape {prior.shape}, the learner is [{f}, {t}]")
        else:
            p = jnp.asarray(prior)
        return CountState(jnp.zeros((f, t), jnp.float64), p)

    @jax.jit
    def _update(state, X, Y, keep):
        X, Y = zero_dropped(X, Y, keep)
        return state._replace(N=state.N + X.T @ Y)

    def update(state: CountState, X, Y, mask=None) -> CountState:
        X, Y, keep = check_batch(X, Y, mask, state.N.shape[0], state.N.shape[1])
        return _update(state, X, Y, keep)

    @jax.jit
    def weights(state: CountState) -> jax.Array:
        total = jnp.sum(state.N, axis=-1, keepdims=True)
        return (state.N + alpha * state.prior) / (total + alpha)

    return Learner(init=init, update=update, weights=weights, name=f"counts(alpha={alpha:g})")
