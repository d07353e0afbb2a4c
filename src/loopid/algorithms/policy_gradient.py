"""Model-free policy-gradient baseline (paper section 6, footnote: "same as CPI, except gradient
descent is done directly on deterministic linear controller. We solve a linear system to estimate
the gradient from sample cost with perturbed parameters").

Parameters: a time-invariant gain offset ``θ [m, n]`` on a base gain ``K⁰`` (``K_t = K⁰_t + θ``,
``θ_1 = 0``), only on the *free* entries (:func:`pg_base`). On hover, ``K⁰`` is the trim-holding
controller ``u_t = u* − θ φ(x_t)`` (gain 1 on the ``u_prev`` error, 0 on ``du_prev``), whose test
trajectories at θ = 0 are exactly π_1's (from μ, π_1 never acts: ~2.5e6), and θ acts
on the physical and constant coordinates (52 gains). Elsewhere ``K⁰`` is π_1's gain and all mn
gains are free. Each iteration (:mod:`loopid.algorithms.policy_gradient_step`, steps 1-4 there:
a reference rollout, P probes, the footnote's linear system for the gradient, then a
conservative step or plain descent, with the two readings of "samples" and of the step) flies
rollouts from the test's start μ (:mod:`loopid.algorithms.policy_gradient_rollouts`) within the
m samples of the other methods; :func:`run_policy_gradient` runs it on every seed.

Why. Numbers from hover at π_1 (θ = 0), exact autodiff gradients of the test objective ``J_400``
(400 steps from μ) over 200 noise draws (``analysis/pg_gradient/pg_gradient_quality.py``), and
scratch runs of 4-8 seeds with 50 test trajectories:

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

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.contracts import Agent, Row, Trace
from loopid.algorithms.keys import iteration_key, seed_keys
from loopid.algorithms.loop import drive
from loopid.algorithms.loop_program import eval_noise, trajectory_mean
from loopid.algorithms.plant import Plant
from loopid.algorithms.policy_gradient_step import budget, init_state, make_pg_step, spent


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
