"""How good is the policy-gradient baseline's gradient estimate on hover? ("Limits" in
:mod:`loopid.algorithms.policy_gradient`).

Compares, at π_1 (θ = 0, the baseline's start), three directions with the exact gradient of the
test objective ``J_400(θ) = E_w[cost of 400 steps from μ]`` (autodiff through the simulator,
mean over ``N`` noise draws):

1. the exact gradient of the baseline's surrogate ``E_w[log cost of H steps from μ]``;
2. the exact gradient of the surrogate on *one* noise draw (what common random numbers see);
3. the baseline's finite-difference estimate from m = 500 transitions (one antithetic pair of
   H = 125 steps, :func:`~loopid.algorithms.policy_gradient_step.fd_gradient`).

For each it prints the cosine with ``∇J_400`` and the best ``J_400`` ratio along the direction
(a line search over step lengths with the exact objective), along ``−g`` and, as the control,
along ``+g``. Run: ``.venv/bin/python analysis/pg_gradient/pg_gradient_quality.py`` (~2 min on two
cores).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.policy_gradient_step import budget, fd_gradient
from loopid.experiments.families.helicopter import agent as agent_of
from loopid.experiments.families.helicopter import setup
from loopid.experiments.families.helicopter.scenario import scenario

N = 200  # noise draws for the exact expectations
TRIALS = 20  # finite-difference estimates drawn


def main() -> None:
    s = scenario("hover", samples=500)
    st = setup(s)
    plant = st.plant
    dyn = plant.dynamics
    agent = agent_of(s)
    K1, _ = agent.policy(agent.init())
    H, P = budget(s.samples, s.pg_horizon, plant.horizon)
    target = jnp.asarray(plant.task.target)
    x0 = jnp.asarray(plant.task.x0)
    Q, R = jnp.asarray(plant.task.Q), jnp.asarray(plant.task.R)
    m, n = plant.n_action, plant.n_state
    no_fifo = jnp.zeros((0, m))

    def cost(theta, noise):
        def body(carry, inp):
            x, total = carry
            w, tau = inp
            dx = dyn.to_error(x, target[tau])
            du = -(K1[tau] + theta) @ dx
            x, _ = dyn.step_delayed(x, no_fifo, du, w)
            return (x, total + dx @ Q @ dx + du @ R @ du), dx

        steps = noise.shape[0]
        (_, total), dxs = jax.lax.scan(body, (x0, 0.0), (noise, jnp.arange(steps)))
        return jnp.minimum(total, s.cost_cap), dxs

    keys = jax.random.split(jax.random.key(0), N)
    w400 = jax.vmap(lambda k: dyn.noise_sequence(k, 400, 1.0))(keys)
    j400 = jax.jit(lambda th: jnp.mean(jax.vmap(lambda w: cost(th, w)[0])(w400)))
    theta0 = jnp.zeros((m, n))
    base = float(j400(theta0))
    g400 = np.asarray(jax.jit(jax.grad(j400))(theta0))

    steps = np.logspace(-6, -1, 16)

    def report(g):
        """Cosine with ∇J_400 and the best J_400 ratio along −g and along +g (the control:
        a direction that lowers J_400 both ways carries curvature, not gradient, information)."""
        g = np.asarray(g)
        cos = float(np.sum(g * g400) / (np.linalg.norm(g) * np.linalg.norm(g400)))
        unit = jnp.asarray(g / np.linalg.norm(g))
        down = min(float(j400(-a * unit)) for a in steps) / base
        up = min(float(j400(a * unit)) for a in steps) / base
        return cos, down, up

    def surrogate(th, ws):
        return jnp.mean(jax.vmap(lambda w: jnp.log(cost(th, w)[0]))(ws))

    print(f"hover, π_1: J_400 = {base:.3e}; H = {H}, P = {P} antithetic pair(s) per iteration")

    def line(name, results):
        cs, down, up = np.array(results).reshape(-1, 3).T
        print(
            f"{name:<30} cos median {np.median(cs):+.3f}, best J_400 ratio along −g "
            f"{np.median(down):.3f}, along +g {np.median(up):.3f} ({len(cs)} draws)"
        )

    line("exact ∇E[log J_H]", [report(jax.grad(surrogate)(theta0, w400[:, :H]))])
    line(
        "exact ∇ on one noise draw",
        [report(jax.grad(surrogate)(theta0, w400[i : i + 1, :H])) for i in range(10)],
    )

    _, dxs = cost(theta0, w400[0, :H])
    rms = jnp.sqrt(jnp.mean(dxs**2, axis=0))
    floor = math.sqrt(s.nu_state_var)
    scale = jnp.maximum(rms, floor)
    fd = []
    for trial in range(TRIALS):
        k_eps, k_w = jax.random.split(jax.random.key(100 + trial))
        e = (s.pg_sigma / math.sqrt(n)) * jax.random.normal(k_eps, (P, m, n))
        ws = jax.vmap(lambda k: dyn.noise_sequence(k, H, 1.0))(jax.random.split(k_w, P))
        plus = jax.vmap(lambda d, w: jnp.log(cost(d / scale, w)[0]))(e, ws)
        minus = jax.vmap(lambda d, w: jnp.log(cost(-d / scale, w)[0]))(e, ws)
        g_scaled = fd_gradient(e, (plus - minus) / 2.0)
        fd.append(report(g_scaled / scale))  # the raw-gain direction the step takes
    line(f"FD estimate from m = {s.samples}", fd)


if __name__ == "__main__":
    main()
