"""The policy-gradient baseline's rollouts (:mod:`loopid.algorithms.policy_gradient`): R
rollouts of ``H`` steps from μ, the test's start (τ = 0, an empty delay memory), one per gain
offset, each flying ``u_τ = −(K⁰_τ + θ_r) Δx_τ`` and scored by its capped log cost::

    ℓ_r = log min(Σ_τ Δx_τᵀQΔx_τ + Δu_τᵀRΔu_τ, cost_cap)      (non-finite: the cap)

under one process-noise draw shared by all (common random numbers) or a draw each. Shapes:
offsets ``θ [R, m, n]``, base ``K⁰ [T, m, n]``, noise ``[H, n_noise]`` or ``[R, H, n_noise]``;
result ``[R]`` (:func:`make_rollouts`).
"""

from collections.abc import Callable

import jax
import jax.numpy as jnp

from loopid.algorithms.closed_loop import DelayedLoop
from loopid.algorithms.plant import Plant, column_ops, halving_sum, quadratic_form


def make_rollouts(
    plant: Plant, base: jax.Array, H: int, cost_cap: float
) -> Callable[..., jax.Array | tuple[jax.Array, jax.Array]]:
    """``rollouts(offsets, noise, *, errors=False)``: the baseline's rollouts of ``H`` steps from
    μ (the test's start: τ = 0, an empty delay memory), one per gain offset.

    Rollout r flies ``u_τ = −(K⁰_τ + offsets[r]) Δx_τ`` (``offsets [R, m, n]``, ``base = K⁰ [T,
    m, n]``) under the process noise ``[H, n_noise]`` (one draw shared by all: common random
    numbers) or ``[R, H, n_noise]`` (a draw each), and scores its capped log cost ``log min(Σ_τ
    Δx_τᵀQΔx_τ + Δu_τᵀRΔu_τ, cost_cap)`` (a non-finite total counts as the cap); the result is
    ``[R]``, with ``errors`` also the error states visited ``[H, n, R]``.

    The R rollouts advance together as one column batch, ``x [n_x, R]``, like the test rollouts
    (:meth:`Plant.eval_seeds`): each state component is a contiguous vector over the rollouts,
    and each rollout's action is summed term by term over the n error coordinates (a batched
    ``@`` of R small matrices is slower on a CPU: 1.25x on the funnel's 500 rollouts). The
    baseline flies fixed gains, for which both delay readings are the same closed loop, so it
    steps as ``fifo``."""
    target = jnp.asarray(plant.task.target, jnp.float64)
    x0 = jnp.asarray(plant.task.x0, jnp.float64)
    m, n = plant.n_action, plant.n_state
    loop = DelayedLoop("fifo", int(plant.task.delay))
    step_columns, error_columns = column_ops(plant.dynamics)
    quad_Q, quad_R = quadratic_form(plant.task.Q), quadratic_form(plant.task.R)
    cap = float(cost_cap)

    def rollouts(offsets, noise, *, errors: bool = False):
        R = offsets.shape[0]
        gains = jnp.moveaxis(offsets, 0, -1)  # [m, n, R]
        shared = noise.ndim == 2
        ws = noise if shared else jnp.moveaxis(noise, 0, -1)  # [H, n_noise(, R)]

        def body(carry, inp):
            x, memory, total = carry
            w, tau = inp
            dx = error_columns(x, target[tau])
            seen, tau_gain, memory = loop.sense(memory, dx, tau)
            # rollout r's gain column j, base_t[:, j] + gains[:, j, r], formed where it is used,
            # and du computed once: otherwise XLA wrote all R gains [m, n, R] at every step
            # (3.3 MB for 10 funnel seeds) and re-read them in each of du's three consumers
            base_t = base[tau_gain]
            du = -halving_sum([(base_t[:, j, None] + gains[:, j]) * seen[j] for j in range(n)])
            du = jax.lax.optimization_barrier(du)
            total = total + quad_Q(dx) + quad_R(du)
            w = jnp.broadcast_to(w[:, None], (w.shape[0], R)) if shared else w
            x, memory = loop.act(step_columns, x, memory, du, w)
            return (x, memory, total), (dx if errors else None)

        x = jnp.broadcast_to(x0[:, None], (x0.shape[0], R))
        carry0 = (x, loop.memory0(n, m, (R,)), jnp.zeros(R, jnp.float64))
        taus = jnp.arange(H, dtype=jnp.int32)
        (_, _, total), dxs = jax.lax.scan(body, carry0, (ws, taus))
        total = jnp.where(jnp.isfinite(total), jnp.minimum(total, cap), cap)
        log_cost = jnp.log(jnp.maximum(total, jnp.finfo(jnp.float64).tiny))
        return (log_cost, dxs) if errors else log_cost

    return rollouts
