"""Rollouts: open loop through any dynamics, closed loop of (time-varying) linear policies.

Problem convention shared by the solvers: ``dynamics(x, u, t) -> x_next`` with ``x [n]``,
``u [m]``, integer step ``t``; trajectories ``X [T+1, n]``, ``U [T, m]``. Everything here is a
``lax.scan`` (jittable, vmappable over leading batch axes by ``jax.vmap``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from loopid.control._checks import check_shape, shape_of

__all__ = ["Rollout", "linear_rollout", "rollout", "tracking_rollout"]


class Rollout(NamedTuple):
    """A trajectory: states ``X [T+1, n]`` (X[0] = x0) and the actions applied ``U [T, m]``."""

    X: Array
    U: Array


def rollout(dynamics, x0: Array, U: Array) -> Array:
    """Open loop: X[0] = x0, X[t+1] = dynamics(X[t], U[t], t); returns ``X [T+1, n]``."""
    T = U.shape[0]

    def body(x, inputs):
        u, t = inputs
        x_next = dynamics(x, u, t)
        return x_next, x_next

    _, X = jax.lax.scan(body, x0, (U, jnp.arange(T)))
    return jnp.concatenate([x0[None], X], axis=0)


def tracking_rollout(dynamics, x0: Array, X_ref: Array, U_ref: Array, K: Array) -> Rollout:
    """Closed loop around a nominal: u_t = U_ref[t] - K[t] (x_t - X_ref[t]) (iLQR's policy).

    ``X_ref [T+1, n]``, ``U_ref [T, m]``, ``K [T, m, n]``; returns the :class:`Rollout`.
    """
    T = U_ref.shape[0]

    def body(x, inputs):
        x_ref, u_ref, K_t, t = inputs
        u = u_ref - K_t @ (x - x_ref)
        x_next = dynamics(x, u, t)
        return x_next, (x_next, u)

    _, (X, U) = jax.lax.scan(body, x0, (X_ref[:-1], U_ref, K, jnp.arange(T)))
    return Rollout(jnp.concatenate([x0[None], X], axis=0), U)


def linear_rollout(A, B, K, x0, *, k=None, c=None, W=None, T: int | None = None) -> Rollout:
    """Closed loop of a linear policy on a linear model.

        u_t = -K_t x_t - k_t,     x_{t+1} = A_t x_t + B_t u_t + c_t + W_t

    Args:
        A: ``[T, n, n]`` or ``[n, n]`` (time-invariant).
        B: ``[T, n, m]`` or ``[n, m]``.
        K: ``[T, m, n]`` or ``[m, n]`` (a steady-state gain, e.g. ``dlqr(...).K``).
        x0: ``[n]`` start state.
        k: ``[T, m]`` or ``[m]`` feedforward (default 0).
        c: ``[T, n]`` or ``[n]`` drift (default 0).
        W: ``[T, n]`` additive disturbance sequence (default 0; needs the time axis).
        T: horizon, needed only when no argument has a time axis.

    Returns:
        :class:`Rollout` with ``X [T+1, n]``, ``U [T, m]``. Batch with ``jax.vmap``.
    """
    sA = check_shape("A", A, (None, None))
    n = sA[-1]
    if sA[-2] != n:
        raise ValueError(f"A must be square, got shape {sA}")
    m = check_shape("B", B, (n, None))[-1]
    cores = {"A": (n, n), "B": (n, m), "K": (m, n), "k": (m,), "c": (n,), "W": (n,)}
    given = {"A": A, "B": B, "K": K, "k": k, "c": c, "W": W}
    horizons = {}
    for name, x in given.items():
        if x is None:
            continue
        s = check_shape(name, x, cores[name])
        if len(s) == len(cores[name]) + 1:
            horizons[name] = s[0]
        elif len(s) != len(cores[name]) or name == "W":
            want = "[T, " + ", ".join(map(str, cores[name])) + "]"
            raise ValueError(f"{name} must have shape {want} (or no T axis), got shape {s}")
    if len(set(horizons.values())) > 1:
        raise ValueError(f"time axes differ: {horizons}")
    if horizons:
        if T is not None and T not in horizons.values():
            raise ValueError(f"T = {T} disagrees with the time axes {horizons}")
        T = next(iter(horizons.values()))
    if T is None or T < 1:
        raise ValueError("T is required (and positive) when no argument has a time axis")
    if shape_of("x0", x0) != (n,):
        raise ValueError(f"x0 must have shape [{n}], got shape {shape_of('x0', x0)}")

    def full(name, x):
        core = cores[name]
        x = jnp.zeros(core, jnp.float64) if x is None else jnp.asarray(x, jnp.float64)
        return jnp.broadcast_to(x, (T, *core))

    seqs = [full(name, x) for name, x in given.items()]
    return _linear_rollout(jnp.asarray(x0, jnp.float64), *seqs)


@jax.jit
def _linear_rollout(x0, A, B, K, k, c, W) -> Rollout:
    def body(x, inputs):
        A_t, B_t, K_t, k_t, c_t, w_t = inputs
        u = -K_t @ x - k_t
        x_next = A_t @ x + B_t @ u + c_t + w_t
        return x_next, (x_next, u)

    _, (X, U) = jax.lax.scan(body, x0, (A, B, K, k, c, W))
    return Rollout(jnp.concatenate([x0[None], X], axis=0), U)
