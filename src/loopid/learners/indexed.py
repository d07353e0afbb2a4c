"""Time-varying learners: one independent copy of a base learner per time step.

``indexed(learner, T)`` is a :class:`~loopid.learners.Learner` whose state is the base state
stacked over T steps (every leaf gets a leading [T] axis) and whose update takes, besides X, Y
and mask, an integer ``index`` [b]: the time step of each row. Step t's state is updated with the
rows whose index equals t (and whose mask is on), all steps at once with fixed shapes, so

- FTRL per step is an independent regularised fit per step, n counting that step's rows only
  (the funnel's time-varying model), and
- OGD per step takes a gradient step only where the batch has rows for that step; a step with no
  rows keeps its weights and its step count.

``weights`` returns [T, f, t]. A base learner with an ``update_indexed`` fast path (FTRL:
scatter-add, O(b f²)) uses it; otherwise ``update`` is vmapped over the T steps with the rows of
other steps masked out (O(T b f t) for OGD).

A step with no rows keeps its state, so its weights do not change either:
:func:`touched_weights` re-solves only the steps a batch reached (b solves instead of T: the
funnel's 500 rows over 599 steps; timed in ``benchmarks/learners.py``), each exactly as
``weights`` would.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from loopid.learners.base import Learner, check_batch, check_index

__all__ = ["indexed", "touched_weights"]


def indexed(learner: Learner, T: int) -> Learner:
    """Stack ``learner`` over ``T`` time steps; rows are routed to their step by ``index``.

    Args:
      learner: the per-step learner (e.g. ``ftrl_least_squares(1e-3)``).
      T: number of time steps (positive integer).

    Returns:
      A :class:`Learner` with ``init(n_features, n_targets)`` -> stacked state,
      ``update(state, X, Y, mask=None, index=...)`` (index [b] integers in [0, T), required) and
      ``weights(state)`` -> [T, f, t].
    """
    if isinstance(T, bool) or not isinstance(T, int | np.integer) or T < 1:
        raise ValueError(f"T must be a positive integer, got {T!r}")
    if not isinstance(learner, Learner):
        raise TypeError(f"learner must be a loopid.learners.Learner, got {type(learner).__name__}")
    T = int(T)
    base = learner
    steps = jnp.arange(T)

    def init(n_features, n_targets):
        one = base.init(n_features, n_targets)
        return jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (T, *a.shape)), one)

    def _sizes(state):
        f, t = jax.eval_shape(base.weights, jax.tree_util.tree_map(lambda a: a[0], state)).shape
        return f, t

    @jax.jit
    def _update_vmapped(states, X, Y, keep, index):
        def one(state, t):
            return base.update(state, X, Y, keep & (index == t))

        return jax.vmap(one)(states, steps)

    _update = _update_vmapped if base.update_indexed is None else base.update_indexed

    def update(state, X, Y, mask=None, index=None):
        f, t = _sizes(state)
        X, Y, keep = check_batch(X, Y, mask, f, t)
        index = check_index(index, X.shape[0], T)
        return _update(state, X, Y, keep, index)

    @jax.jit
    def weights(state):
        return jax.vmap(base.weights)(state)

    return Learner(init=init, update=update, weights=weights, name=f"indexed({base.name}, T={T})")


def touched_weights(learner: Learner, states, W: jax.Array, index, keep) -> jax.Array:
    """The weights ``[T, f, t]`` of ``states`` (an :func:`indexed` state stacked over T steps),
    given ``W``, the weights before the update that made ``states``, and that update's rows:
    ``index`` [b] their steps and ``keep`` [b] whether each counted. Only the steps of kept rows
    are solved again, with ``learner`` (the per-step learner ``indexed`` was built on); every
    other step keeps its row of ``W``. Equal bit for bit to ``indexed(learner, T).weights(states)``
    when ``W`` is the weights of the states before the update: each step's solve is the same
    computation on the same state. Fixed shapes: b solves whether or not steps repeat."""
    T = W.shape[0]
    index = jnp.where(keep, index, T)  # a dropped row touches no step
    at = jnp.minimum(index, T - 1)
    fresh = jax.vmap(learner.weights)(jax.tree_util.tree_map(lambda a: a[at], states))
    return W.at[index].set(fresh, mode="drop")
