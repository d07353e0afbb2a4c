"""The policy-gradient baseline's second reading, ``pg_samples = "rollouts"`` (SPEC §5.3).

On a linear-quadratic system (``x' = A x + B u + w``, the optimal gain known from the Riccati
equation): a sample is one whole-horizon rollout with perturbed gains, and the gradient is the
least-squares solution of the m − 2 probes' equations. The tests check the budget of that reading,
that its estimate is the exact gradient of the shared noise draw's log cost (autodiff through the
same rollout) up to curvature, and that a few iterations lower the paired test cost of a
suboptimal gain towards, and not below, the optimal LQR cost.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.contracts import Agent, SolverInfo
from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop_program import eval_noise
from loopid.algorithms.plant import Plant, make_plant
from loopid.algorithms.policy_gradient import run_policy_gradient
from loopid.algorithms.policy_gradient_rollouts import make_rollouts
from loopid.algorithms.policy_gradient_step import budget, init_state, make_pg_step, spent
from loopid.control import dlqr_affine
from loopid.systems.linear import linear_dynamics, linear_task

K_STATE, M_ACT, T = 3, 2, 100
SIGMA, NU_STATE_VAR, CAP = 0.01, 0.0025, 1e8
SAMPLES = 20  # rollouts per iteration: P = 18 probes for d = 8 free gains


class LQ(NamedTuple):
    """The plant and its optimal stationary gain ``K_opt [m, n]``."""

    plant: Plant
    K_opt: np.ndarray


def _lq() -> LQ:
    """The realisable linear system of ``test_loop_linear`` and its optimal (stationary) gain."""
    rng = np.random.default_rng(1)
    A = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.1], [0.0, 0.0, 0.95]])
    B = 0.3 * rng.normal(size=(K_STATE, M_ACT))
    task = linear_task(np.eye(K_STATE), 0.1 * np.eye(M_ACT), np.ones(K_STATE), T, noise_std=0.1)
    plant = make_plant(task, linear_dynamics(A, B), stop_norm=50.0)
    Ae = np.zeros((K_STATE + 1, K_STATE + 1))
    Ae[:K_STATE, :K_STATE], Ae[K_STATE, K_STATE] = A, 1.0
    Be = np.zeros((K_STATE + 1, M_ACT))
    Be[:K_STATE] = B
    return LQ(plant, np.asarray(dlqr_affine(Ae, Be, task.Q, task.R).K))


@pytest.fixture(scope="module")
def lq():
    return _lq()


@pytest.fixture(scope="module")
def base(lq):
    """The start gain, ``0.3 K_opt`` at every step: stabilising, ~1.55x the optimal cost."""
    return jnp.broadcast_to(jnp.asarray(0.3 * lq.K_opt), (T, M_ACT, K_STATE + 1))


@pytest.fixture(scope="module")
def step20(lq, base):
    """The baseline's iteration under the rollouts reading, m = 20, every gain free (unjitted)."""
    free = jnp.ones((M_ACT, K_STATE + 1))
    return make_pg_step(
        lq.plant, base, free, samples=SAMPLES, horizon=600, sigma=SIGMA,
        nu_state_var=NU_STATE_VAR, cost_cap=CAP, samples_mode="rollouts",
    )  # fmt: skip


def fixed_gain_agent(K) -> Agent:
    """An agent whose π_1 is the stationary gain ``K [m, n]`` (the baseline's start)."""
    Kt = jnp.broadcast_to(jnp.asarray(K, jnp.float64), (T, *np.shape(K)))
    info = SolverInfo(jnp.bool_(True), jnp.float64(0.0))
    return Agent(lambda: (), lambda s, b: s, lambda s: (Kt, info), lambda s, b: jnp.zeros(1))


def test_rollouts_budget():
    """One rollout per sample: H is the whole (capped) horizon, P = m − 2, m counted as spent."""
    for m in (4, 5, 20, 100, 500):
        for horizon in (1, 25, 400, 600):
            H, P = budget(m, horizon, 400, samples_mode="rollouts")
            assert (H, P) == (min(horizon, 400), m - 2)
            assert spent(m, horizon, 400, samples_mode="rollouts") == m
            # the default reading is unchanged and never spends more than m transitions
            assert budget(m, horizon, 400) == budget(m, horizon, 400, samples_mode="transitions")
            assert spent(m, horizon, 400) <= m
    assert budget(500, 600, 400, samples_mode="rollouts") == (400, 498)
    assert budget(100, 600, 400, samples_mode="rollouts") == (400, 98)
    with pytest.raises(ValueError, match="samples >= 4"):
        budget(3, 400, 400, samples_mode="rollouts")
    with pytest.raises(ValueError, match=r"pg_samples must be .* got 'episodes'"):
        budget(100, 400, 400, samples_mode="episodes")


def test_memory_holds_one_iteration(step20):
    """L = max(d, P + 1): with P > d probes the ring buffer still gives every rollout of an
    iteration its own slot (a repeated scatter index would drop probes), and a memory too small
    for one iteration is refused rather than silently overwritten."""
    free = jnp.ones((M_ACT, K_STATE + 1))  # d = 8
    assert init_state(free, 1.0).probes.shape[0] == 8  # the transitions reading: L = d
    assert init_state(free, 1.0, probes=3).probes.shape[0] == 8
    assert init_state(free, 1.0, probes=18).probes.shape[0] == 19
    state, _ = jax.jit(step20)(init_state(free, 0.1, probes=18), jax.random.key(0))
    assert int(state.filled.sum()) == 19 and int(state.cursor) == 0
    assert np.all(np.any(np.asarray(state.probes) != 0, axis=(1, 2)))  # 19 distinct rollouts
    with pytest.raises(ValueError, match="probes=18"):
        step20(init_state(free, 0.1), jax.random.key(0))


def _log_cost(plant, base, theta, noise):
    """The log cost of the whole-horizon rollout of ``base + θ`` under ``noise`` and its error
    states (the baseline's rollout, written out again for autodiff)."""
    task, dyn = plant.task, plant.dynamics
    Q, R = jnp.asarray(task.Q), jnp.asarray(task.R)
    no_fifo = jnp.zeros((0, plant.n_action))

    def body(carry, inp):
        x, total = carry
        w, tau = inp
        dx = dyn.to_error(x, task.target[tau])
        du = -(base[tau] + theta) @ dx
        x, _ = dyn.step_delayed(x, no_fifo, du, w)
        return (x, total + dx @ Q @ dx + du @ R @ du), dx

    steps = jnp.arange(noise.shape[0])
    (_, total), dxs = jax.lax.scan(body, (jnp.asarray(task.x0), jnp.float64(0.0)), (noise, steps))
    return jnp.log(total), dxs


def test_rollouts_gradient_is_the_draws_gradient(lq, base, step20):
    """With P = m − 2 ≥ d probes on one shared noise draw, the footnote's linear system returns
    that draw's exact gradient of the log cost (``jax.grad`` through the same rollout) up to
    curvature, in the scaled coordinates ``e = δ diag(s)`` in which the step is taken:
    ``g ≈ ∇_θ ℓ_w diag(1/s)``. Measured over 10 θ: cosine min 0.998 (m = 20), 0.9994 (m = 40);
    0.78 at P = d = 8 (square but ill-conditioned), median 0.58 at P = 4 < d (a projection)."""
    plant = lq.plant
    H, P = budget(SAMPLES, 600, T, samples_mode="rollouts")
    assert H == T and P >= M_ACT * (K_STATE + 1)
    one = jax.jit(step20)
    log_cost = jax.jit(lambda th, w: _log_cost(plant, base, th, w))
    grad = jax.jit(jax.grad(lambda th, w: _log_cost(plant, base, th, w)[0]))
    free = jnp.ones((M_ACT, K_STATE + 1))
    rng = np.random.default_rng(0)
    cosines = []
    for trial in range(5):
        theta = jnp.asarray(0.2 * rng.normal(size=(M_ACT, K_STATE + 1)))  # a θ near the start
        key = jax.random.key(trial)
        _, info = one(init_state(free, 0.1, probes=P)._replace(theta=theta), key)
        # the step's shared draw: the first half of its key, H steps of the task's noise
        w = plant.dynamics.noise_sequence(jax.random.split(key)[0], H, plant.noise_std)
        log_ref, dxs = log_cost(theta, w)
        np.testing.assert_allclose(info.log_ref, log_ref, rtol=1e-12)  # the same rollout
        scale = jnp.maximum(jnp.sqrt(jnp.mean(dxs**2, axis=0)), np.sqrt(NU_STATE_VAR))
        exact = np.ravel(grad(theta, w) / scale)  # ∂ℓ/∂e = ∂ℓ/∂θ diag(1/s)
        g = np.ravel(info.gradient)
        cosines.append(g @ exact / (np.linalg.norm(g) * np.linalg.norm(exact)))
    assert min(cosines) > 0.9, cosines


@pytest.mark.slow
def test_rollouts_lower_the_lq_cost(lq):
    """From 0.3 K_opt (stabilising, 1.54-1.56x the optimal cost), 8 iterations of m = 20
    rollouts lower every seed's test cost (paired: the same test noise at every iteration) and
    keep it above the optimal LQR gain's cost on that noise. Measured (3 seeds): last/first
    0.76-0.79 with pg_step = 3 (last/optimum 1.17-1.21), 0.86-0.87 with 1, 0.67-0.72 with 10
    (the first radius, ``pg_step·σ√m``, never grows: the default 0.1 moves ~3% in 10)."""
    seeds, n_test, samples = np.arange(3), 50, SAMPLES
    trace = run_policy_gradient(
        lq.plant, fixed_gain_agent(0.3 * lq.K_opt), seeds, iterations=8, samples=samples,
        n_test=n_test, sigma=SIGMA, step=3.0, nu_state_var=NU_STATE_VAR, cost_cap=CAP,
        samples_mode="rollouts",
    )  # fmt: skip
    rows = trace.rows
    noise = eval_noise(lq.plant, seed_keys(seeds), n_test, "last").test
    K_opt = jnp.broadcast_to(jnp.asarray(lq.K_opt), (len(seeds), T, M_ACT, K_STATE + 1))
    opt = np.asarray(lq.plant.eval_seeds(K_opt, noise)[0]).mean(axis=1)
    first, last = rows.test_cost[:, 0], rows.test_cost[:, -1]
    assert np.all(first > 1.3 * opt)  # the start is clearly suboptimal, so the check can fail
    assert np.all(last < 0.9 * first), (first, last)
    assert np.all(last > opt), (last, opt)
    assert np.all(rows.diverged == 0)
    # the rows count rollouts: m per iteration, all of the (perturbed) policy
    assert np.all(rows.policy_samples[:, 1:] == samples)
    assert np.all(rows.valid_samples[:, 1:] == samples)
    np.testing.assert_array_equal(trace.samples, samples * np.arange(8))


# ---- the two readings of the step (pg_update) --------------------------------------------------


_COMPILED: dict = {}


def _steps(lq, base, *, samples: int, update: str, noise_std: float | None = None):
    """The baseline's iteration under ``update`` on the LQ system (``noise_std``: another noise
    level of the same system), jitted once per module."""
    key = (samples, update, noise_std)
    if key not in _COMPILED:
        _COMPILED[key] = _compile(lq, base, samples=samples, update=update, noise_std=noise_std)
    return _COMPILED[key]


def _compile(lq, base, *, samples: int, update: str, noise_std: float | None):
    plant = lq.plant
    if noise_std is not None:
        task = plant.task._replace(noise_std=noise_std)
        plant = make_plant(task, plant.dynamics, stop_norm=50.0)
    free = jnp.ones((M_ACT, K_STATE + 1))
    one = make_pg_step(
        plant, base, free, samples=samples, horizon=600, sigma=SIGMA, nu_state_var=NU_STATE_VAR,
        cost_cap=CAP, samples_mode="rollouts", update=update,
    )  # fmt: skip
    _, P = budget(samples, 600, T, samples_mode="rollouts")
    return jax.jit(one), init_state(free, 0.01, probes=P)


def test_descent_without_noise_is_gradient_descent_with_alpha_from_the_first_radius(lq, base):
    """Noise-free, the two readings see the same rollouts: the first descent step equals the
    conservative one (α = ρ_1/‖g_1‖ makes it the trust radius long), and every later step is
    exactly −α g, α fixed, where the conservative step stays ρ long along g/‖g‖."""
    descent, state_d = _steps(lq, base, samples=SAMPLES, update="descent", noise_std=0.0)
    conservative, state_c = _steps(lq, base, samples=SAMPLES, update="conservative", noise_std=0.0)
    key = jax.random.key(3)
    d1, info_d = descent(state_d, key)
    c1, info_c = conservative(state_c, key)
    np.testing.assert_allclose(info_d.gradient, info_c.gradient, rtol=1e-12, atol=1e-15)
    assert bool(info_c.accepted)
    np.testing.assert_allclose(d1.theta, c1.theta, rtol=1e-12, atol=1e-15)
    g1 = np.asarray(info_d.gradient)
    np.testing.assert_allclose(float(d1.alpha), 0.01 / np.linalg.norm(g1), rtol=1e-12)
    d2, info_2 = descent(d1, jax.random.key(4))
    assert float(d2.alpha) == float(d1.alpha)  # set once
    step = np.asarray(d2.theta - d1.theta)
    g2 = np.asarray(info_2.gradient)
    # in scaled coordinates the step is −α g: the ratio step/g is −α/s_j in every column
    ratio = step / np.where(g2 == 0, 1.0, g2)
    assert np.all(ratio < 0)
    np.testing.assert_allclose(ratio, ratio[0:1, :] * np.ones_like(ratio), rtol=1e-9)
    assert not np.allclose(np.linalg.norm(g2), np.linalg.norm(g1), rtol=1e-3)  # a real test


def test_descent_gives_every_rollout_its_own_draw(lq, base):
    """Under ``conservative`` a step of length ~0 costs what the reference costs (the same
    draw); under ``descent`` the candidate flies its own draw, so its cost differs by the
    noise."""
    key = jax.random.key(0)
    spread = {}
    for update in ("conservative", "descent"):
        one, state = _steps(lq, base, samples=SAMPLES, update=update)
        _, info = one(state._replace(radius=jnp.float64(1e-12)), key)
        spread[update] = abs(float(info.log_cand - info.log_ref))
    assert spread["conservative"] < 1e-9
    assert spread["descent"] > 1e-3


def test_unknown_update_is_one_line():
    with pytest.raises(ValueError, match="pg_update must be one of conservative, descent"):
        _compile(
            _lq(),
            jnp.zeros((T, M_ACT, K_STATE + 1)),
            samples=SAMPLES,
            update="bold",
            noise_std=None,
        )


@pytest.mark.parametrize("shared", [True, False])
def test_rollouts_are_each_gains_own_closed_loop(lq, shared):
    """The column-batched rollouts equal, rollout by rollout, a plain step-by-step loop of the
    same closed loop (NumPy, one rollout at a time): a delay of one step, a time-varying base
    gain, each rollout its own offset, the noise shared or one draw each, and a capped rollout."""
    task = lq.plant.task._replace(delay=1)
    plant = make_plant(task, lq.plant.dynamics, stop_norm=50.0)
    rng = np.random.default_rng(3)
    H, R, cap = 60, 4, 1e3
    base = np.asarray(lq.K_opt)[None] + 0.05 * rng.normal(size=(T, M_ACT, K_STATE + 1))
    offsets = 0.05 * rng.normal(size=(R, M_ACT, K_STATE + 1))
    offsets[-1] = -3.0  # an unstable loop: its cost reaches the cap
    noise = 0.1 * rng.normal(size=(H, K_STATE) if shared else (R, H, K_STATE))
    got = make_rollouts(plant, jnp.asarray(base), H, cap)(jnp.asarray(offsets), jnp.asarray(noise))

    step = jax.jit(plant.dynamics.step_delayed)  # the system's own step, no delay
    no_delay = jnp.zeros((0, M_ACT))
    Q, Rm, x0 = np.asarray(task.Q), np.asarray(task.R), np.asarray(task.x0)
    want = []
    for r in range(R):
        x, pending, total = x0.copy(), np.zeros(M_ACT), 0.0
        w = noise if shared else noise[r]
        for tau in range(H):
            dx = np.append(x, 1.0)
            du = -(base[tau] + offsets[r]) @ dx
            total += dx @ Q @ dx + du @ Rm @ du
            x = np.asarray(step(x, no_delay, pending, w[tau])[0])
            pending = du  # the change commanded now acts one step later
        want.append(np.log(min(total, cap)) if np.isfinite(total) else np.log(cap))
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-12)
    assert float(got[-1]) == np.log(cap)
