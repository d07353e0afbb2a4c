"""Planning on a learned nonlinear model against planning on the true model.

(a) One iLQR plan (:func:`loopid.control.plan`, compiled: ``jax.jit`` of the plan with the
    model's parameters as its argument, the way :func:`loopid.algorithms.planning_agent.ilqr_plan`
    runs inside the loop; timed after one compiling call). Every row of a system runs the same
    planner, cost, start and initial actions for the same number of iterations (``tol = atol = 0``
    so neither stops early; the iterations run are printed). Median of ``REPEATS`` calls.

    - Pendulum-v1 from hanging (Δx = [cos θ − 1, sin θ, θ̇, 1] [4], Δu [1]), T = 200 steps, Gym's
      cost with the torque penalty (``Penalized(pendulum.cost_obs, 2, 100)``), U0 = 0.2 (from
      there iLQR improves for 226 iterations: none stops early). True model:
      :func:`loopid.systems.pendulum.step_obs`. Learned: Δx' = Δx + Wᵀφ(Δx, Δu), φ polynomial of
      degree 3 (F = 35, :func:`loopid.models.feature_maps.polynomial`) or 4 (F = 70, the
      swing-up example's), W [F, 4] fitted by
      FTRL least squares (λ = 1e-3) on 40 random starts × 200 steps of uniform random torques,
      planned through ``feature_model.dynamics`` with W traced (``plan(params=W)``).
    - The nose-in funnel (``make_task("funnel")``, Δx [21] error coordinates along the target,
      Δu [4], T = 599 steps, 600 target states), cost ΔxᵀQΔx + ΔuᵀRΔu, the expert's initial actions
      (:func:`loopid.systems.helicopter.expert.funnel_initial_actions`). True model: the noise-free
      helicopter step in error coordinates, Δx' = to_error(step(from_error(Δx, x*_t), Δu, 0),
      x*_{t+1}), the target traced as ``params``. Learned: one global feature model for all steps,
      Δx' = A_tΔx + B_tΔu + Wᵀφ(Δx, Δu) on the ``"heading"`` funnel nominal
      (:func:`loopid.systems.helicopter.funnel_nominal.funnel_nominal`), φ polynomial degree 2 (F =
      325) or 400 random Fourier features (F = 425), W fitted by FTRL on one-step queries of the
      true model about the true-model row's plan (32 per step, states and actions ± N(0, 0.05²));
      both start from that plan's closed loop (:func:`plan_rows_funnel`; its learned plans are not
      finite, which leaves the time per iteration unchanged, see there). A third row is the expert's
      own formulation (:func:`loopid.control.ilqr` on the raw 21-state step with the cost in error
      coordinates, as :func:`loopid.systems.helicopter.expert.funnel_expert_gains` runs it).

(b) MPC step rate: :class:`loopid.control.MPCController` (horizon 60, 10 iLQR iterations, the
    warm start plus the alternatives ±2, re-planning every 1 or 4 steps) driving 8
    ``loopid/PendulumHanging-v0`` envs through :meth:`loopid.systems.GymSystem.rollouts`
    (SyncVectorEnv), env steps per second after a compiling episode, best of ``REPEATS``;
    the true model against the degree-3 feature model above.

(c) MPC in the helicopter's compiled loop (:func:`loopid.algorithms.mpc_plant.mpc_plant`, what
    ``planner_kind = "mpc"`` flies): the test flights of one hover iteration, ``eval_seeds`` of
    S = 4 seeds x 8 trajectories x 400 steps (compiled; median of ``REPEATS``), 50-step plans of 5
    iLQR iterations re-planned every 10 steps. Rows: the true model (the noise-free helicopter in
    error coordinates), and the hover nominal plus a learned degree-1 (the linear offset model)
    or degree-2 polynomial (F = 325), fitted by FTRL on 16 of the expert's hover rollouts with
    action noise N(0, 0.1²). The gains plant flying the expert's gains over the same noise is a
    second reference: what one MPC trajectory step costs against one gains step.

The reference of every ratio is the true-model row of the same system, measured in the same run.
Goal: learned / true <= 2.

    .venv/bin/python benchmarks/nonlinear.py [--quick]
"""

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import loopid  # noqa: F401  (float64, registers loopid/PendulumHanging-v0)
from loopid import control
from loopid.learners import ftrl_least_squares
from loopid.models import feature_maps as FM
from loopid.models import feature_model as F
from loopid.models.linear_offset import LinearOffsetModel
from loopid.systems import helicopter as h
from loopid.systems import pendulum
from loopid.systems.from_gymnasium import GymSystem
from loopid.systems.gym_slots import Slot
from loopid.systems.helicopter.expert import funnel_initial_actions
from loopid.systems.helicopter.funnel_nominal import funnel_nominal
from loopid.systems.helicopter.tasks import make_task

PUSH = jnp.array([[2.0], [-2.0]])  # the swing-up's alternative initial actions (±u_max)
COST = control.Penalized(pendulum.cost_obs, 2.0, 100.0)


def fit(nominal, fmap, dx, du, dx_next, t=None):
    """W [F, n] by FTRL least squares (λ = 1e-3) on the residuals of ``nominal``."""
    learner = ftrl_least_squares(1e-3)
    y = F.residual_targets(nominal, dx, du, dx_next, t)
    state = learner.update(learner.init(fmap.size, nominal.n), fmap(dx, du), y)
    return learner.weights(state)


def timed(f, *args, repeats):
    """(median seconds after one compiling call, compile seconds, the last result)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(f(*args))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(f(*args))
        times.append(time.perf_counter() - t0)
    return statistics.median(times), first, out


# ----------------------------------------------------------------------------- (a) pendulum
def true_pendulum(p, dx, du, t):
    return pendulum.step_obs(dx, du, t)


def pendulum_data(starts=40, steps=200, seed=0):
    """Transitions (Δx, Δu, Δx') [starts·steps, ·] of uniform random torques in [−2, 2]."""
    rng = np.random.default_rng(seed)
    x0 = np.stack([rng.uniform(-np.pi, np.pi, starts), rng.uniform(-1, 1, starts)], 1)
    U = jnp.asarray(rng.uniform(-2, 2, (starts, steps, 1)))

    def fly(x0, U):
        return jax.lax.scan(lambda x, u: (pendulum.step(x, u), x), x0, U)[1]

    X = jax.vmap(fly)(jnp.asarray(x0), U)  # [starts, steps, 2]
    X_next = jax.vmap(lambda x, u: jax.vmap(pendulum.step)(x, u))(X, U)
    dx, dx_next = pendulum.to_error(X), pendulum.to_error(X_next)
    return dx.reshape(-1, 4), U.reshape(-1, 1), dx_next.reshape(-1, 4)


def pendulum_learned(degree: int = 3):
    """(dynamics(W, Δx, Δu, t), W) of the feature model of ``degree`` fitted to random torques."""
    nominal = LinearOffsetModel(jnp.eye(4), jnp.zeros((4, 1)))
    fmap = FM.polynomial(4, 1, degree)
    W = fit(nominal, fmap, *pendulum_data())

    def learned(W, dx, du, t):
        return F.dynamics(nominal, fmap, W)(dx, du, t)

    return learned, W


def plan_rows_pendulum(iterations, repeats):
    x0 = pendulum.to_error(jnp.array([np.pi, 0.0]))
    U0 = jnp.full((200, 1), 0.2)
    learned, W = pendulum_learned()
    learned4, W4 = pendulum_learned(4)

    def planner(model):
        settings = dict(iterations=iterations, tol=0.0, atol=0.0)
        return jax.jit(lambda p: control.plan(model, COST, x0, U0, params=p, **settings))

    return [
        ("true model (step_obs)", *timed(planner(true_pendulum), None, repeats=repeats)),
        ("learned: polynomial 3, F = 35", *timed(planner(learned), W, repeats=repeats)),
        ("learned: polynomial 4, F = 70", *timed(planner(learned4), W4, repeats=repeats)),
    ]


# ----------------------------------------------------------------------------- (a) funnel
ZERO_NOISE = jnp.zeros(h.N_NOISE)


def true_funnel(target, dx, du, t):
    """The noise-free helicopter step in error coordinates along ``target`` [T+1, 21]."""
    x = h.from_error(dx, target[t])
    return h.to_error(h.step(x, du, ZERO_NOISE), target[t + 1])


def funnel_data(target, X, U, samples=32, std=0.05, seed=0):
    """One-step queries of the true model about a planned flight (X [T+1, 21], U [T, 4]):
    Δx = X_t + N(0, std²) (constant entry kept 1), Δu = U_t + N(0, std²), Δx' = the true error
    step; ``samples`` per step, [samples·T, ·] rows with their steps t."""
    T = U.shape[0]
    k1, k2 = jax.random.split(jax.random.key(seed))
    dx = X[None, :-1] + std * jax.random.normal(k1, (samples, T, h.N_STATE))
    dx = dx.at[..., -1].set(1.0).reshape(samples * T, h.N_STATE)
    du = (U[None] + std * jax.random.normal(k2, (samples, T, h.N_ACTION))).reshape(-1, h.N_ACTION)
    t = jnp.tile(jnp.arange(T), samples)
    dx_next = jax.vmap(true_funnel, in_axes=(None, 0, 0, 0))(target, dx, du, t)
    return dx, du, dx_next, t


def funnel_learned(task, nominal, fmap, data):
    W = fit(nominal, fmap, *data)

    def learned(W, dx, du, t):
        return F.dynamics(nominal, fmap, W)(dx, du, t)

    return learned, W


def plan_rows_funnel(iterations, repeats, quick):
    """The funnel's rows. Both planners start from the same stabilised closed loop: a first
    (untimed) true-model plan of ``iterations`` iterations from the expert's initial actions,
    as iLQR's initial policy u_t = U0_t − K0_t Δx_t (U0 = U + K X, K0 = K).

    The learned plans are not finite (final J = nan), measured: fitted this way (train MSE
    2.8e-3 against the heading nominal's 2.1e-2, of a target variance 0.76), the global model's
    Jacobians along the plan are off by 0.5-0.8 (std 0.01) and its closed loop under the feedback
    has spectral radius 1.05-1.3 (true model 0.95-1.01), so the 599-step rollout overflows by
    t = 73, from cold actions and from this warm start alike. The time per iteration does not
    depend on the values: every iteration runs the quadratisation, the backward pass and the
    forward pass for every α, and tol = 0 forces the same iterations (a failed iteration
    raises μ; 10 iterations stay below the ~17 failures that exceed mu_max)."""
    task = make_task("funnel")
    target = jnp.asarray(task.target, jnp.float64)
    Q, R = jnp.asarray(task.Q), jnp.asarray(task.R)
    cost = control.quadratic_cost(task.Q, task.R)
    U_cold = jnp.asarray(funnel_initial_actions(task))
    dx0 = h.to_error(jnp.asarray(task.x0), target[0])
    nominal = funnel_nominal("heading", task)
    settings = dict(iterations=iterations, tol=0.0, atol=0.0)

    def planner(model):
        return jax.jit(
            lambda p, U0, K0: control.plan(model, cost, dx0, U0, K0=K0, params=p, **settings)
        )

    true = planner(true_funnel)
    t0 = time.perf_counter()
    first = jax.block_until_ready(true(target, U_cold, jnp.zeros((*U_cold.shape, h.N_STATE))))
    compile_true = time.perf_counter() - t0
    U0 = first.U + jnp.einsum("tmn,tn->tm", first.K, first.X[:-1])
    K0 = first.K
    sec, _, sol = timed(true, target, U0, K0, repeats=repeats)
    rows = [("true model (error coordinates)", sec, compile_true, sol)]
    data = funnel_data(target, first.X, first.U)  # about the true model's plan
    maps = [("polynomial 2, F = 325", FM.polynomial(21, 4, 2))]
    if not quick:
        maps.append(("RFF 400, F = 425", FM.random_fourier(21, 4, 400)))
    for label, fmap in maps:
        learned, W = funnel_learned(task, nominal, fmap, data)
        rows.append((f"learned: {label}", *timed(planner(learned), W, U0, K0, repeats=repeats)))
    if not quick:

        def raw_dynamics(x, u, t):
            return h.step(x, u, ZERO_NOISE)

        def raw_cost(x, u, t):
            dx = h.to_error(x, target[t])
            return dx @ Q @ dx + u @ R @ u

        def expert(x0):
            return control.ilqr(raw_dynamics, raw_cost, x0, U_cold, max_iter=iterations, tol=0.0)

        x0 = jnp.asarray(task.x0)
        rows.append(("expert's ilqr (raw state, cold)", *timed(expert, x0, repeats=repeats)))
    return rows


def print_plans(title, rows, iterations):
    print(f"\n{title}: one plan, {iterations} iterations forced (tol = 0), median of repeats")
    print(f"{'model':34s}{'iters':>6s}{'plan [ms]':>11s}{'ms/iter':>9s}{'compile [s]':>13s}"
          f"{'vs true':>9s}{'final J':>11s}")  # fmt: skip
    ref = rows[0][1] / max(int(rows[0][3].iterations), 1)
    for label, sec, first, sol in rows:
        its = int(sol.iterations)
        per = sec / max(its, 1)
        print(f"{label:34s}{its:6d}{1e3 * sec:11.1f}{1e3 * per:9.2f}{first - sec:13.1f}"
              f"{per / ref:8.2f}x{float(sol.cost):11.4g}")  # fmt: skip


# ----------------------------------------------------------------------------- (c) JAX-loop MPC
def mpc_plant_rows(repeats, quick):
    """[(label, seconds, compile seconds, mean test cost)] of the hover's MPC test flights
    (module docstring, (c)); the first row flies the expert's gains."""
    from loopid.algorithms.keys import seed_keys
    from loopid.algorithms.loop_program import eval_noise
    from loopid.algorithms.mpc_plant import mpc_plant
    from loopid.algorithms.plant import make_plant
    from loopid.algorithms.transitions import flatten
    from loopid.models.linear_offset import hover_nominal
    from loopid.systems.helicopter.expert import expert_gains

    task = make_task("hover")
    plant = make_plant(task, h.DYNAMICS)
    S, n_test = (2, 4) if quick else (4, 8)
    W = eval_noise(plant, seed_keys(np.arange(S)), n_test, "last").test
    K = jnp.broadcast_to(expert_gains(task), (S, plant.horizon, 4, 21))
    keys = jax.random.split(jax.random.key(0), 16)
    data = flatten(jax.vmap(lambda k: plant.rollout(K[0], k, 0.1))(keys))
    nominal = hover_nominal(21, 4)
    cost = control.quadratic_cost(task.Q, task.R)
    target = task.target

    def true_model(p, dx, du, t):
        x = h.from_error(dx, target[t])
        return h.to_error(h.step(x, du, jnp.zeros(h.N_NOISE)), target[t + 1])

    sec, first, (c, _) = timed(jax.jit(plant.eval_seeds), K, W, repeats=repeats)
    rows = [("expert's gains (gains plant)", sec, first - sec, float(jnp.mean(c)))]
    for label, degree in (("true model", None), ("learned: polynomial 1 (linear)", 1),
                          ("learned: polynomial 2, F = 325", 2)):  # fmt: skip
        if degree is None:
            model, params = true_model, jnp.zeros((S, 1))
        else:
            fmap = FM.polynomial(21, 4, degree)
            w = fit(nominal, fmap, data.dx, data.du, data.dx_next)
            model = lambda p, dx, du, t, fmap=fmap: F.dynamics(nominal, fmap, p)(dx, du, t)  # noqa: E731
            params = jnp.broadcast_to(w, (S, *w.shape))
        mpc = mpc_plant(plant, control.replanner(
            model, cost, jnp.zeros(4), horizon=50, every=10, iterations=5)).plant  # fmt: skip
        sec, first, (c, _) = timed(jax.jit(mpc.eval_seeds), params, W, repeats=repeats)
        rows.append((label, sec, first - sec, float(jnp.mean(c))))
    return rows, S * n_test * plant.horizon


# ----------------------------------------------------------------------------- (b) MPC rate
def mpc_rate(model, params, every, episode, repeats):
    """Env steps per second of MPCController on 8 hanging pendulums (best of repeats)."""
    ctrl = control.MPCController(
        model, COST, params, jnp.zeros(1), horizon=60, every=every, iterations=10,
        alternatives=PUSH, target=pendulum.TARGET,
    )  # fmt: skip
    with GymSystem(
        "loopid/PendulumHanging-v0", target=pendulum.TARGET, horizon=episode, num_envs=8
    ) as system:
        slots = [Slot(0, 0, i, 0.0, False) for i in range(8)]
        t0 = time.perf_counter()
        system.rollouts([ctrl], slots[:8])  # compiles (every row plans at t = 0)
        first = time.perf_counter() - t0
        best, cost = 0.0, None
        for _ in range(repeats):
            ctrl.reset()
            t0 = time.perf_counter()
            r = system.rollouts([ctrl], slots)
            secs = time.perf_counter() - t0
            best = max(best, int(r.steps.sum()) / secs)
            cost = -float(r.reward.sum(1).mean())
    return best, first, cost


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer rows, shorter episodes")
    args = parser.parse_args()
    repeats = 3
    it_p, it_f = (20, 5) if args.quick else (50, 10)
    episode = 20 if args.quick else 40
    print(f"devices: {jax.devices()}")
    t_all = time.perf_counter()

    print_plans("Pendulum swing-up, T = 200", plan_rows_pendulum(it_p, repeats), it_p)
    print_plans("Funnel, T = 599", plan_rows_funnel(it_f, repeats, args.quick), it_f)

    learned, W = pendulum_learned()
    print(
        "\nMPC on 8 x loopid/PendulumHanging-v0 (GymSystem, SyncVectorEnv), horizon 60, "
        f"10 iterations, alternatives ±2, {episode}-step episodes, best of {repeats}"
    )
    print(f"{'model':34s}{'every':>6s}{'steps/s':>9s}{'compile [s]':>13s}{'vs true':>9s}"
          f"{'cost/ep':>9s}")  # fmt: skip
    for every in (1, 4):
        ref = None
        for label, model, p in (("true model (step_obs)", true_pendulum, None),
                                ("learned: polynomial 3, F = 35", learned, W)):  # fmt: skip
            rate, first, cost = mpc_rate(model, p, every, episode, repeats)
            ref = ref or rate
            print(f"{label:34s}{every:6d}{rate:9.1f}{first:13.1f}{ref / rate:8.2f}x{cost:9.1f}")
    rows, steps = mpc_plant_rows(repeats, args.quick)
    print(
        f"\nMPC in the helicopter's JAX loop (mpc_plant), hover test flights: {steps} steps, "
        f"horizon 50, every 10, 5 iterations, median of {repeats}"
    )
    print(f"{'flown by':34s}{'[s]':>8s}{'steps/s':>11s}{'compile [s]':>13s}{'vs true':>9s}"
          f"{'cost':>9s}")  # fmt: skip
    for label, sec, compile_s, cost in rows:
        ratio = sec / rows[1][1]
        print(f"{label:34s}{sec:8.3f}{steps / sec:11.0f}{compile_s:13.1f}{ratio:8.2f}x"
              f"{cost:9.1f}")  # fmt: skip
    print(
        f"\nvs true: the learned row's time over the true row's (per iteration for plans); "
        f"goal <= 2x. Total {time.perf_counter() - t_all:.0f} s."
    )


if __name__ == "__main__":
    main()
