"""Model-free policy-gradient baseline (paper section 6, footnote: "same as CPI, except gradient
descent is done directly on deterministic linear controller. We solve a linear system to estimate
the gradient from sample cost with perturbed parameters").

Parameters: a time-invariant gain offset ``θ [m, n]`` on the first policy of the model-based
methods (``K_t = K⁽¹⁾_t + θ``, ``θ_1 = 0``), so every method starts from the same π_1.
Iteration n ≥ 2 spends the same m transitions as the other methods: ``P = max(1, m // (2H))``
antithetic pairs of rollouts of ``H`` steps (*choice*: ``pg_horizon``). Pair j starts, CPI style,
from a restart state drawn like ν_t's states (target time ``τ_j`` uniform, error noise of
variance ``nu_state_var``), perturbs ``θ ± δ_j`` with ``δ_j ~ N(0, σ²I)`` and shares its process
noise between the two rollouts (common random numbers). With ``c_j^±`` the summed stage costs,
the gradient ``g`` is the minimum-norm least-squares solution of

    ⟨g, δ_j⟩ = (c_j⁺ − c_j⁻) / 2,   j = 1..P,

and the step is normalised, ``θ ← θ − η g / ‖g‖`` (*choice*: costs span orders of magnitude, a
raw gradient step has no usable scale). Rollout costs are capped like test costs (``cost_cap``).
"""

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.loop import Agent, Row, Trace, _trace, seed_keys, test_noise
from loopid.algorithms.plant import Plant

_TRAIN = 1


def run_policy_gradient(
    plant: Plant,
    agent: Agent,
    seeds,
    *,
    iterations: int,
    samples: int,
    n_test: int,
    horizon: int = 25,
    sigma: float = 0.01,
    step: float = 0.05,
    nu_state_var: float = 0.0025,
    cost_cap: float = 1e8,
    progress: Callable[[int, Row], None] | None = None,
) -> Trace:
    """Run the baseline on every seed; the result has the shape of every other method's."""
    H = int(horizon)
    if not 1 <= H <= plant.horizon:
        raise ValueError(f"pg_horizon must lie in [1, {plant.horizon}], got {horizon}")
    pairs = max(1, samples // (2 * H))
    keys = seed_keys(seeds)
    target = jnp.asarray(plant.task.target, jnp.float64)
    Q, R = jnp.asarray(plant.task.Q), jnp.asarray(plant.task.R)
    cap = float(cost_cap)
    K1, info = agent.policy(agent.init())
    m, n = plant.n_action, plant.n_state
    d = int(plant.task.delay)
    std = float(plant.task.noise_std)

    def short_cost(K, x, tau0, key):
        noise = plant.dynamics.noise_sequence(key, H, std)

        def body(carry, inp):
            x, fifo, total = carry
            w, k = inp
            tau = tau0 + k
            dx = plant.dynamics.to_error(x, target[tau])
            du = -K[tau] @ dx
            total = total + dx @ Q @ dx + du @ R @ du
            x, fifo = plant.dynamics.step_delayed(x, fifo, du, w)
            return (x, fifo, total), None

        fifo0 = jnp.zeros((d, m), jnp.float64)
        (_, _, total), _ = jax.lax.scan(body, (x, fifo0, jnp.float64(0.0)), (noise, jnp.arange(H)))
        return jnp.where(jnp.isfinite(total), jnp.minimum(total, cap), cap)

    def evaluate(theta, noise):
        costs, div = plant.test_costs(K1 + theta, noise)
        zero = jnp.float64(0.0)
        return Row(
            jnp.mean(costs),
            jnp.median(costs),
            jnp.sum(div),
            zero,
            zero,
            zero,
            jnp.int32(2 * pairs * H),  # every sample comes from the (perturbed) policy
            jnp.int32(2 * pairs * H),
            info.converged,
            info.spectral_radius,
            {},
        )

    def pg_step(theta, key, noise, it):
        k = jax.random.fold_in(jax.random.fold_in(key, _TRAIN), it)
        k_tau, k_x, k_delta, k_noise = jax.random.split(k, 4)
        tau = jax.random.randint(k_tau, (pairs,), 0, plant.horizon - H + 1)
        xi = jnp.sqrt(nu_state_var) * jax.random.normal(k_x, (pairs, n - 1), jnp.float64)
        dx0 = jnp.concatenate([xi, jnp.ones((pairs, 1))], axis=1)
        x0 = jax.vmap(plant.dynamics.from_error)(dx0, target[tau])
        delta = sigma * jax.random.normal(k_delta, (pairs, m, n), jnp.float64)
        nk = jax.random.split(k_noise, pairs)
        plus = jax.vmap(lambda dl, x, t, kk: short_cost(K1 + theta + dl, x, t, kk))(
            delta, x0, tau, nk
        )
        minus = jax.vmap(lambda dl, x, t, kk: short_cost(K1 + theta - dl, x, t, kk))(
            delta, x0, tau, nk
        )
        g, *_ = jnp.linalg.lstsq(delta.reshape(pairs, -1), (plus - minus) / 2.0)
        norm = jnp.linalg.norm(g)
        g = jnp.where(jnp.isfinite(norm) & (norm > 0), g / jnp.maximum(norm, 1e-300), 0.0)
        theta = theta - step * g.reshape(m, n)
        return theta, evaluate(theta, noise)

    noise = test_noise(plant, keys, n_test, "last").test
    start = jax.jit(jax.vmap(lambda w: evaluate(jnp.zeros((m, n)), w)))
    advance = jax.jit(jax.vmap(pg_step, in_axes=(0, 0, 0, None)))
    theta = jnp.zeros((keys.shape[0], m, n))
    row = start(noise)
    rows = [row]
    if progress:
        progress(1, row)
    for it in range(2, iterations + 1):
        theta, row = advance(theta, keys, noise, jnp.int32(it))
        rows.append(row)
        if progress:
            progress(it, row)
    return _trace(np.asarray(seeds), samples, rows)
