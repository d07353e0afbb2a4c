"""The delayed closed-loop step, written once: how a controller's change reaches the system under
each reading of an actuation delay of d steps.

Two readings (the scenario field ``delay_mode``, one of the experiment's readings):

- ``"fifo"``: the controller commands ``Δu_t = −K_t Δx_t`` from the current error and the system
  applies the change commanded d steps earlier (a FIFO of commands, zeros at the start). The
  memory is the d pending commands, ``[d, m, ...]``.
- ``"latency"``: the controller acts on the error observed d steps earlier, ``Δu_t = −K_{t−d}
  Δx_{t−d}`` (zero vectors before the first d observations, so ``Δu_t = 0`` for t < d), and its
  change acts at once, ``x_{t+1} = f(x_t, Δu_t)``. The memory is the last d observed errors,
  ``[d, n, ...]``.

For any fixed gain both apply the same change at every step, so the closed loop is the same; what
differs is what a learner records as the action of a transition (the command, or the change that
acted).

A :class:`DelayedLoop` splits one step of any closed loop in two: :meth:`~DelayedLoop.sense`
(what the controller sees, and the time of the gain it uses) and :meth:`~DelayedLoop.act`
(advance the system and the memory). The training rollouts, the test flights, the drawn
trajectories and model-predictive control all step through it. Batch axes trail (``dx [n,
...]``, ``du [m, ...]``, ``memory [d, ·, ...]``), so the column-batched test rollouts
(:meth:`loopid.algorithms.plant.Plant.eval_seeds`) use it unchanged.
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

#: The readings of a delay: ``fifo`` or ``latency`` (module docstring).
DELAY_MODES = ("fifo", "latency")

#: ``step_delayed(x, fifo, du, w) -> (x_next, fifo_next)``: the system's step with a FIFO of
#: pending changes (:func:`loopid.systems.helicopter.step_delayed` and every other system's).
StepDelayed = Callable[[jax.Array, jax.Array, jax.Array, jax.Array], tuple[jax.Array, jax.Array]]


class DelayedLoop(NamedTuple):
    """A delay of ``d`` steps under the reading ``mode`` (module docstring); static, hashable."""

    mode: str
    d: int

    @property
    def latency(self) -> bool:
        """Whether the controller acts on an old observation (``mode == "latency"``)."""
        return self.mode == "latency"

    def memory0(self, n: int, m: int, batch: tuple[int, ...] = ()) -> jax.Array:
        """The empty memory: ``[d, n, *batch]`` observations (latency) or ``[d, m, *batch]``
        commands (fifo), zeros."""
        return jnp.zeros((self.d, n if self.latency else m, *batch), jnp.float64)

    def sense(
        self, memory: jax.Array, dx: jax.Array, tau
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``(seen, tau_gain, memory)``: the error the controller acts on now, the time index of
        the gain it uses, and the memory after observing ``dx`` at time ``tau``. Under ``fifo``:
        ``(dx, tau, memory)``; under ``latency``: the error of ``d`` steps ago, ``max(tau − d,
        0)``, and the memory shifted by one observation."""
        if not self.latency:
            return dx, tau, memory
        observed = jnp.concatenate([memory, dx[None]], axis=0)
        return observed[0], jnp.maximum(tau - self.d, 0), observed[1:]

    def act(
        self, step: StepDelayed, x: jax.Array, memory: jax.Array, du: jax.Array, w: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """``(x_next, memory_next)``: the system stepped from ``x`` with the change ``du`` and
        process noise ``w``. Under ``fifo`` the change joins the pending commands and the oldest
        acts; under ``latency`` it acts at once (``memory`` is already the one :meth:`sense`
        returned)."""
        if not self.latency:
            return step(x, memory, du, w)
        x_next, _ = step(x, jnp.zeros((0, *du.shape), du.dtype), du, w)
        return x_next, memory


def check_delay_mode(delay_mode: str) -> None:
    """One-line ``ValueError`` unless ``delay_mode`` is one of :data:`DELAY_MODES`."""
    if delay_mode not in DELAY_MODES:
        raise ValueError(f"delay_mode must be one of {', '.join(DELAY_MODES)}, got {delay_mode!r}")
