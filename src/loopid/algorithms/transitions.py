"""Operations on fixed-shape batches of recorded transitions
(:class:`~loopid.algorithms.contracts.Transitions`, or any NamedTuple of arrays with a leading
batch axis and a boolean ``mask``): cleaning, row-wise choice, uniform draws, merging rollouts.

Every batch keeps its shape: a row that holds no data is masked and zero-filled, never removed
and never NaN, so the programs that use them compile once.
"""

import jax
import jax.numpy as jnp

from loopid.algorithms.contracts import Transitions


def clean(tr: Transitions) -> Transitions:
    """Invalidate rows with non-finite numbers and zero-fill every invalid row."""
    finite = (
        jnp.all(jnp.isfinite(tr.x), axis=-1)
        & jnp.all(jnp.isfinite(tr.dx), axis=-1)
        & jnp.all(jnp.isfinite(tr.du), axis=-1)
        & jnp.all(jnp.isfinite(tr.dx_next), axis=-1)
    )
    mask = tr.mask & finite

    def zero(a):
        return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, jnp.zeros_like(a))

    return Transitions(zero(tr.x), zero(tr.dx), zero(tr.du), zero(tr.dx_next), tr.t, mask)


def select(take_first: jax.Array, a: Transitions, b: Transitions) -> Transitions:
    """Row-wise choice: row i of ``a`` where ``take_first[i]``, else row i of ``b``.

    Any NamedTuple of arrays with a leading batch axis works (the result has ``a``'s type), so
    other systems' transition records (e.g. finite-MDP ``(s, a, s_next, t, mask)``) share it."""

    def pick(u, v):
        return jnp.where(take_first.reshape(take_first.shape + (1,) * (u.ndim - 1)), u, v)

    return type(a)(*(pick(u, v) for u, v in zip(a, b, strict=True)))


def draw(tr: Transitions, key: jax.Array, n: int) -> Transitions:
    """Draw ``n`` rows uniformly without replacement among the valid rows of ``tr``.

    Gumbel top-k over ``log(mask)``: fixed shapes, and when fewer than ``n`` rows are valid the
    surplus draws are invalid rows (masked), never duplicates.
    """
    b = tr.mask.shape[0]
    if n > b:
        raise ValueError(f"cannot draw n={n} rows from a batch of {b}")
    scores = jax.random.gumbel(key, (b,)) + jnp.where(tr.mask, 0.0, -jnp.inf)
    _, idx = jax.lax.top_k(scores, n)
    return jax.tree_util.tree_map(lambda a: a[idx], tr)


def flatten(tr: Transitions) -> Transitions:
    """Merge the two leading axes ``[R, T]`` of stacked rollouts into one ``[R·T]``."""
    return jax.tree_util.tree_map(lambda a: a.reshape((-1, *a.shape[2:])), tr)
