"""The linearised expert L (SPEC §2): optimal control on the *true* simulator.

- Time-invariant tasks (hover): the true model linearised about the hover target in error
  coordinates (:func:`loopid.systems.helicopter.linearize`), steady-state LQR for the affine
  model (:func:`loopid.control.dlqr_affine`); the same gain at every step.
- Time-varying tasks (the funnel): iLQR on the noise-free true simulator along the target
  (:func:`loopid.control.ilqr`), whose local feedback policy ``u_t = Ū_t − K_t (Δx_t − ΔX̄_t)``
  around its own nominal trajectory ``X̄`` is written as an affine gain on the error coordinates.

Either way the result is ``K: [horizon, m, n]`` with ``u_t = −K_t Δx_t``, the policy format of
the loop; the expert is also the policy behind ν_e and ν_en.
"""

import jax
import jax.numpy as jnp

from loopid.control.lqr import dlqr_affine
from loopid.systems import helicopter
from loopid.systems.tasks import Task


def hover_expert_gain(task: Task) -> jax.Array:
    """The steady-state LQR gain ``[m, n]`` of the true model linearised about the target."""
    target = jnp.asarray(task.target)
    A, B = helicopter.linearize(target[0], target[1])
    sol = dlqr_affine(A, B, task.Q, task.R)
    if not bool(sol.converged):
        raise RuntimeError("the linearised expert's LQR did not converge on the true model")
    return sol.K


def funnel_expert_gains(task: Task, *, max_iter: int = 100) -> jax.Array:
    """iLQR on the true noise-free simulator along the target, as affine error-coordinate gains."""
    from loopid.control.ilqr import ilqr

    target = jnp.asarray(task.target, jnp.float64)
    T = target.shape[0] - 1
    m = helicopter.N_ACTION
    zero_noise = jnp.zeros(helicopter.N_NOISE, jnp.float64)
    Q, R = jnp.asarray(task.Q), jnp.asarray(task.R)

    def dynamics(x, u, t):
        return helicopter.step(x, u, zero_noise)

    def cost(x, u, t):
        dx = helicopter.to_error(x, target[t])
        return dx @ Q @ dx + jnp.where(t < T, u @ R @ u, 0.0)

    sol = ilqr(dynamics, cost, jnp.asarray(task.x0), jnp.zeros((T, m)), max_iter=max_iter)
    # u_t = Ū_t − K_t (x_t − X̄_t) in raw coordinates; x_t − X̄_t ≈ J_t (Δx_t − ΔX̄_t) with
    # J_t = ∂ from_error(Δx, x*_t) / ∂Δx at ΔX̄_t.
    dX = jax.vmap(helicopter.to_error)(sol.X[:-1], target[:-1])
    J = jax.vmap(jax.jacfwd(helicopter.from_error))(dX, target[:-1])
    Kerr = jnp.einsum("tmx,txe->tme", sol.K, J)
    n = dX.shape[-1]
    feedback = Kerr[:, :, : n - 1]
    ff = -(sol.U + jnp.einsum("tme,te->tm", feedback, dX[:, : n - 1]))
    return jnp.concatenate([feedback, ff[:, :, None]], axis=-1)


def expert_gains(task: Task) -> jax.Array:
    """The expert's policy ``K: [horizon, m, n]`` for ``task`` (see the module docstring)."""
    horizon = task.target.shape[0] - 1
    if task.time_varying:
        return funnel_expert_gains(task)
    K = hover_expert_gain(task)
    return jnp.broadcast_to(K, (horizon, *K.shape))
