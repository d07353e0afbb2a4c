"""One iteration of the model-free policy-gradient baseline
(:mod:`loopid.algorithms.policy_gradient`) for one seed, pure and jittable (:func:`make_pg_step`),
and its budget (:func:`budget`, :func:`spent`).

Parameters: a time-invariant gain offset ``θ [m, n]`` on a base gain ``K⁰`` (``K_t = K⁰_t + θ``,
``θ_1 = 0``), only on the *free* entries F
(:func:`~loopid.algorithms.policy_gradient.pg_base`). Iteration n ≥ 2 spends at most the m
transitions of the other methods, in ``R = P + 2`` rollouts of ``H`` steps (:func:`budget`) that
all start at the test's start μ and all see the same process noise ``w`` (common random
numbers; the rollouts: :mod:`loopid.algorithms.policy_gradient_rollouts`):

1. *Reference.* One rollout of ``θ``: its log cost ``ℓ_0`` and the RMS ``s_j`` of each error
   coordinate along it (the scale of coordinate j, floored at ``sqrt(nu_state_var)``).
2. *Probes.* P rollouts of ``θ + δ_i``, ``δ_i = (σ/√d) (ε_i ⊙ F) diag(1/s)``, ``ε_i ~ N(0, I)``,
   F the free mask, d the number of free gains; each gives ``ℓ_i − ℓ_0``, exactly the
   one-sided difference of the same noise draw's cost. Each (δ_i, ℓ_i − ℓ_0) enters a memory
   of the last ``L = max(d, P + 1)`` probes (a ring buffer).
3. *Gradient: the footnote's linear system.* In the current scaled coordinates ``e = δ diag(s)``,
   the minimum-norm least-squares ``g`` of ``⟨g, e_j⟩ = ℓ_j − ℓ_0^{(j)}`` over the memory
   (:func:`fd_gradient`; empty slots are zero rows, which do not change the solution).
4. *Conservative step.* The candidate ``θ' = θ − ρ (g/‖g‖) diag(1/s)`` is rolled out under the
   same noise ``w``; it enters the memory as a probe, and is accepted only if its log cost is
   below ``ℓ_0``. The trust radius ``ρ`` halves after a rejection and stays after an acceptance
   (``ρ_1 = pg_step · σ√m``).

Two readings of "samples", ``samples_mode`` (the scenario's ``pg_samples``):

- ``"transitions"`` (the measurements of :mod:`loopid.algorithms.policy_gradient`): a sample
  is one transition, as for every other method. Iteration n spends ``(P + 2)·H ≤ m`` of them:
  ``H = min(pg_horizon, T, m // 4)``, ``P = m // H − 2`` (hover, m = 500: H = 125, P = 2).
- ``"rollouts"`` (the scenarios' default): a sample is one rollout of the whole ``H =
  min(pg_horizon, T)`` steps with
  perturbed gains, scored by its cost. The m rollouts of an iteration are the reference, ``P =
  m − 2`` probes and the candidate, and step 3's system is ``E g = Δℓ`` with ``E [L, d]`` the
  scaled perturbations (``L ≥ P``), solved as ``g = E⁺ Δℓ``: with ``P ≥ d`` (hover: m ≥ 54,
  funnel: m ≥ 86) it is determined by one iteration's probes alone (the memory then holds
  them and the previous candidate), and on the shared draw ``w``
  ``ℓ(θ + δ) − ℓ(θ) = ⟨∇ℓ_w(θ) diag(1/s), e⟩ + O(σ²)``, so ``g`` is that draw's gradient up to
  curvature. Otherwise identical (steps 1-4); the rows count rollouts (``used = m``).

Two readings of the step, ``update`` (the scenario's ``pg_update``), for the footnote's "same as
CPI, except gradient descent is done directly on deterministic linear controller":

- ``"conservative"`` (this module's default and the ``literal`` preset's; steps 1-4 above): CPI's
  conservative update, a step of the trust radius along the normalised estimate, taken only if it
  lowers the cost on the shared draw. Under ``rollouts`` the sample count barely matters: once
  ``P ≥ d`` one shared draw determines the system, so ``g`` is that draw's gradient whatever m is
  (the estimates of m = 100 and m = 500 from the same key have cosine 0.95-0.99 on hover), and
  every step is accepted, so the radius never shrinks and θ moves by ρ_1 per iteration
  (``analysis/pg_gradient/pg_sample_count.py``). The pace is set by ρ_1, not by m.
- ``"descent"`` (the scenarios' default, preset ``probable``): plain gradient descent on noisy
  samples, ``θ ← θ − α g`` in scaled coordinates, always taken. Every rollout of an iteration has
  its own noise draw (a sample is one rollout's measured cost, as on a real system), so the
  estimate's noise falls as m grows: the paper's own account of its baseline (100 samples
  "insufficient to get good gradient estimates", 500 better). The step size α is set once, at the
  first iteration, so that the first step is as long as the first trust radius
  (``α = ρ_1 / ‖g_1‖``): no new setting; later steps scale with the estimate's length.

The memory holds ``L = max(d, P + 1)`` rollouts: d so that the system can be square from
several iterations' probes when P < d (the transitions reading: 2 probes a step); P + 1 so that
one iteration's P probes and its candidate fit, since a ring-buffer scatter of P > L probes
repeats slots (which write wins is then undefined) and would drop probes of the current draw.
(With the transitions reading on hover and funnel P + 1 ≤ d, so L = d as before.)
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.plant import Plant, ordered_sum
from loopid.algorithms.policy_gradient_rollouts import make_rollouts


class PGState(NamedTuple):
    """Per-seed state: the gain offset ``theta [m, n]``, the trust radius ``radius`` and the
    probe memory: raw-gain probes ``probes [L, m, n]``, their log-cost differences ``diffs [L]``,
    which slots hold one ``filled [L]``, and the next slot ``cursor`` (a ring buffer); under
    ``update = "descent"`` the step size ``alpha`` (0 until the first step sets it)."""

    theta: jax.Array
    radius: jax.Array
    probes: jax.Array
    diffs: jax.Array
    filled: jax.Array
    cursor: jax.Array
    alpha: jax.Array


class PGStep(NamedTuple):
    """What one iteration did (per seed): the reference and candidate log costs on the shared
    noise, whether the candidate was accepted, and the estimated gradient (scaled coordinates)."""

    log_ref: jax.Array
    log_cand: jax.Array
    accepted: jax.Array
    gradient: jax.Array


SAMPLES_MODES = ("transitions", "rollouts")
UPDATES = ("conservative", "descent")


def budget(
    samples: int, horizon: int, task_horizon: int, *, samples_mode: str = "transitions"
) -> tuple[int, int]:
    """Rollout length H and probe count P for m = ``samples`` per iteration (module docstring,
    "Two readings"). ``"transitions"``: ``H = min(horizon, task_horizon, m // 4)``, ``R = m // H``
    rollouts: one reference, one candidate and ``P = R − 2`` probes (so ``R·H ≤ m`` and
    ``P ≥ 2``). ``"rollouts"``: ``H = min(horizon, task_horizon)`` and ``R = m`` rollouts, so
    ``P = m − 2``. Both need m ≥ 4 (a reference, two probes, a candidate)."""
    if samples_mode not in SAMPLES_MODES:
        raise ValueError(f"pg_samples must be 'transitions' or 'rollouts', got {samples_mode!r}")
    if samples < 4:
        raise ValueError(
            f"the policy-gradient baseline needs samples >= 4 (a reference, two probes and a "
            f"candidate rollout), got {samples}"
        )
    if horizon < 1:
        raise ValueError(f"pg_horizon must be >= 1, got {horizon}")
    if samples_mode == "rollouts":
        return min(int(horizon), int(task_horizon)), samples - 2
    H = min(int(horizon), int(task_horizon), samples // 4)
    return H, samples // H - 2


def spent(samples: int, horizon: int, task_horizon: int, *, samples_mode: str = "transitions"):
    """What one iteration n ≥ 2 spends, in the unit of ``samples``: ``(P + 2)·H`` transitions
    (``"transitions"``, at most m) or ``P + 2 = m`` rollouts (``"rollouts"``)."""
    H, P = budget(samples, horizon, task_horizon, samples_mode=samples_mode)
    return P + 2 if samples_mode == "rollouts" else (P + 2) * H


def check_update(update: str) -> None:
    """One-line ``ValueError`` unless ``update`` is one of :data:`UPDATES`."""
    if update not in UPDATES:
        raise ValueError(f"pg_update must be one of {', '.join(UPDATES)}, got {update!r}")


def fd_gradient(perturbations: jax.Array, differences: jax.Array) -> jax.Array:
    """The footnote's linear system: the minimum-norm least-squares ``g`` of
    ``⟨g, δ_i⟩ = c(θ + δ_i) − c(θ)`` (or an antithetic half difference); ``perturbations
    [P, ...]``, result ``[...]``. Zero rows (δ_i = 0, difference 0) do not change the result."""
    P = perturbations.shape[0]
    g, *_ = jnp.linalg.lstsq(perturbations.reshape(P, -1), differences)
    return g.reshape(perturbations.shape[1:])


def init_state(free: jax.Array, radius: float, *, probes: int = 0) -> PGState:
    """θ = 0, ``radius``, an empty memory of ``L = max(d, probes + 1)`` slots (d = number of free
    gains, ``probes`` = P of :func:`budget`): the last d probes, and at least one iteration's P
    probes and candidate, so that no slot is written twice in one scatter."""
    L = max(int(np.asarray(free).sum()), int(probes) + 1)
    m, n = free.shape
    return PGState(
        jnp.zeros((m, n)), jnp.float64(radius), jnp.zeros((L, m, n)), jnp.zeros(L),
        jnp.zeros(L, bool), jnp.int32(0), jnp.float64(0.0),
    )  # fmt: skip


def make_pg_step(
    plant: Plant,
    base: jax.Array,
    free: jax.Array,
    *,
    samples: int,
    horizon: int,
    sigma: float,
    nu_state_var: float,
    cost_cap: float,
    samples_mode: str = "transitions",
    update: str = "conservative",
) -> Callable[[PGState, jax.Array], tuple[PGState, PGStep]]:
    """One iteration ``(state, key) -> (state, PGStep)`` for one seed (module docstring, steps
    1-4); pure, jittable, fixed shapes. ``samples_mode``: the reading of ``samples``
    (:func:`budget`); ``update``: the reading of the step (module docstring, "Two readings of
    the step"); the state's memory must hold ``P + 1`` rollouts
    (``init_state(free, radius, probes=P)``)."""
    check_update(update)
    H, P = budget(samples, horizon, plant.horizon, samples_mode=samples_mode)
    m, n = plant.n_action, plant.n_state
    free = jnp.asarray(free, jnp.float64)
    d = int(np.asarray(free).sum())
    std = float(plant.task.noise_std)
    floor = float(np.sqrt(nu_state_var)) if nu_state_var > 0 else 1.0
    rollouts = make_rollouts(plant, base, H, cost_cap)

    def remember(state: PGState, deltas, diffs) -> PGState:
        k, L = deltas.shape[0], state.probes.shape[0]
        slots = (state.cursor + jnp.arange(k, dtype=jnp.int32)) % L
        return state._replace(
            probes=state.probes.at[slots].set(deltas),
            diffs=state.diffs.at[slots].set(diffs),
            filled=state.filled.at[slots].set(True),
            cursor=(state.cursor + k) % L,
        )

    def step(state: PGState, key: jax.Array) -> tuple[PGState, PGStep]:
        if state.probes.shape[0] < P + 1:  # static: a scatter with repeated slots is undefined
            raise ValueError(
                f"the probe memory holds {state.probes.shape[0]} rollouts, one iteration needs "
                f"P + 1 = {P + 1}: use init_state(free, radius, probes={P})"
            )
        k_noise, k_eps = jax.random.split(key)
        if update == "descent":  # every rollout its own draw: [reference, P probes, candidate]
            draw = jax.vmap(lambda k: plant.dynamics.noise_sequence(k, H, std))
            ws = draw(jax.random.split(k_noise, P + 2))
            w, w_probes, w_cand = ws[0], ws[1 : P + 1], ws[P + 1]
        else:  # common random numbers: one draw for every rollout of the iteration
            w = plant.dynamics.noise_sequence(k_noise, H, std)
        log_ref, dxs = rollouts(state.theta[None], w, errors=True)
        log_ref = log_ref[0]
        rms = jnp.sqrt(ordered_sum(dxs[..., 0] ** 2, axis=0) / H)  # fixed order: chunk-invariant
        scale = jnp.where(jnp.isfinite(rms), jnp.maximum(rms, floor), floor)
        e = (sigma / np.sqrt(d)) * jax.random.normal(k_eps, (P, m, n), jnp.float64) * free
        delta = e / scale
        log_probe = rollouts(state.theta + delta, w_probes if update == "descent" else w)
        state = remember(state, delta, log_probe - log_ref)
        rows = jnp.where(state.filled[:, None, None], state.probes * scale, 0.0)
        g = fd_gradient(rows, jnp.where(state.filled, state.diffs, 0.0)) * free  # exact zeros
        norm = jnp.sqrt(ordered_sum((g * g).reshape(-1)))
        usable = jnp.isfinite(norm) & (norm > 0)
        if update == "descent":
            # plain gradient descent, θ ← θ − α g (scaled coordinates), always taken; α is set
            # once, so that the first step is as long as the first trust radius
            alpha = jnp.where(
                (state.alpha > 0) | ~usable,
                state.alpha,
                state.radius / jnp.where(usable, norm, 1.0),
            )
            step_ = jnp.where(usable, -alpha * g, 0.0) / scale
            log_cand = rollouts((state.theta + step_)[None], w_cand)[0]
            state = remember(state, step_[None], (log_cand - log_ref)[None])
            state = state._replace(theta=state.theta + step_, alpha=alpha)
            return state, PGStep(log_ref, log_cand, usable, g)
        direction = jnp.where(usable, g / jnp.where(usable, norm, 1.0), 0.0)
        step_ = -state.radius * direction / scale
        log_cand = rollouts((state.theta + step_)[None], w)[0]
        state = remember(state, step_[None], (log_cand - log_ref)[None])
        accepted = usable & jnp.isfinite(log_cand) & (log_cand < log_ref)
        state = state._replace(
            theta=jnp.where(accepted, state.theta + step_, state.theta),
            radius=jnp.where(accepted, state.radius, 0.5 * state.radius),
        )
        return state, PGStep(log_ref, log_cand, accepted, g)

    return step
