"""The ν_t fit at one circle step of the funnel and the velocity-from-attitude block summaries.

Helpers of ``analysis/funnel_nu_t/funnel_nu_t.py`` (its section 2): where ν_t is centred
(:func:`centre_of`), ν_t's sampler with its target time fixed (:func:`sampler_at`, checked against
the real sampler by :func:`check_sampler`), the plain least-squares fit of one step
(:func:`least_squares`), the true simulator's Jacobian there (:func:`jacobian_at`), and the
summaries of a velocity-from-attitude block against the expert flight's, at one step
(:func:`summary`, :func:`fmt_block`) and over every circle step (:func:`circle_table`). Imported by
that script; run alone it does nothing.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

import loopid  # noqa: F401  (float64)
from loopid.algorithms.exploration import Centre, nu_trajectory
from loopid.experiments.families.helicopter import assembly
from loopid.models.linear_offset import to_matrices
from loopid.systems import helicopter as H

VEL, ATT = H.NED_DOT, slice(17, 20)  # error coordinates: velocity rows, attitude-error columns
CIRCLES = (H.FUNNEL_PAD, H.FUNNEL_PAD + H.FUNNEL_CIRCLES * H.FUNNEL_STEPS_PER_CIRCLE)


def centre_of(reading: str, plant, K_expert) -> Centre:
    """What ν_t draws around under ``reading`` (the target itself where the reading says None)."""
    c = assembly.nu_t_centre(reading, plant, K_expert)
    return Centre(plant.task.target) if c is None else c


# ----------------------------------------------------------------------------- 2. the fit
def sampler_at(plant, centre: Centre, tau: int, state_var: float, action_var: float):
    """:func:`loopid.algorithms.exploration.nu_trajectory`'s sampler with its target time fixed at
    ``tau`` (the same keys and draws otherwise, so each row equals the real sampler's row wherever
    that one drew ``tau``)."""
    states = jnp.asarray(centre.states, jnp.float64)
    actions = None if centre.actions is None else jnp.asarray(centre.actions, jnp.float64)
    n, m = plant.n_state, plant.n_action

    def sample(key, count):
        _, k_s, k_a, k_q = jax.random.split(key, 4)
        t = jnp.full((count,), tau, jnp.int32)
        xi = math.sqrt(state_var) * jax.random.normal(k_s, (count, n - 1), dtype=jnp.float64)
        dx = jnp.concatenate([xi, jnp.ones((count, 1), jnp.float64)], axis=1)
        x = jax.vmap(plant.dynamics.from_error)(dx, states[t])
        du = math.sqrt(action_var) * jax.random.normal(k_a, (count, m), dtype=jnp.float64)
        if actions is not None:
            du = actions[t] + du
        return jax.vmap(plant.query)(x, du, t, jax.random.split(k_q, count))

    return jax.jit(sample, static_argnums=1)


def check_sampler(plant, centre, tau, state_var, action_var, count: int = 30_000):
    """Rows of the real sampler that drew ``tau`` against the fixed-τ sampler's (same key):
    ``(rows compared, largest absolute difference)``; raises past 1e-12 (the raw states and
    actions are bit for bit the same; error coordinates differ in last bits, fused apart)."""
    key = jax.random.key(12345)
    real = nu_trajectory(plant, state_var=state_var, action_var=action_var, centre=centre)
    a = jax.device_get(jax.jit(real, static_argnums=1)(key, count))
    b = jax.device_get(sampler_at(plant, centre, tau, state_var, action_var)(key, count))
    hit = np.asarray(a.t) == tau
    worst = max(
        float(np.max(np.abs(np.asarray(getattr(a, f))[hit] - np.asarray(getattr(b, f))[hit])))
        for f in ("x", "dx", "du", "dx_next")
    )
    if not worst <= 1e-12:
        raise AssertionError(f"the fixed-τ sampler differs from the real sampler's by {worst}")
    return int(hit.sum()), worst


def least_squares(tr):
    """Plain least squares Δx_{τ+1}[:20] ≈ A Δx_τ + B Δu_τ (Δx's constant entry the intercept):
    ``(A [20, 21], B [20, 4], standard errors of A [20, 21], residual RMS)``."""
    Z = np.concatenate([np.asarray(tr.dx), np.asarray(tr.du)], axis=1)
    Y = np.asarray(tr.dx_next)[:, :20]
    coef, *_ = np.linalg.lstsq(Z, Y, rcond=None)
    resid = Y - Z @ coef
    dof = Z.shape[0] - Z.shape[1]
    var = np.sum(resid**2, axis=0) / dof  # per target
    inv = np.linalg.inv(Z.T @ Z)
    se = np.sqrt(np.outer(np.diag(inv), var))  # [25, 20]
    return coef[:21].T, coef[21:].T, se[:21].T, float(np.sqrt(np.mean(resid**2)))


def jacobian_at(target, tau: int, dx0, du0):
    """The true simulator's (noise-free) Jacobian of Δx_{τ+1} in Δx_τ, in error coordinates
    relative to the target, at ``(dx0, du0)``."""

    def g(dx, du):
        x = H.from_error(dx, target[tau])
        return H.to_error(H.step(x, du, jnp.zeros(H.N_NOISE)), target[tau + 1])

    return np.asarray(jax.jacfwd(g)(jnp.asarray(dx0), jnp.asarray(du0)))


def centre_point(centre: Centre, target, tau: int):
    """The centre's ``(Δx, Δu)`` at ``tau`` in the learner's error coordinates."""
    dx = H.to_error(jnp.asarray(centre.states[tau]), target[tau])
    du = jnp.zeros(H.N_ACTION) if centre.actions is None else jnp.asarray(centre.actions[tau])
    return dx, du


def summary(M, J) -> tuple[float, float]:
    """(projection ⟨M, J⟩/‖J‖², size ‖M‖/‖J‖) of the block M against the flight's block J."""
    return float(np.sum(M * J) / np.sum(J * J)), float(np.linalg.norm(M) / np.linalg.norm(J))


def fmt_block(M) -> str:
    return "[" + "; ".join(" ".join(f"{v:+.3f}" for v in row) for row in M) + "]"


def circle_table(st, finals, centres, target, flight, seeds, N) -> list[str]:
    """The block's projection on the flight's, at every circle step: the true J at each centre
    and D_t's learned models after the last iteration (medians over τ = 100..499)."""
    taus = np.arange(*CIRCLES)

    @jax.jit
    def flight_blocks(states, actions):
        def one(tau):
            dx = H.to_error(states[tau], target[tau])

            def g(d, du):
                x = H.from_error(d, target[tau])
                return H.to_error(H.step(x, du, jnp.zeros(H.N_NOISE)), target[tau + 1])

            return jax.jacfwd(g)(dx, actions[tau])[VEL, ATT]

        return jax.vmap(one)(jnp.asarray(taus))

    Jf = np.asarray(flight_blocks(jnp.asarray(flight.states), jnp.asarray(flight.actions)))
    lines = [
        "Over every circle step τ = 100..499 (400 steps): projection of each block on the flight's "
        "block at the same τ, median over τ (and seeds) [10th-90th percentile]:",
        "",
        "| block | projection | size |",
        "|---|---|---|",
    ]

    def row(name, blocks):
        p = np.sum(blocks * Jf, axis=(-2, -1)) / np.sum(Jf * Jf, axis=(-2, -1))
        s = np.linalg.norm(blocks, axis=(-2, -1)) / np.linalg.norm(Jf, axis=(-2, -1))
        q = np.percentile(p, [10, 90])
        lines.append(
            f"| {name} | {np.median(p):.3f} [{q[0]:.2f}, {q[1]:.2f}] | {np.median(s):.3f} |"
        )

    row("nominal model (heading)", np.asarray(st.nominal.A)[taus][:, VEL, ATT])
    for c in centres:
        centre = centre_of(c, st.plant, st.K_expert)
        acts = (
            jnp.zeros((target.shape[0] - 1, H.N_ACTION))
            if centre.actions is None
            else (jnp.asarray(centre.actions))
        )
        row(f"true J at centre `{c}`", np.asarray(flight_blocks(jnp.asarray(centre.states), acts)))
    for m, c in enumerate(centres):
        W = finals[m]["W"]
        A = np.stack(
            [np.asarray(to_matrices(st.nominal, W[s])[0])[taus] for s in range(len(seeds))]
        )
        row(f"D_t's learned model after it. {N}, `{c}`", A[:, :, VEL, ATT])
    return lines


if __name__ == "__main__":
    print("helpers of analysis/funnel_nu_t/funnel_nu_t.py: run that script")
