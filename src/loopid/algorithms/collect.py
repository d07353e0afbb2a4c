"""Drawing the policy half of each iteration's data (Algorithm 1), with fixed shapes.

Two ways to draw ``count`` transitions from running the current policy π from μ:

- ``"trajectory"`` (the paper's experiments; default for the helicopter): run π over the task
  horizon, restarting from μ whenever a training trajectory leaves the safe region, and draw the
  transitions uniformly at random (without replacement) among the valid steps of those runs; the
  runs are ``ceil(count / horizon)`` rollouts of ``horizon`` steps each. This weights
  ``D_{μ,π}`` uniformly over the horizon.
- ``"geometric"`` (the paper's analysis): for each of the ``count`` draws run π from μ and stop
  with probability ``1 − γ`` at every step, keeping the last transition: the kept step index
  ``L`` has ``P(L = k) ∝ (1 − γ) γ^k``, truncated to the horizon (exact inverse-CDF draw). An
  unbiased draw from the (truncated) discounted distribution ``D_{μ,π}``.

A draw whose trajectory left the safe region before its step comes back masked.
"""

import math

import jax
import jax.numpy as jnp

from loopid.algorithms.contracts import Transitions
from loopid.algorithms.plant import Plant
from loopid.algorithms.transitions import draw, flatten

SAMPLING_MODES = ("trajectory", "geometric")


def geometric_steps(key: jax.Array, count: int, gamma: float, horizon: int) -> jax.Array:
    """``count`` stopping steps ``L ∈ {0, …, horizon−1}`` with ``P(L = k) ∝ γ^k`` (int32).

    Inverse CDF of the geometric law truncated to the horizon: with ``U`` uniform on
    ``(γ^horizon, 1]``, ``L = floor(log U / log γ)``.
    """
    if not 0.0 < gamma < 1.0:
        raise ValueError(f"gamma must be in (0, 1), got {gamma!r}")
    low = gamma**horizon
    u = jax.random.uniform(key, (count,), dtype=jnp.float64, minval=low, maxval=1.0)
    u = jnp.maximum(u, jnp.nextafter(jnp.float64(low), jnp.float64(1.0)))
    steps = jnp.floor(jnp.log(u) / math.log(gamma))
    return jnp.clip(steps, 0, horizon - 1).astype(jnp.int32)


def _keep_only(tr, keep: jax.Array):
    """``tr`` with the rows outside ``keep`` masked and zero-filled (any transitions NamedTuple
    with ``t`` and ``mask`` fields)."""
    mask = tr.mask & keep

    def zero(a):
        return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, jnp.zeros_like(a))

    rows = {f: getattr(tr, f) if f in ("t", "mask") else zero(getattr(tr, f)) for f in tr._fields}
    return type(tr)(**rows)._replace(mask=mask)


def policy_samples(
    plant: Plant,
    K: jax.Array,
    key: jax.Array,
    count: int,
    *,
    mode: str = "trajectory",
    gamma: float = 0.99,
) -> Transitions:
    """``count`` transitions from running the policy ``K`` (see module doc): what
    ``plant.rollout`` flies, gains ``[horizon, m, n]`` or, for a plant flown by MPC
    (:mod:`loopid.algorithms.mpc_plant`), the model's parameters."""
    if mode == "trajectory":
        k_roll, k_draw = jax.random.split(key)
        runs = -(-count // plant.horizon)
        tr = jax.vmap(lambda k: plant.rollout(K, k))(jax.random.split(k_roll, runs))
        return draw(flatten(tr), k_draw, count)
    if mode == "geometric":
        k_roll, k_stop = jax.random.split(key)
        steps = geometric_steps(k_stop, count, gamma, plant.horizon)
        tr = jax.vmap(lambda k: plant.rollout(K, k))(jax.random.split(k_roll, count))
        kept = jax.tree_util.tree_map(lambda a: a[jnp.arange(count), steps], tr)
        # a run cut by the safe region before step L restarted from μ: its step L is not a draw
        # of this trajectory, so it is dropped (masked) rather than taken from the restart
        return _keep_only(kept, kept.t == steps)
    raise ValueError(f"unknown sampling mode {mode!r}; choose one of {SAMPLING_MODES}")
