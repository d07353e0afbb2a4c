"""Model-free policy-gradient baseline (paper section 6, footnote: "same as CPI, except gradient
descent is done directly on deterministic linear controller. We solve a linear system to estimate
the gradient from sample cost with perturbed parameters").

Parameters: a time-invariant gain offset ``θ [m, n]`` on a base gain ``K⁰`` (``K_t = K⁰_t + θ``,
``θ_1 = 0``), only on the *free* entries (:func:`pg_base`). On hover, ``K⁰`` is the trim-holding
controller ``u_t = u* − θ φ(x_t)`` (gain 1 on the ``u_prev`` error, 0 on ``du_prev``), whose test
trajectories at θ = 0 are exactly π_1's (from μ, π_1 never acts: ~2.5e6), and θ acts
on the physical and constant coordinates (52 gains). Elsewhere ``K⁰`` is π_1's gain and all mn
gains are free. Iteration n ≥ 2 spends at most the m transitions of the other methods, in
``R = P + 2`` rollouts of ``H`` steps (:func:`budget`) that all start at the test's start μ and
all see the same process noise ``w`` (common random numbers):

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

- ``"transitions"`` (the measurements below): a sample is one transition, as for
  every other method. Iteration n spends ``(P + 2)·H ≤ m`` of them: ``H = min(pg_horizon, T,
  m // 4)``, ``P = m // H − 2`` (hover, m = 500: H = 125, P = 2).
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
  (``examples/pg_sample_count.py``). The pace is set by ρ_1, not by m.
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

Why. Numbers from hover at π_1 (θ = 0), exact autodiff gradients of
the test objective ``J_400`` (400 steps from μ) over 200 noise draws
(``examples/pg_gradient_quality.py``), and scratch runs of 4-8 seeds with 50 test trajectories:

- *(choice)* **Rollouts from μ, the test's start state** (τ = 0, empty delay FIFO), because the
  baseline is judged on ``J_μ``. CPI-style restarts from ν_t-like states gave directions with
  cosine −0.08 with ``∇J_μ`` (π_1's gains; ν_t perturbs ``u_prev``/``du_prev``, which π_1's test
  trajectories never do), and 0.01-0.05 in the trim-holding parametrisation with ten 25-step
  pairs. CPI's restart distribution is a free input of CPI; μ is the one the comparison uses.
- *(choice)* **Rollouts as long as the budget allows**: ``H = min(pg_horizon, T, m // 4)``
  (``pg_horizon = 600``: no cap below the task horizon), the longest that leave a reference, two
  probes and a candidate. Hover: m = 500 gives H = 125, m = 100 gives H = 25; P = 2 in both.
  The 125-step surrogate's exact gradient has cosine 0.78 with ``∇J_400``, and a line search
  along it lowers ``J_400`` to 0.58 of π_1's.
- *(choice)* **Trim-holding parametrisation on hover.** π_1's gain is 1 on ``du_prev``
  (Δu_t = −Δu_{t−1}): a marginally stable loop, through which any offset on a slowly varying
  coordinate is integrated into the controls. On that base the useful steps are tiny (the best
  step along a one-pair estimate is ~8e-4 in scaled coordinates, median of 20) and runs that
  lower the 125-step cost raise ``J_400`` (median 2.4e6 -> 4e7 over 20 iterations). The
  controller ``u = u* − θ φ(x)`` is the same linear-policy class (a linear map of the error
  state), flies the same test trajectories at θ = 0, and does not integrate: with everything
  else equal, the run above stays at or below π_1 (below).
- *(choice)* **Common random numbers for every rollout of an iteration.** With one noise draw
  per antithetic pair, an estimate's cosine with the mean gradient was 0.01-0.05: the per-draw
  noise dominates. On one shared draw the differences are deterministic in δ: the system of
  step 3 recovers that draw's gradient exactly (cosine 1.000 with 120 probes, 0.43 with 10), and
  one draw's exact gradient is a descent direction of ``J_400`` (best ratio 0.75, median of 10).
- *(choice)* **A memory of the last L = d probes** (transitions reading; the footnote's linear
  system with as many equations as unknowns once full): two new probes per iteration span 2 of
  52 directions; the memory averages over the last ~17 iterations' draws and directions. Old
  probes were taken at nearby θ and under other noise, which the least squares averages.
- *(choice)* **Scaled coordinates.** The error coordinates differ by orders of magnitude (RMS
  along π_1's rollouts: positions ~15 m, velocities ~2 m/s, rates and attitude ~0.05-0.3), so a
  fixed step in raw gains is meaningless. Dividing column j by ``s_j`` makes a unit of ``φ = θ
  diag(s)`` one unit of action; the floor ``sqrt(nu_state_var)`` is ν_t's state noise.
- *(choice)* **Probe size** ``σ = pg_sigma = 0.01`` (ν's action std): a probe moves each action
  by about σ. **Log cost**: costs span 50 (L) to 2.5e6 (π_1) to the cap 1e8; ``log c`` makes the
  differences relative; costs are capped at ``cost_cap`` (non-finite counts as the cap).
- *(choice)* **Conservative, non-growing step.** ``ρ_1 = pg_step · σ√m`` with ``pg_step = 0.1``:
  in π_1's parametrisation the best step along an estimate was ~0.04 probing radii (above), and
  at 1 probing radius (``ρ = 0.02``) every one of 20 estimated directions raised ``J_400`` ~34x.
  A radius that also grows after acceptances (x2 or x1.5) sent 2-4 of 8 seeds to 1e7-4e7 within
  20-60 iterations: the one-draw acceptance test (a 125-step cost is ~1/700 of the 400-step one;
  drift dominates late) admits steps too long for ``J_400``. So ρ halves after a rejection and
  never grows.

Measured, transitions reading (``run("pg", scenario("hover", samples=500, iterations=I, seeds=8,
...))``, each seed's test noise the same at every iteration, so last/first is a paired ratio):

- m = 500, 20 iterations, 300 test trajectories: median over seeds 2.58e6 -> 2.45e6; per-seed
  ratios 0.68-1.09, 5 of 8 below 1. 100 iterations (100 test trajectories): 2.58e6 -> 2.34e6,
  ratios 0.74-1.09, 6 of 8 below 1; it stalls after ~30 iterations as ρ shrinks.
- m = 100 (H = 25), 50 iterations: the median *rises*, 2.58e6 -> 5.8e6 (one seed at 7.7e7): a
  25-step check sees even less of ``J_400`` than a 125-step one.

Limits: at m = 500 an improvement of ~5-10%, far from the paper's "~15000 after 100
iterations"; at m = 100 (the paper: "only small improvement") it gets worse. ``J_400`` from π_1
is dominated by the position drift that one short draw barely sees; a step rule that keeps
moving without a 400-step check inside m is the open problem. On the funnel (π_1's gains as
base, 84 free gains) the method runs without a measured study.
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.closed_loop import DelayedLoop
from loopid.algorithms.contracts import Agent, Row, Trace
from loopid.algorithms.keys import iteration_key, seed_keys
from loopid.algorithms.loop import drive
from loopid.algorithms.loop_program import eval_noise, trajectory_mean
from loopid.algorithms.plant import (
    Plant,
    column_ops,
    halving_sum,
    ordered_sum,
    quadratic_form,
)


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


def pg_base(plant: Plant, K1: jax.Array, *, hold: bool) -> tuple[jax.Array, jax.Array]:
    """The base gain ``K⁰ [T, m, n]`` and the free mask ``F [m, n]`` (module docstring).

    ``hold``: the trim-holding controller ``u = u* − θ φ(x)`` of the helicopter's error
    coordinates (gain I on the first m coordinates, the ``u_prev`` error, and 0 on the next m,
    ``du_prev``), θ free on the rest; otherwise π_1's gain ``K1`` with every entry free."""
    m, n = plant.n_action, plant.n_state
    if not hold:
        return K1, jnp.ones((m, n), jnp.float64)
    if n < 2 * m + 1:
        raise ValueError(
            f"the trim-holding base needs error coordinates [u_prev (m), du_prev (m), ...], "
            f"got n_state={n} for n_action={m}"
        )
    base = jnp.zeros_like(K1).at[:, :, :m].set(jnp.eye(m, dtype=K1.dtype))
    return base, jnp.zeros((m, n), jnp.float64).at[:, 2 * m :].set(1.0)


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


def run_policy_gradient(
    plant: Plant,
    agent: Agent,
    seeds,
    *,
    iterations: int,
    samples: int,
    n_test: int,
    horizon: int = 600,
    sigma: float = 0.01,
    step: float = 0.1,
    hold: bool = False,
    nu_state_var: float = 0.0025,
    cost_cap: float = 1e8,
    samples_mode: str = "transitions",
    update: str = "conservative",
    progress: Callable[[int, Row], None] | None = None,
    noise: jax.Array | None = None,
) -> Trace:
    """Run the baseline on every seed; the result has the shape of every other method's.

    ``horizon``: the longest rollout (``pg_horizon``); ``sigma``: the probe's action scale
    (``pg_sigma``); ``step``: the first trust radius in probing radii (``pg_step``); ``hold``:
    the trim-holding base (:func:`pg_base`) instead of π_1's gains; ``samples_mode``: the
    reading of ``samples`` (``pg_samples``, :func:`budget`); ``update``: the reading of the step
    (``pg_update``: ``conservative`` or ``descent``). The rows' ``policy_samples`` and
    ``valid_samples`` are what an iteration spent (:func:`spent`), and the Trace's ``samples``
    column counts m per iteration: transitions under ``"transitions"``, *rollouts* (of
    ``min(horizon, T)`` steps each) under ``"rollouts"``. ``noise``: the seeds' test noise
    (``EvalNoise.test``) when the caller keeps a
    :func:`loopid.algorithms.loop_program.noise_program`."""
    if not (sigma > 0 and step > 0):
        raise ValueError(f"pg_sigma and pg_step must be > 0, got {sigma!r}, {step!r}")
    _, P = budget(samples, horizon, plant.horizon, samples_mode=samples_mode)
    used = spent(samples, horizon, plant.horizon, samples_mode=samples_mode)
    keys = seed_keys(seeds)
    K1, info = agent.policy(agent.init())
    m = plant.n_action
    base, free = pg_base(plant, K1, hold=hold)
    one_step = make_pg_step(
        plant, base, free, samples=samples, horizon=horizon, sigma=sigma,
        nu_state_var=nu_state_var, cost_cap=cost_cap, samples_mode=samples_mode, update=update,
    )  # fmt: skip

    def evaluate(theta, noise):
        """Every seed's test row; ``theta [S, m, n]``, noise in :meth:`Plant.eval_seeds`' layout."""
        S = theta.shape[0]
        costs, div = plant.eval_seeds(base[None] + theta[:, None], noise)
        zero = jnp.zeros(S)
        count = jnp.full(S, used, jnp.int32)  # every sample is of the (perturbed) policy
        return Row(
            test_cost=trajectory_mean(costs), test_cost_median=jnp.median(costs, axis=1),
            diverged=jnp.sum(div, axis=1), loss_nu=zero, loss_policy=zero, online_loss=zero,
            policy_samples=count, valid_samples=count, solver_converged=jnp.full(S, info.converged),
            spectral_radius=jnp.full(S, info.spectral_radius), extra={},
        )  # fmt: skip

    @jax.jit
    def advance(state, keys, noise, it):
        k = jax.vmap(lambda key: iteration_key(key, it))(keys)
        state, _ = jax.vmap(one_step)(state, k)
        return state, evaluate(state.theta, noise)

    if noise is None:
        noise = eval_noise(plant, keys, n_test, "last").test
    S = keys.shape[0]
    one = init_state(free, step * sigma * np.sqrt(m), probes=P)
    state = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (S, *a.shape)), one)
    state, rows = drive(
        lambda: (state, jax.jit(evaluate)(state.theta, noise)),
        lambda state, it: advance(state, keys, noise, jnp.int32(it)),
        iterations,
        progress,
    )
    final = {"K": base[None] + state.theta[:, None]}
    return Trace.from_rows(np.asarray(seeds), samples, rows, final)
