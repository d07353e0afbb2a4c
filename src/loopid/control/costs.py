"""The costs the planner (:func:`loopid.control.plan`, :mod:`loopid.control.mpc`) is used with,
``cost(x [n], u [m], t) -> scalar``, hashable, so that a cost passed as a static ``jit`` argument
shares compiled code: :class:`QuadraticCost` (built by :func:`quadratic_cost`), and
:class:`Penalized`, any cost plus :func:`action_penalty`.

Clipped actions: a clip in the dynamics has zero derivative outside its range, so iLQR cannot
see that a larger torque does nothing; :class:`QuadraticCost` adds a smooth penalty
``w Σ_i max(|u_i| − u_limit, 0)²`` that keeps the plan inside the limit (Pendulum-v1:
:mod:`loopid.systems.pendulum`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

__all__ = ["Penalized", "QuadraticCost", "action_penalty", "quadratic_cost"]


def action_penalty(u, u_limit: float, weight: float):
    """``weight Σ_i max(|u_i| − u_limit, 0)²``: zero inside the limit, C¹, quadratic outside."""
    return weight * jnp.sum(jnp.maximum(jnp.abs(u) - u_limit, 0.0) ** 2)


@dataclass(frozen=True)
class Penalized:
    """``cost(x, u, t) + weight Σ_i max(|u_i| − u_limit, 0)²`` (:func:`action_penalty`).

    Keeps a plan inside an action limit that the dynamics enforce with a clip (module
    docstring). Hashable (by ``cost``'s identity and the two numbers), so a ``Penalized`` made
    twice from the same function shares compiled code."""

    cost: Callable
    u_limit: float
    weight: float = 100.0

    def __post_init__(self):
        if not callable(self.cost):
            raise TypeError(f"cost must be callable, got {self.cost!r}")
        _check_limit(self.u_limit, self.weight)

    def __call__(self, x, u, t=None):
        return self.cost(x, u, t) + action_penalty(u, self.u_limit, self.weight)


@dataclass(frozen=True)
class QuadraticCost:
    """``c(x, u, t) = xᵀQx + uᵀRu (+ weight Σ_i max(|u_i| − u_limit, 0)² when u_limit is
    set)``. Frozen and hashable by value (Q and R are kept as nested tuples), so two equal costs
    share compiled code. Build it with :func:`quadratic_cost`."""

    Q: tuple
    R: tuple
    u_limit: float | None = None
    weight: float = 100.0

    def __call__(self, x, u, t=None):
        Q = jnp.asarray(self.Q, jnp.float64)
        R = jnp.asarray(self.R, jnp.float64)
        c = x @ Q @ x + u @ R @ u
        if self.u_limit is not None:
            c = c + action_penalty(u, self.u_limit, self.weight)
        return c


def _check_limit(u_limit, weight) -> None:
    if u_limit is not None and not (np.isfinite(u_limit) and u_limit > 0):
        raise ValueError(f"u_limit must be a positive number or None, got {u_limit!r}")
    if not (np.isfinite(weight) and weight >= 0):
        raise ValueError(f"weight must be a non-negative number, got {weight!r}")


def quadratic_cost(Q, R, *, u_limit: float | None = None, weight: float = 100.0) -> QuadraticCost:
    """:class:`QuadraticCost` from ``Q [n, n]``, ``R [m, m]``, an optional action limit
    ``u_limit > 0`` and the penalty ``weight >= 0``; ValueError naming a bad value."""
    Q = np.asarray(Q, np.float64)
    R = np.asarray(R, np.float64)
    if Q.ndim != 2 or Q.shape[0] != Q.shape[1] or R.ndim != 2 or R.shape[0] != R.shape[1]:
        raise ValueError(f"Q and R must be square matrices, got shapes {Q.shape} and {R.shape}")
    _check_limit(u_limit, weight)
    as_tuple = lambda A: tuple(tuple(float(v) for v in row) for row in A)  # noqa: E731
    limit = None if u_limit is None else float(u_limit)
    return QuadraticCost(as_tuple(Q), as_tuple(R), limit, float(weight))
