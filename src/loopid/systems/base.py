"""What the loop needs to know about a JAX system: its step, error coordinates and noise
(:class:`Dynamics`), and the task it is flown on (:class:`Task`, :func:`trajectory_cost`).

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
import jax.numpy as jnp


class Dynamics(NamedTuple):
    """The pure functions of one system (see the module docstring) and its sizes."""

    step_delayed: Callable[..., tuple[jax.Array, jax.Array]]
    to_error: Callable[[jax.Array, jax.Array], jax.Array]
    from_error: Callable[[jax.Array, jax.Array], jax.Array]
    noise_sequence: Callable[..., jax.Array]
    n_error: int
    n_action: int
    columns: bool = False


class Task(NamedTuple):
    """One task of a system: the target it tracks, its start, noise, delay and quadratic cost.

    Fields: ``name``; ``target`` [T, n_x] (the target states x*_0..x*_{T−1}); ``noise_std``
    (the process noise's std, in the system's noise units); ``delay`` d (steps); ``Q``
    [n, n] over the error coordinates, ``R`` [m, m] over the commanded actions; ``x0`` [n_x]
    the start state; ``time_varying`` (whether the target moves). The helicopter's tasks are
    :func:`loopid.systems.helicopter.tasks.make_task`; a linear test system's
    :func:`loopid.systems.linear.linear_task`.
    """

    name: str
    target: jax.Array
    noise_std: float
    delay: int
    Q: jax.Array
    R: jax.Array
    x0: jax.Array
    time_varying: bool

    @property
    def horizon(self) -> int:
        """Number of actions, T − 1."""
        return self.target.shape[0] - 1


def trajectory_cost(dX: jax.Array, dU: jax.Array, Q: jax.Array, R: jax.Array) -> jax.Array:
    """Total cost Σ_t dX_tᵀ Q dX_t + Σ_t dU_tᵀ R dU_t of dX [T, n] and dU [T−1, m]; scalar."""
    return jnp.einsum("ti,ij,tj->", dX, Q, dX) + jnp.einsum("ti,ij,tj->", dU, R, dU)
