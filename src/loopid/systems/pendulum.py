"""Gymnasium's Pendulum-v1 as pure JAX functions, and a Gymnasium env that starts it hanging down.

The dynamics and cost are those of ``gymnasium/envs/classic_control/pendulum.py`` (gymnasium 1.x),
operation for operation, in float64. State ``x = (θ, θ̇)`` with θ = 0 upright, θ = π hanging;
action ``u [1]`` a torque; parameters :class:`PendulumParams` (g = 10, m = l = 1, dt = 0.05,
``|θ̇| ≤ 8``, ``|u| ≤ 2``)::

    ū     = clip(u, −u_max, u_max)
    θ̇'    = clip(θ̇ + (3g/(2l) sin θ + 3/(m l²) ū) dt, −θ̇_max, θ̇_max)
    θ'    = θ + θ̇' dt
    c(x, u) = angle_normalize(θ)² + 0.1 θ̇² + 0.001 ū²        (Gym's reward is −c)

with ``angle_normalize(a) = ((a + π) mod 2π) − π``. Observations are ``o = (cos θ, sin θ, θ̇)``
(float32 in the env). :func:`step` and :func:`cost` equal the env's step to 1e-12 for float64
actions; with a float32 action (what :class:`~loopid.systems.GymSystem` sends) the env computes
its 0.001 ū² term in float32, ~5e-11 off.

Error coordinates (those of :class:`loopid.systems.GymSystem` with ``observe`` = all three
entries, target ``o* = (1, 0, 0)`` (upright, at rest) and ``a_op = 0``)::

    Δx = [cos θ − 1, sin θ, θ̇, 1]  [4],      Δu = u  [1].

:func:`step_obs` is the dynamics in these coordinates (θ recovered as ``atan2(sin θ, cos θ)``),
so a planner in Δx sees exactly what the loop records. A quadratic cost
``ΔxᵀQΔx`` with ``Q = diag(1, 1, q, 0)`` is ``2 − 2 cos θ + q θ̇²``: smooth, and ≈ θ² + q θ̇² near
upright (Gym's θ² term has a kink at θ = ±π, which gradient-based planners cannot use).

Gradients and the clips: ``jnp.clip`` has zero derivative outside its range, so for ``|u| > u_max``
the torque has no effect and no gradient (B = 0), and above ``|θ̇| = θ̇_max`` the speed is frozen.
The dynamics keep both clips (they are what the env does); planners keep the torque inside the
limit with a smooth penalty on ``|u| > u_max`` (:class:`loopid.control.Penalized`), and
a swing-up never needs ``|θ̇|`` near 8 (θ̇² ≤ 2·3g/(2l)·2 = 60 from rest at the bottom to upright).

:class:`PendulumHangingEnv` (``gymnasium.make("loopid/PendulumHanging-v0")``) is Pendulum-v1
with a different reset: θ = π + U(−noise, noise), θ̇ = 0. Pendulum-v1's own reset options
(``x_init``, ``y_init``) draw θ ∈ [−x_init, x_init], always centred on upright, so they cannot
give a hanging start.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from gymnasium.envs.classic_control.pendulum import PendulumEnv
from jax import Array

__all__ = [
    "TARGET",
    "PendulumHangingEnv",
    "PendulumParams",
    "angle_normalize",
    "cost",
    "cost_obs",
    "from_error",
    "observe",
    "step",
    "step_obs",
    "to_error",
]

TARGET = np.array([1.0, 0.0, 0.0])
"""The target observation o* = (cos 0, sin 0, 0): upright and at rest."""


class PendulumParams(NamedTuple):
    """Physical constants of Pendulum-v1 (its defaults); any field may be a traced JAX scalar."""

    g: float = 10.0
    m: float = 1.0
    l: float = 1.0
    dt: float = 0.05
    max_speed: float = 8.0
    max_torque: float = 2.0


DEFAULT = PendulumParams()


def angle_normalize(a):
    """Gym's ``((a + π) mod 2π) − π``: the angle in [−π, π)."""
    return ((a + jnp.pi) % (2 * jnp.pi)) - jnp.pi


def step(x: Array, u: Array, t=None, params: PendulumParams = DEFAULT) -> Array:
    """One Pendulum-v1 step in state form: ``x [2] = (θ, θ̇)``, ``u [1]`` -> ``x' [2]``.

    ``t`` is unused (the system is time-invariant; it is there for the ``(x, u, t)`` convention).
    """
    g, m, l, dt, max_speed, max_torque = params
    th, thdot = x[0], x[1]
    ub = jnp.clip(u[0], -max_torque, max_torque)
    newthdot = thdot + (3 * g / (2 * l) * jnp.sin(th) + 3.0 / (m * l**2) * ub) * dt
    newthdot = jnp.clip(newthdot, -max_speed, max_speed)
    newth = th + newthdot * dt
    return jnp.stack([newth, newthdot])


def cost(x: Array, u: Array, t=None, params: PendulumParams = DEFAULT) -> Array:
    """Gym's cost of one step (the negated reward): ``angle_normalize(θ)² + 0.1 θ̇² + 0.001 ū²``
    with ``ū`` the clipped torque; ``x [2]``, ``u [1]`` -> scalar."""
    ub = jnp.clip(u[0], -params.max_torque, params.max_torque)
    return angle_normalize(x[0]) ** 2 + 0.1 * x[1] ** 2 + 0.001 * (ub**2)


def cost_obs(dx: Array, du: Array, t=None, params: PendulumParams = DEFAULT) -> Array:
    """Gym's cost in error coordinates: ``θ² + 0.1 θ̇² + 0.001 ū²`` with θ = atan2(Δx₁, Δx₀ + 1)
    (= angle_normalize(θ) up to rounding), ``Δx [4]``, ``Δu [1]`` -> scalar.

    The planning cost of the swing-up (with a torque penalty, see the module docstring of
    :mod:`loopid.control.plan`): its gradient does not vanish at the bottom, where the
    quadratic ``ΔxᵀQΔx`` looks like a minimum to iLQR's Gauss-Newton model."""
    return cost(from_error(dx), du, t, params)


def observe(x: Array) -> Array:
    """Gym's observation ``(cos θ, sin θ, θ̇)``: ``x [..., 2]`` -> ``[..., 3]``."""
    return jnp.stack([jnp.cos(x[..., 0]), jnp.sin(x[..., 0]), x[..., 1]], axis=-1)


def to_error(x: Array) -> Array:
    """``Δx = [cos θ − 1, sin θ, θ̇, 1]``: ``x [..., 2]`` -> ``[..., 4]``."""
    o = observe(x)
    one = jnp.ones((*o.shape[:-1], 1), o.dtype)
    return jnp.concatenate([o - jnp.asarray(TARGET), one], axis=-1)


def from_error(dx: Array) -> Array:
    """The state ``(θ, θ̇)`` of ``Δx [..., 4]``, with θ = atan2(sin θ, cos θ) ∈ (−π, π]."""
    th = jnp.arctan2(dx[..., 1], dx[..., 0] + 1.0)
    return jnp.stack([th, dx[..., 2]], axis=-1)


def step_obs(dx: Array, du: Array, t=None, params: PendulumParams = DEFAULT) -> Array:
    """Pendulum-v1 in error coordinates: ``Δx [4]``, ``Δu [1]`` -> ``Δx' [4]`` (differentiable
    except through the clips, see the module docstring). ``Δx`` need not lie on the circle:
    only the direction of (cos θ, sin θ) is read."""
    return to_error(step(from_error(dx), du, t, params))


class PendulumHangingEnv(PendulumEnv):
    """Pendulum-v1 started hanging down: θ = π + U(−noise, noise), θ̇ = 0.

    Everything but the reset is Pendulum-v1's (dynamics, reward, spaces). ``noise`` (radians,
    default 0: exactly hanging) is a constructor argument and may be overridden per reset with
    ``options={"noise": value}``; other options are ignored. Registered as
    ``loopid/PendulumHanging-v0`` (200 steps, like Pendulum-v1).
    """

    def __init__(self, render_mode: str | None = None, g: float = 10.0, noise: float = 0.0):
        super().__init__(render_mode=render_mode, g=g)
        self.noise = _check_noise(noise)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)  # seeds np_random (and draws Pendulum's own start, replaced)
        noise = self.noise
        if options is not None and "noise" in options:
            noise = _check_noise(options["noise"])
        th = np.pi + (self.np_random.uniform(-noise, noise) if noise > 0 else 0.0)
        self.state = np.array([th, 0.0])
        self.last_u = None
        return self._get_obs(), {}


def _check_noise(noise) -> float:
    value = float(noise)
    if not (np.isfinite(value) and 0.0 <= value <= np.pi):
        raise ValueError(f"noise must be a number in [0, pi], got {noise!r}")
    return value
