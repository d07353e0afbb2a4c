"""What the loop needs to know about a JAX system: its step, error coordinates and noise.

A :class:`Dynamics` bundles the pure functions of one real system so that
:func:`loopid.algorithms.plant.make_plant` can run any of them (the helicopter, a linear test
system, …) through the same rollouts, queries and tests. Conventions:

- ``step_delayed(x, fifo, du, noise) -> (x_next, fifo_next)``: raw state ``x``, pending commanded
  changes ``fifo [d, m]`` (d = 0 for no delay), commanded action ``du [m]``, process noise.
- ``to_error(x, x_star) -> dx [n]`` and ``from_error(dx, x_star) -> x``: error coordinates
  relative to a target state, whose last entry is the constant 1 (so linear models and
  controllers are affine).
- ``noise_sequence(key, T, std) -> [T, n_noise]``: the process noise of T steps.
- ``columns``: True when ``step_delayed`` and ``to_error`` also take column batches (vectors
  along the leading axis, any trailing batch axes: ``x [n_x, *B]``, ``fifo [d, m, *B]``, with
  ``x_star`` unbatched). The plant then runs every test trajectory of every seed in one such
  batch; otherwise it wraps the functions in ``jax.vmap`` over the trailing axes (same numbers,
  slower on a CPU).
"""

from collections.abc import Callable
from typing import NamedTuple

import jax


class Dynamics(NamedTuple):
    """The pure functions of one system (see the module docstring) and its sizes."""

    step_delayed: Callable[..., tuple[jax.Array, jax.Array]]
    to_error: Callable[[jax.Array, jax.Array], jax.Array]
    from_error: Callable[[jax.Array, jax.Array], jax.Array]
    noise_sequence: Callable[..., jax.Array]
    n_error: int
    n_action: int
    columns: bool = False
