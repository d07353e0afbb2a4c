"""The planner's settings and their checks, shared by :func:`loopid.control.plan`,
:func:`loopid.control.mpc_rollout`, :func:`loopid.control.replanner` and
:class:`loopid.control.MPCController`. They run in Python before any tracing, reading shapes
only (``jax.eval_shape``: nothing is computed), so a bad size or setting is a one-line
``ValueError`` naming it.

- sizes: :func:`positive_int` (horizons, iteration counts), :func:`check_every` (the steps
  between re-plans, 1 <= every <= horizon);
- the problem: :func:`check_problem`, ``x0 [n]``, ``U0 [T, m]``,
  ``dynamics(params, x [n], u [m], t) -> [n]`` and ``cost(x, u, t) -> scalar``;
- actions: :func:`initial_actions` (``U0`` as ``[horizon, m]``) and
  :func:`alternative_actions` (``[A, horizon, m]``);
- iLQR's numeric settings as the traced :class:`Settings` (:func:`ilqr_settings`): changing them
  does not recompile.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from loopid.control._checks import check_finite, shape_of
from loopid.control.ilqr import check_settings

__all__ = [
    "Settings",
    "alternative_actions",
    "check_every",
    "check_problem",
    "ilqr_settings",
    "initial_actions",
    "positive_int",
]


def positive_int(name: str, value, hint: str = "") -> int:
    """``value`` as an int >= 1; ``ValueError`` naming ``name`` (and ``hint``, e.g. an upper
    bound) otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive int{hint}, got {value!r}")
    return int(value)


def check_every(every, horizon: int) -> int:
    """``every`` (the steps between re-plans) as an int in [1, ``horizon``]; ``ValueError``
    otherwise."""
    if (
        isinstance(every, bool)
        or not isinstance(every, int | np.integer)
        or not (1 <= every <= horizon)
    ):
        raise ValueError(f"every must be an int in [1, horizon={horizon}], got {every!r}")
    return int(every)


def check_problem(dynamics, cost, params, x0, U0, t0=0) -> tuple[int, int]:
    """Shapes of x0 [n] and U0 [T, m] and of what dynamics/cost return (jax.eval_shape);
    returns ``(n, m)``."""
    sx = shape_of("x0", x0)
    sU = shape_of("U0", U0)
    if len(sx) != 1:
        raise ValueError(f"x0 must have shape [n], got shape {sx}")
    if len(sU) != 2 or sU[0] < 1:
        raise ValueError(f"U0 must have shape [T, m] with T >= 1, got shape {sU}")
    x = jax.ShapeDtypeStruct(sx, jnp.float64)
    u = jax.ShapeDtypeStruct(sU[1:], jnp.float64)
    t = jax.ShapeDtypeStruct((), jnp.asarray(t0).dtype)
    x_next = jax.eval_shape(dynamics, params, x, u, t)
    if x_next.shape != sx:
        raise ValueError(f"dynamics(params, x0, U0[0], t) must have shape {sx}, got {x_next.shape}")
    c = jax.eval_shape(cost, x, u, t)
    if c.shape != ():
        raise ValueError(f"cost(x0, U0[0], t) must be a scalar, got shape {c.shape}")
    return sx[0], sU[1]


def initial_actions(U0, horizon: int) -> tuple[Array, int]:
    """``U0`` as ``[horizon, m]``: a ``[m]`` vector is repeated, ``[horizon, m]`` kept."""
    s = shape_of("U0", U0)
    if len(s) == 1:
        U0 = jnp.broadcast_to(jnp.asarray(U0, jnp.float64), (horizon, s[0]))
    elif len(s) != 2 or s[0] != horizon:
        raise ValueError(f"U0 must have shape [m] or [horizon={horizon}, m], got shape {s}")
    check_finite("U0", U0)
    return jnp.asarray(U0, jnp.float64), int(U0.shape[-1])


def alternative_actions(alternatives, horizon: int, m: int):
    """``alternatives`` as ``[A, horizon, m]`` (``[A, m]``: constant actions), or None."""
    if alternatives is None:
        return None
    s = shape_of("alternatives", alternatives)
    A = jnp.asarray(alternatives, jnp.float64)
    if len(s) == 2 and s[1] == m and s[0] >= 1:
        A = jnp.broadcast_to(A[:, None, :], (s[0], horizon, m))
    elif not (len(s) == 3 and s[0] >= 1 and s[1:] == (horizon, m)):
        raise ValueError(
            f"alternatives must have shape [A, {m}] or [A, horizon={horizon}, {m}] with A >= 1, "
            f"got shape {s}"
        )
    check_finite("alternatives", alternatives)
    return A


class Settings(NamedTuple):
    """iLQR's numeric settings (traced, so changing them does not recompile)."""

    alphas: Array
    tol: Array
    atol: Array
    mu_init: Array
    mu_min: Array
    mu_max: Array
    mu_factor: Array


def ilqr_settings(alphas, tol, atol, mu_init, mu_min, mu_max, mu_factor) -> Settings:
    """:class:`Settings` from :func:`loopid.control.ilqr`'s settings, checked
    (:func:`~loopid.control.ilqr.check_settings`), as float64 arrays."""
    alphas = check_settings(alphas, mu_init, mu_min, mu_max, mu_factor)
    f = lambda v: jnp.asarray(v, jnp.float64)  # noqa: E731
    return Settings(alphas, f(tol), f(atol), f(mu_init), f(mu_min), f(mu_max), f(mu_factor))
