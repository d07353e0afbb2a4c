"""How far below the linearised expert L can a static linear gain go on the hover test protocol?

The paper's hover panels have DAgger ending below L. Every hover policy the loop flies is one
static affine gain ``K [4, 21]`` in error coordinates (the feedforward in the last column), so
the best such gain bounds what any learned model's LQR can reach. Measured here, for each
panel and delay reading: ``hover`` (d = 0, where the two readings coincide: run once) and
``hover-delay`` (d = 1) under ``delay_mode = "latency"`` and under ``"fifo"``.

1. Search. From L's gain (:func:`loopid.systems.helicopter.expert.expert_gains`,
time-invariant on hover:
   ``K_expert[0]``), minimise the mean test cost of the static gain (broadcast over the 400
   steps) over its 84 entries: the plant's own test rollouts (:meth:`Plant.eval_costs`: 400
   steps from the task's start state, noise std 1, costs capped at 1e8), differentiated by JAX
   through the true simulator. Optimiser and stopping rule, fixed before the measured runs:
   ``optax.lbfgs()`` (memory 10, zoom line search, its defaults) for exactly ``--iterations``
   iterations (default 100; a pilot run on hover-delay moved the training objective by a
   further 0.1 % between 100 and 400 iterations), no other stopping test. Training noise:
   ``--n-train`` trajectories (default 200) from ``eval_noise(PRNGKey(TRAIN_KEY), n)``.
   hover-delay under ``fifo``: a static gain's closed loop, and so this objective, is the same
   under both readings, so by default the latency search's gain is taken and the objective
   and its gradient under the two readings are compared at L and at that gain;
   ``--fifo-search`` runs the whole search under ``fifo`` as well (measured: the same gain to
   3e-4 per entry, the same held-out cost to 0.002).
2. Held-out test. ``--n-test`` trajectories (default 1,000) from ``PRNGKey(TEST_KEY)``, never
   seen by the search; L and the best gain on the same noise (common random numbers), with the
   standard error of each mean and of the paired difference ``cost_L − cost_best``; also the
   best gain with its du_prev columns set to 0. The same search and test on the hover
   linearisation as the plant (:func:`linearised_plant`: linear dynamics, the same noise
   draws), d = 0 and d = 1 (latency): how much a linear system allows (at d = 0 L is the
   optimal steady-state policy there, so that row is also a check on over-fitting the
   training noise). ``--no-linearised`` skips it.
3. The gain itself and representability (d = 1): the change ``K_best − K_L`` per block of
   columns; spectral radii of the hover linearisation's closed loop with the gain acting on the
   current state (undelayed) and on the state one step old (delayed); and
   - whether some *undelayed* linear model has ``K_best`` as its LQR gain with the task's own
     Q, R (the learner's solver): such a model is constructed (:func:`model_with_gain`:
     Gauss-Newton on Â with B kept at the true one, minimum steps in the metric of
     one-step prediction error over L's visited states), (a) letting any row of A change,
     (b) only the velocity and rate rows (the rows the process noise enters), then checked
     with the project's ``dlqr_affine``; its one-step prediction error over the visited
     states is reported next to the true linearisation's, in units of the process noise;
   - inverse optimality for the *true* (A, B): whether some Q' ⪰ 0, R' ≻ 0 make ``K_best`` the
     LQR gain of the hover linearisation (a linear feasibility problem over two PSD cones,
     :func:`inverse_optimality`; L's own gain, feasible by construction, is the control),
     for the best gains of both panels with and without their du_prev columns;
   - the LQR gain of the least-squares linear model of the true simulator over the states L
     visits flying with ν_en's action noise (std ``FIT_ACTION_STD``, so that B is identified
     at d = 0 too; noise-free targets: the limit a fitted model reaches on that distribution),
     and the held-out costs of its gain and of the gains with only its A or only its B.
4. Linearisation error over visited states: the hover linearisation (``helicopter.linearize``
   about the trim) against the true noise-free step at the states and applied changes of
   ``--n-visit`` test-protocol flights (default 30 x 400 steps; the plant's rollout without
   restarts, key ``VISIT_KEY``) of L and of the best gain: RMS error per block (velocity,
   position, rates, attitude), relative to the RMS of the true noise-free increment
   ``Δx_{t+1} − Δx_t`` of the block, overall and in quintile bins of ``‖Δx‖`` (constant entry
   excluded), with the per-step process-noise std of the block for scale; and the same error
   with every visited deviation from the trim scaled by s = 1, 1/2, 1/4 (how it grows with the
   distance from the trim).

    .venv/bin/python analysis/best_linear_gain/best_linear_gain.py [--quick] [--iterations 100]
        [--n-train 200] [--n-test 1000] [--n-visit 30] [--fifo-search]
        [--no-linearised] [--out results.md]

This script holds the search, the held-out test and the tables of 1-2; beside it,
``linear_gain_flights.py`` flies static gains (:func:`linearised_plant` among them),
``linear_gain_analysis.py`` holds the analyses of 3-4 (:func:`model_with_gain`,
:func:`inverse_optimality`, the linearisation error) and ``linear_gain_report.py`` their
tables.

About 5 minutes on 2 cores shared with other jobs at the default sizes (296 s measured;
``--quick``: 30 iterations, 100 training and 300 test trajectories).
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
from linear_gain_flights import (  # beside this script
    fmt,
    held_out,
    linearised_plant,
    mean_se,
    no_du_prev,
    static,
)
from linear_gain_report import gain_report  # beside this script

import loopid  # noqa: F401  (float64)
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task

TRAIN_KEY, TEST_KEY = 101, 202
PANELS = (  # (label, task, delay_mode); at d = 0 the readings coincide
    ("hover (d = 0)", "hover", "latency"),
    ("hover-delay, latency", "hover-delay", "latency"),
    ("hover-delay, fifo", "hover-delay", "fifo"),
)


# ----------------------------------------------------------------------------- 1-2 search, test
def search(plant, K0: jax.Array, noise: jax.Array, iterations: int):
    """L-BFGS from ``K0`` on the mean test cost under ``noise``; (K, objective trace)."""
    H = plant.horizon

    def loss(K):
        return jnp.mean(plant.eval_costs(static(K, H), noise)[0])

    opt = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(loss)

    @jax.jit
    def step(K, state):
        value, grad = value_and_grad(K, state=state)
        updates, state = opt.update(grad, state, K, value=value, grad=grad, value_fn=loss)
        return optax.apply_updates(K, updates), state, value

    K, state, trace = K0, opt.init(K0), []
    for _ in range(iterations):
        K, state, value = step(K, state)
        trace.append(float(value))
    trace.append(float(jax.jit(loss)(K)))
    return K, trace


def same_objective(plant_a, plant_b, gains: dict, noise: jax.Array):
    """The training objective and its gradient under two plants at each gain:
    ([(name, relative |Δ value|, relative max |Δ gradient|)], plant_b's values)."""
    H = plant_a.horizon

    def value_and_grad(plant):
        def loss(K):
            return jnp.mean(plant.eval_costs(static(K, H), noise)[0])

        return jax.jit(jax.value_and_grad(loss))

    fa, fb = value_and_grad(plant_a), value_and_grad(plant_b)
    rows, values = [], []
    for name, K in gains.items():
        (va, ga), (vb, gb) = fa(K), fb(K)
        dg = float(jnp.max(jnp.abs(ga - gb)) / jnp.max(jnp.abs(ga)))
        rows.append((name, float(jnp.abs(va - vb) / jnp.abs(va)), dg))
        values.append(vb)
    return rows, values


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="30 iterations, 100 / 300 trajectories")
    ap.add_argument("--iterations", type=int)
    ap.add_argument("--n-train", type=int)
    ap.add_argument("--n-test", type=int)
    ap.add_argument("--n-visit", type=int, default=30, help="flights for the visited states")
    ap.add_argument("--fifo-search", action="store_true",
                    help="search under fifo too (default: the latency search's gain)")  # fmt: skip
    ap.add_argument("--no-linearised", action="store_true",
                    help="skip the search on the linearised simulator")  # fmt: skip
    ap.add_argument("--out", help="also write the report as Markdown here")
    args = ap.parse_args()
    iterations = args.iterations or (30 if args.quick else 100)
    n_train = args.n_train or (100 if args.quick else 200)
    n_test = args.n_test or (300 if args.quick else 1000)
    t_all = time.perf_counter()
    lines = [
        f"Search: optax.lbfgs, {iterations} iterations from L's gain, {n_train} training "
        f"trajectories (PRNGKey({TRAIN_KEY})); held-out: {n_test} trajectories "
        f"(PRNGKey({TEST_KEY})), common to L and the best gain; test protocol: 400 steps from "
        "the trim, noise std 1, costs capped at 1e8.",
        "",
        "| panel, reading | train: L → best | held-out L | held-out best | L − best (paired) "
        "| relative improvement | diverged L / best | search s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    found, fifo_note = {}, []
    for label, task_name, mode in PANELS:
        t0 = time.perf_counter()
        task = make_task(task_name)
        plant = helicopter_plant(task, delay_mode=mode)
        K_L = expert_gains(task)[0]
        train = plant.eval_noise(jax.random.PRNGKey(TRAIN_KEY), n_train)
        shared = mode == "fifo" and not args.fifo_search
        if shared:  # a static gain's closed loop is the same under both readings (module doc)
            K_best = found["hover-delay, latency"]["K_best"]
            fifo_note = same_objective(found["hover-delay, latency"]["plant"], plant,
                                       {"K_L": K_L, "K_best": K_best}, train)  # fmt: skip
            trace = [float(v) for v in fifo_note[1]]
        else:
            K_best, trace = search(plant, K_L, train, iterations)
        secs = time.perf_counter() - t0
        test = plant.eval_noise(jax.random.PRNGKey(TEST_KEY), n_test)
        res = held_out(plant, {"L": K_L, "best": K_best, "no du_prev": no_du_prev(K_best)}, test)
        (cL, dL), (cB, dB) = res["L"], res["best"]
        diff = cL - cB
        rel = diff / cL.mean()
        found[label] = {"task": task, "plant": plant, "K_L": K_L, "K_best": K_best, "test": test,
                        "costs": {k: c for k, (c, _) in res.items()}}  # fmt: skip
        lines.append(
            f"| {label}{' (latency search gain)' if shared else ''} | {trace[0]:.3f} → "
            f"{trace[-1]:.3f} | {fmt(*mean_se(cL))} | {fmt(*mean_se(cB))} "
            f"| {fmt(*mean_se(diff))} "
            f"| {100 * rel.mean():.2f} % ± {100 * rel.std(ddof=1) / np.sqrt(rel.size):.2f} % "
            f"| {dL} / {dB} | {secs:.0f} |"
        )
        print(lines[-1], flush=True)
    lat, fifo = found["hover-delay, latency"], found["hover-delay, fifo"]
    if args.fifo_search:
        cross = held_out(lat["plant"], {"fifo": fifo["K_best"]}, lat["test"])["fifo"][0]
        lines += [
            "",
            f"The fifo search's gain flown under latency (same held-out noise): "
            f"{fmt(*mean_se(cross))}; max "
            f"|K_best(latency) − K_best(fifo)| = "
            f"{float(jnp.max(jnp.abs(lat['K_best'] - fifo['K_best']))):.2e}.",
        ]
    else:
        lines += [
            "",
            "hover-delay, fifo: the latency search's gain (a static gain's closed loop is the "
            "same under both readings; --fifo-search runs the search under fifo too). The "
            "training objective and its gradient under the two readings, max |difference| "
            "(relative to the largest entry): "
            + "; ".join(f"at {k}: value {dv:.1e}, gradient {dg:.1e}" for k, dv, dg in fifo_note[0])
            + ".",
        ]
    lines += [
        "",
        "The best gain with its du_prev columns set to 0 (held-out, same noise):",
        "",
        "| panel, reading | L | best | best, du_prev columns 0 | L − (best, du_prev 0) |",
        "|---|---|---|---|---|",
    ]
    for label, f in found.items():
        c = f["costs"]
        lines.append(
            f"| {label} | {fmt(*mean_se(c['L']))} | {fmt(*mean_se(c['best']))} "
            f"| {fmt(*mean_se(c['no du_prev']))} | {fmt(*mean_se(c['L'] - c['no du_prev']))} |"
        )

    # ---- the same search on the linearised simulator: what a linear analysis allows
    lines += [
        "",
        "The same search on the hover linearisation as the plant (linear dynamics, the same "
        "noise draws, keys and sizes): how much of the improvement a linear system allows.",
        "",
        "| panel, reading | train: L → best | held-out L | held-out best | L − best (paired) "
        "| relative improvement | search s |",
        "|---|---|---|---|---|---|---|",
    ]
    if args.no_linearised:
        lines.append("| (skipped: --no-linearised) | | | | | | |")
    for label, task_name, mode in () if args.no_linearised else PANELS[:2]:
        t0 = time.perf_counter()
        task = make_task(task_name)
        plant = linearised_plant(task, mode)
        K_L = expert_gains(task)[0]
        train = plant.eval_noise(jax.random.PRNGKey(TRAIN_KEY), n_train)
        K_lin, trace = search(plant, K_L, train, iterations)
        secs = time.perf_counter() - t0
        test = plant.eval_noise(jax.random.PRNGKey(TEST_KEY), n_test)
        res = held_out(plant, {"L": K_L, "best": K_lin}, test)
        cL, cB = res["L"][0], res["best"][0]
        rel = (cL - cB) / cL.mean()
        lines.append(
            f"| {label} | {trace[0]:.3f} → {trace[-1]:.3f} | {fmt(*mean_se(cL))} "
            f"| {fmt(*mean_se(cB))} | {fmt(*mean_se(cL - cB))} "
            f"| {100 * rel.mean():.2f} % ± {100 * rel.std(ddof=1) / np.sqrt(rel.size):.2f} % "
            f"| {secs:.0f} |"
        )
        print(lines[-1], flush=True)

    lines += gain_report(found, args.n_visit)
    lines += [f"total {time.perf_counter() - t_all:.0f} s"]
    text = "\n".join(lines)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
