"""The linearised expert L: optimal control on the *true* simulator.

- Time-invariant tasks (hover): the true model linearised about the hover target in error
  coordinates (:func:`loopid.systems.helicopter.linearize`), steady-state LQR for the affine
  model (:func:`loopid.control.dlqr_affine`); the same gain at every step.
- Time-varying tasks (the funnel): iLQR on the noise-free true simulator along the target
  (:func:`loopid.control.ilqr`), whose local feedback policy ``u_t = Ū_t − K_t (Δx_t − ΔX̄_t)``
  around its own nominal trajectory ``X̄`` is written as an affine gain on the error coordinates.

Either way the result is ``K: [horizon, m, n]`` with ``u_t = −K_t Δx_t``, the policy format of
the loop; the expert is also the policy behind ν_e and ν_en.
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.control.ilqr import ilqr
from loopid.control.lqr_affine import dlqr_affine_unchecked
from loopid.systems import helicopter
from loopid.systems.base import Task


@jax.jit
def _linearised_lqr(x_star, x_star_next, Q, R):
    A, B = helicopter.linearize(x_star, x_star_next)
    return dlqr_affine_unchecked(A, B, Q, R)


def hover_expert_gain(task: Task) -> jax.Array:
    """The steady-state LQR gain ``[m, n]`` of the true model linearised about the target
    (one compiled program: linearisation and solve)."""
    target = jnp.asarray(task.target)
    sol = _linearised_lqr(target[0], target[1], jnp.asarray(task.Q), jnp.asarray(task.R))
    if not bool(sol.converged):
        raise RuntimeError("the linearised expert's LQR did not converge on the true model")
    return sol.K


def funnel_initial_actions(task: Task) -> np.ndarray:
    """iLQR's starting actions ``[T, 4]`` for the funnel (actions are control *changes*).

    A step to the hover trim at t = 0, then the rudder change that holds the circle's yaw rate
    ω = 2π/5 rad/s from the first circle step and its reversal after the last (the attitude cost
    is periodic in 4π of yaw, so a start without yaw ends in a local minimum that never turns
    nose-in). Without pads the circle starts at t = 0.
    """
    T = task.target.shape[0] - 1
    omega = 2 * np.pi / (helicopter.FUNNEL_STEPS_PER_CIRCLE * helicopter.DT)
    d_rudder = -helicopter.RATE_DAMPING[2] * omega / helicopter.CONTROL_GAIN[2]
    U0 = np.zeros((T, helicopter.N_ACTION))
    U0[0] = np.asarray(helicopter.hover_trim().u)
    if T + 1 > helicopter.FUNNEL_STEPS_PER_CIRCLE * helicopter.FUNNEL_CIRCLES:  # with pads
        U0[helicopter.FUNNEL_PAD, 2] += d_rudder
        U0[T + 1 - helicopter.FUNNEL_PAD, 2] -= d_rudder
    else:
        U0[0, 2] += d_rudder
    return U0


class FunnelProblem(NamedTuple):
    """The funnel expert's trajectory optimisation in :func:`loopid.control.ilqr`'s convention:
    ``dynamics(x, u, t)`` the noise-free raw-state step, ``cost(x, u, t) = Δx_tᵀ Q Δx_t +
    uᵀ R u`` with ``Δx_t = to_error(x, x*_t)``, the initial actions ``U0 [T, 4]``
    (:func:`funnel_initial_actions`) and the start ``x0 [21]``."""

    dynamics: Callable[[jax.Array, jax.Array, jax.Array], jax.Array]
    cost: Callable[[jax.Array, jax.Array, jax.Array], jax.Array]
    U0: jax.Array
    x0: jax.Array


def funnel_expert_problem(task: Task) -> FunnelProblem:
    """The problem :func:`funnel_expert_gains` solves for the funnel ``task``."""
    target = jnp.asarray(task.target, jnp.float64)
    zero_noise = jnp.zeros(helicopter.N_NOISE, jnp.float64)
    Q, R = jnp.asarray(task.Q), jnp.asarray(task.R)

    def dynamics(x, u, t):
        return helicopter.step(x, u, zero_noise)

    def cost(x, u, t):  # iLQR calls it with u = 0 at t = T
        dx = helicopter.to_error(x, target[t])
        return dx @ Q @ dx + u @ R @ u

    return FunnelProblem(dynamics, cost, jnp.asarray(funnel_initial_actions(task)), task.x0)


def funnel_expert_gains(task: Task, *, max_iter: int = 100) -> jax.Array:
    """iLQR on the true noise-free simulator along the target (:func:`funnel_expert_problem`),
    as affine error-coordinate gains."""
    target = jnp.asarray(task.target, jnp.float64)
    dynamics, cost, U0, x0 = funnel_expert_problem(task)
    sol = ilqr(dynamics, cost, jnp.asarray(x0), U0, max_iter=max_iter)
    if not bool(sol.converged):
        raise RuntimeError(f"the funnel expert's iLQR did not converge in {max_iter} iterations")
    return _error_coordinate_gains(sol.X, sol.U, sol.K, target)


@jax.jit
def _error_coordinate_gains(X, U, K, target):
    """``u_t = Ū_t − K_t (x_t − X̄_t)`` in raw coordinates as an affine gain on error coordinates:
    ``x_t − X̄_t ≈ J_t (Δx_t − ΔX̄_t)`` with ``J_t = ∂ from_error(Δx, x*_t) / ∂Δx`` at ``ΔX̄_t``."""
    dX = jax.vmap(helicopter.to_error)(X[:-1], target[:-1])
    J = jax.vmap(jax.jacfwd(helicopter.from_error))(dX, target[:-1])
    Kerr = jnp.einsum("tmx,txe->tme", K, J)
    n = dX.shape[-1]
    feedback = Kerr[:, :, : n - 1]
    ff = -(U + jnp.einsum("tme,te->tm", feedback, dX[:, : n - 1]))
    return jnp.concatenate([feedback, ff[:, :, None]], axis=-1)


def expert_gains(task: Task) -> jax.Array:
    """The expert's policy ``K: [horizon, m, n]`` for ``task`` (see the module docstring)."""
    horizon = task.target.shape[0] - 1
    if task.time_varying:
        return funnel_expert_gains(task)
    K = hover_expert_gain(task)
    return jnp.broadcast_to(K, (horizon, *K.shape))
