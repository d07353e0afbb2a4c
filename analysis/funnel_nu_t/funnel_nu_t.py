"""Where ν_t is centred on the funnel, and what DAgger with ν_t (D_t) learns from it.

A diagnostic, not a speed test. ν_t draws its noise around one of three centres
(``nu_t_center``): ``target`` (the cost's target: no collective, level attitude), ``trim`` (the
target's states with the hover-trim controls) or ``nominal`` (the expert's planned, noise-free
flight, its states and actions). For each centre it measures:

1. D_t's learning on the funnel, per iteration and seed: the loop program of the scenario
   (:func:`loopid.algorithms.loop_program.make_loop_program` on the funnel's plant and agent) with
   the three centres' ν_t samplers as three methods of one lane set (DAgger, p_n = ½, ν index 0, 1,
   2), driven one ``step`` at a time. Before iteration n's step the policy it flies, π_{n−1}
   (the carry's ``K``), is flown again in that iteration's training rollout (the same keys:
   :func:`loopid.algorithms.keys.iteration_keys`, ``plant.rollout``, which restarts from the
   start when ``‖[Δx; Δu]‖ > stop_norm``): the target time τ of the first restart (599: none),
   the rollout's valid steps, those on the circles (τ = 100..499), and the policy samples of
   the batch, which must equal the row's ``policy_samples`` (checked, with ``valid_samples``).
   Printed with the row's ``loss_nu`` and ``loss_policy`` (the model's mean squared one-step
   error on the ν draws and the policy draws, before the update) and the test cost over
   ``--n-test`` trajectories (not the protocol's 100). ``--check`` first runs each centre's
   own scenario program (:func:`loopid.experiments.families.helicopter.assembly.setup`,
   method ``dagger-t``) for a few iterations and requires its rows and policies to be bit for
   bit those of the lane set.
2. A ν_t-only fit at one circle step τ (``--tau``): ``--fit-samples`` draws of ν_t at that step
   (the sampler of :func:`loopid.algorithms.exploration.nu_trajectory` with its target time fixed;
   checked row for row, to 1e-12, against the real sampler's draws that land on τ), then plain least
   squares of Δx_{τ+1} on [Δx_τ; Δu_τ] in the learner's error coordinates (relative to the
   target). The block that reads velocity (rows 8:11, ``ned_dot``) from the attitude error
   (columns 17:20) is set beside the same block of: the true simulator's Jacobian at the
   centre (what the fit should find), the true Jacobian along the expert's planned flight
   (what the policy flies through), the funnel's nominal model (``funnel_nominal =
   "heading"``), and D_t's learned model at τ after the last iteration (median over seeds).
   Each block is summarised by its projection on the flight's block, ⟨M, J⟩ / ‖J‖² (1: the
   flight's coupling; negative: reversed), and its size ‖M‖ / ‖J‖; the same summaries follow
   over every circle step (no fit there: the Jacobians, the nominal and the learned models).

Run (``--out``: also write the tables as Markdown):

    .venv/bin/python analysis/funnel_nu_t/funnel_nu_t.py     # 2 seeds, 12 iterations, 1000 draws
    .venv/bin/python analysis/funnel_nu_t/funnel_nu_t.py --full --check --out results.md
                                                             # 4 seeds, 40 iterations

This script holds the command line and the report; beside it, ``funnel_nu_t_learning.py``
runs and tabulates 1 and ``funnel_nu_t_fit.py`` holds the fit and the block summaries of 2.

On 2 shared CPU cores the default took about 3 minutes, ``--full --check`` about 5.5 (of which
the check 2.5: it compiles each centre's own program). Exits 1 if a check fails.
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from funnel_nu_t_fit import (  # beside this script
    ATT,
    VEL,
    centre_of,
    centre_point,
    check_sampler,
    circle_table,
    fmt_block,
    jacobian_at,
    least_squares,
    sampler_at,
    summary,
)
from funnel_nu_t_learning import (  # beside this script
    check_against_scenarios,
    check_rows,
    learning_summary,
    learning_table,
    run_centres,
    scenario,
)

import loopid  # noqa: F401  (float64)
from loopid.experiments.families.helicopter import assembly
from loopid.experiments.families.helicopter.readings import NU_T_CENTERS
from loopid.models.linear_offset import to_matrices

SIZES = {"default": (2, 12, 1000), "full": (4, 40, 4000)}  # seeds, iterations, fit draws


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="4 seeds, 40 iterations, 4000 fit draws")
    ap.add_argument("--seeds", type=int, help="seeds 0..S-1")
    ap.add_argument("--iterations", type=int)
    ap.add_argument("--fit-samples", type=int, help="ν_t draws per centre for the fit")
    ap.add_argument("--tau", type=int, default=300, help="the fit's target time (circles: 100-499)")
    ap.add_argument("--n-test", type=int, default=10, help="test trajectories per seed and it.")
    ap.add_argument("--centres", default=",".join(NU_T_CENTERS))
    ap.add_argument("--check", action="store_true", help="also run each centre's own program")
    ap.add_argument("--check-iterations", type=int, default=4)
    ap.add_argument("--out", help="write the tables as Markdown here")
    args = ap.parse_args()
    S, N, F = SIZES["full" if args.full else "default"]
    S, N, F = args.seeds or S, args.iterations or N, args.fit_samples or F
    seeds = list(range(S))
    centres = args.centres.split(",")
    tau = args.tau
    t_all = time.perf_counter()
    md = [
        "# ν_t's centre on the funnel: what D_t learns",
        "",
        f"Command: `.venv/bin/python analysis/funnel_nu_t/funnel_nu_t.py --seeds {S} "
        f"--iterations {N} --fit-samples {F} --tau {tau} --n-test {args.n_test}"
        + (" --check" if args.check else "")
        + "`. Funnel scenario, probable readings otherwise (funnel_nominal = heading, pads, "
        f"500 samples per iteration, DAgger p_n = ½), seeds {seeds}.",
        "",
    ]

    t0 = time.perf_counter()
    sc = scenario("nominal", N, args.n_test)
    st = assembly.setup(sc)
    plant, target = st.plant, jnp.asarray(st.plant.task.target)
    print(f"setup (expert, nominal, planned flight): {time.perf_counter() - t0:.1f} s")

    # ------------------------------------------------------------------ 2. the fit at τ
    t0 = time.perf_counter()
    flight = centre_of("nominal", plant, st.K_expert)
    J_flight = jacobian_at(target, tau, *centre_point(flight, target, tau))
    Jf = J_flight[VEL, ATT]
    A_nom = np.asarray(st.nominal.A[tau])
    fit_rows = []
    fits = {}
    for c in centres:
        centre = centre_of(c, plant, st.K_expert)
        compared, gap = check_sampler(plant, centre, tau, sc.nu_state_var, sc.nu_action_var)
        sample = sampler_at(plant, centre, tau, sc.nu_state_var, sc.nu_action_var)
        tr = jax.device_get(sample(jax.random.key(2024), F))
        A_fit, _, se, rms = least_squares(tr)
        dx_c, du_c = centre_point(centre, target, tau)
        J_c = jacobian_at(target, tau, dx_c, du_c)
        c4 = float(centre.states[tau][3] + du_c[3])  # the collective the step applies
        fits[c] = A_fit[VEL, ATT]
        fit_rows.append((c, A_fit[VEL, ATT], se[VEL, ATT], rms, J_c[VEL, ATT], c4, compared, gap))
    c4_flight = float(flight.states[tau][3] + flight.actions[tau][3])
    print(f"fits at τ = {tau}: {time.perf_counter() - t0:.1f} s")

    # ------------------------------------------------------------------ 1. the learning
    t0 = time.perf_counter()
    results_list, finals, lane_program = run_centres(st, centres, seeds, N, args.n_test, sc.samples)
    t_learn = time.perf_counter() - t0
    results = dict(zip(centres, results_list, strict=True))
    problems = check_rows(results)
    print(f"learning, {len(centres)} centres x {S} seeds x {N} iterations: {t_learn:.1f} s")
    for p in problems:
        print("CHECK FAILED:", p)
    check_lines = []
    if args.check:
        t0 = time.perf_counter()
        check_lines = check_against_scenarios(
            st, centres, seeds, args.check_iterations, args.n_test, sc.samples, lane_program
        )
        print(f"check against the scenarios' own programs: {time.perf_counter() - t0:.1f} s")
        for line in check_lines:
            print("  " + line)

    # ------------------------------------------------------------------ tables
    md += ["## 1-2. D_t per iteration: training flights and losses", ""]
    md += [
        "τ of 1st restart: the target time at which iteration n's training rollout of π_{n−1} "
        "(599 steps, one rollout per seed and iteration; restarts when ‖[Δx; Δu]‖ > 5) first "
        "left the safe region (599: never). Valid rollout steps: of its 599 steps (after a "
        "restart it flies again from τ = 0). Circle steps: its valid steps at τ = 100..499. "
        "valid_samples / policy_samples / loss_nu / loss_policy: the loop's rows (500 samples "
        "per iteration; loss = mean squared one-step error of the model before the update). "
        "Recomputed policy samples equal the rows' on every seed and iteration: "
        + ("yes." if not problems else "NO: " + "; ".join(problems)),
        "",
    ]
    md += [*learning_summary(results, seeds), ""]
    if check_lines:
        md += ["Lane set against each centre's own scenario program (`dagger-t`):", ""]
        md += ["- " + line for line in check_lines] + [""]
    for c in centres:
        md += [*learning_table(c, results[c], seeds, args.n_test), ""]

    md += [f"## 3. Velocity-from-attitude block at τ = {tau}", ""]
    md += [
        f"Rows: ned_dot error (entries 8:11); columns: attitude error (entries 17:20); "
        f"Δx_{{τ+1}} per unit of attitude error. ν_t fit: {F} draws at τ = {tau} (key 2024), "
        "plain least squares on [Δx (21, constant included); Δu (4)]; SE: the largest standard "
        "error of the block's 9 entries. J at centre: the true simulator's Jacobian at the "
        "centre. Flight: J along the expert's planned flight. Projection = ⟨M, J_flight⟩ / "
        "‖J_flight‖²; size = ‖M‖ / ‖J_flight‖. c'₄: the collective applied at the centre "
        "(body force F_z / m = 1.21 − 27.5 c'₄ m/s², drag aside). Sampler check: rows of the "
        "real ν_t sampler (30,000 draws, key 12345) that landed on τ against the fixed-τ "
        "sampler's (raw states and actions bit for bit; error coordinates to the last bits).",
        "",
        "| block M | 3x3 (rows ned_dot N, E, D) | projection | size | note |",
        "|---|---|---|---|---|",
    ]
    proj, size = summary(Jf, Jf)
    md.append(
        f"| true J along the expert's flight | {fmt_block(Jf)} | {proj:.3f} | {size:.3f} "
        f"| c'₄ = {c4_flight:.3f}, F_z/m = {1.21 - 27.5 * c4_flight:+.2f} |"
    )
    proj, size = summary(A_nom[VEL, ATT], Jf)
    md.append(
        f"| nominal model (heading) | {fmt_block(A_nom[VEL, ATT])} | {proj:.3f} | {size:.3f} "
        "| the initial model |"
    )
    for c, block, se, rms, Jc, c4, compared, gap in fit_rows:
        proj, size = summary(block, Jf)
        md.append(
            f"| ν_t fit, `{c}` | {fmt_block(block)} | {proj:.3f} | {size:.3f} "
            f"| SE ≤ {np.max(se):.3f}, residual RMS {rms:.4f}; sampler check on {compared} "
            f"rows, max diff {gap:.1e} |"
        )
        proj, size = summary(Jc, Jf)
        md.append(
            f"| true J at centre `{c}` | {fmt_block(Jc)} | {proj:.3f} | {size:.3f} "
            f"| c'₄ = {c4:.3f}, F_z/m = {1.21 - 27.5 * c4:+.2f} |"
        )
    for m, c in enumerate(centres):
        W, count = finals[m]["W"], finals[m]["count"]
        A_learned = np.stack([np.asarray(to_matrices(st.nominal, W[s])[0][tau]) for s in range(S)])
        blocks = A_learned[:, VEL, ATT]
        per = [summary(b, Jf) for b in blocks]
        md.append(
            f"| D_t's learned model after it. {N}, `{c}` (median over seeds) "
            f"| {fmt_block(np.median(blocks, 0))} "
            f"| {np.median([p for p, _ in per]):.3f} | {np.median([s for _, s in per]):.3f} "
            f"| per seed projection {'/'.join(f'{p:.2f}' for p, _ in per)}; samples at τ "
            f"{'/'.join(str(int(n)) for n in count[:, tau])} |"
        )
    md.append("")
    md += circle_table(st, finals, centres, target, flight, seeds, N)

    total = time.perf_counter() - t_all
    md += ["", f"Run time: {total:.0f} s in all (learning {t_learn:.0f} s), 2 shared cores."]
    text = "\n".join(md) + "\n"
    print(text)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            f.write(text)
    if problems:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
