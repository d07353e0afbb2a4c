"""The report of the best static gain's analyses: the gain, representability, linearisation.

The tables of sections 3 and 4 of ``analysis/best_linear_gain/best_linear_gain.py``, from the gains
its search found (:func:`gain_report`): the best gain against L's by column block, the closed loops
on the hover linearisation, whether an undelayed linear model or some cost has the best gain as its
LQR gain, the LQR gain of the least-squares model of L's visited states, and the hover
linearisation's error over the visited states. Imported by that script; run alone it does nothing.
"""

import time

import jax
import jax.numpy as jnp
import numpy as np
from linear_gain_analysis import (  # beside this script
    inverse_optimality,
    least_squares_model,
    linearisation_error,
    model_with_gain,
    scaled_error,
)
from linear_gain_flights import (  # beside this script
    BLOCKS,
    N_Z,
    STATE_BLOCKS,
    fmt,
    held_out,
    mean_se,
    no_du_prev,
    true_next,
    visited,
)

import loopid  # noqa: F401  (float64)
from loopid.control.lqr_affine import dlqr_affine
from loopid.systems import helicopter
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task

VISIT_KEY = 303
#: Action noise of the flights the least-squares model is fitted on (ν_en's: variance 1e-4).
FIT_ACTION_STD = 0.01


def gain_report(found: dict, n_visit: int) -> list[str]:
    """Sections 3 and 4 as Markdown lines, from ``found`` (per panel: task, plant, K_L, K_best,
    held-out noise) and ``n_visit`` flights per gain for the visited states."""
    lat = found["hover-delay, latency"]
    lines = []
    # ---- 3: the gains, representability (d = 1, latency) and the least-squares model
    lines += ["", "### The best gain against L's", ""]
    lines += ["| panel | " + " | ".join(b for b, _ in BLOCKS) + " | whole |",
              "|---|" + "---|" * (len(BLOCKS) + 1)]  # fmt: skip
    for label in ("hover (d = 0)", "hover-delay, latency"):
        K_L, K_b = np.asarray(found[label]["K_L"]), np.asarray(found[label]["K_best"])
        cells = [
            f"{np.linalg.norm(K_b[:, sl] - K_L[:, sl]):.3f} / {np.linalg.norm(K_L[:, sl]):.3f}"
            for _, sl in BLOCKS
        ]
        whole = np.linalg.norm(K_b - K_L) / np.linalg.norm(K_L)
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {whole:.3f} (relative) |")
    lines += ["", "(cells: ‖K_best − K_L‖_F / ‖K_L‖_F of the block's columns)"]

    target = make_task("hover").target
    A, B = (np.asarray(M) for M in helicopter.linearize(target[0], target[1]))
    Q, R = np.asarray(make_task("hover").Q), np.asarray(make_task("hover").R)
    lines += ["", "### Closed loops on the hover linearisation (spectral radius)", "",
              "| gain | undelayed (acts on Δx_t) | delayed (acts on Δx_{t−1}) |",
              "|---|---|---|"]  # fmt: skip
    Az, Bz = A[:N_Z, :N_Z], B[:N_Z]
    for name, K in (("L", lat["K_L"]), ("best, d = 1", lat["K_best"]),
                    ("best, d = 0", found["hover (d = 0)"]["K_best"])):  # fmt: skip
        Kz = np.asarray(K)[:, :N_Z]
        und = np.max(np.abs(np.linalg.eigvals(Az - Bz @ Kz)))
        big = np.block([[Az, -Bz @ Kz], [np.eye(N_Z), np.zeros((N_Z, N_Z))]])
        dly = np.max(np.abs(np.linalg.eigvals(big)))
        lines.append(f"| {name} | {und:.4f} | {dly:.4f} |")

    # visited states (also for section 4); "fit": L's flights with ν_en's action noise
    visits = {}
    for label in ("hover (d = 0)", "hover-delay, latency"):
        f = found[label]
        flight_plant = helicopter_plant(f["task"], delay_mode="latency", stop_norm=1e300)
        key = jax.random.PRNGKey(VISIT_KEY)
        for gname, K, std in (("K_L", f["K_L"], 0.0), ("K_best", f["K_best"], 0.0),
                              ("fit", f["K_L"], FIT_ACTION_STD)):  # fmt: skip
            x, dx, du = visited(flight_plant, K, n_visit, key, std)
            visits[label, gname] = (dx, du, true_next(x, du, target[0]))

    lines += ["", "### Is the best delay-1 gain an LQR gain of an undelayed linear model?", ""]
    dx, du, nxt = visits["hover-delay, latency", "K_L"]
    zc = dx[:, : N_Z + 1]
    sigma = jnp.asarray(zc.T @ zc / zc.shape[0])
    K_best = lat["K_best"]
    noise_std = {"velocity": helicopter.DT / helicopter.MASS,
                 "rates": helicopter.DT / helicopter.INERTIA}  # fmt: skip
    any_row, noisy_rows = np.ones(N_Z), np.zeros(N_Z)
    noisy_rows[8:11], noisy_rows[14:17] = noise_std["velocity"], noise_std["rates"]
    lines += [
        f"Constructed: a model Â (B kept at the hover linearisation's) whose LQR gain with the "
        f"task's Q, R is K_best, by Gauss-Newton from Â = A with minimum steps in the metric of "
        f"the mean squared one-step prediction over the {dx.shape[0]} states L visits "
        f"({n_visit} flights, PRNGKey({VISIT_KEY})). (a) any row of A may change; (b) only "
        "the velocity and rate rows (the only ones the process noise enters, so the only ones "
        "a least-squares learner cannot pin down exactly), weighted by 1/noise variance.",
        "",
        "| construction | Gauss-Newton max residual (steps) | dlqr_affine on Â: converged, "
        "spectral radius | max abs(K_LQR(Â, B) − K_best) | ‖Â − A‖_F (‖A − I‖_F = "
        f"{np.linalg.norm(A - np.eye(21)):.3f}) | s |",
        "|---|---|---|---|---|---|",
    ]
    models = {}
    for name, row_scale in (("(a) any row", any_row), ("(b) velocity and rate rows", noisy_rows)):
        t0 = time.perf_counter()
        A_hat, gn = model_with_gain(*(jnp.asarray(M) for M in (A, B, Q, R)), K_best, sigma,
                                    row_scale)  # fmt: skip
        sol = dlqr_affine(*(jnp.asarray(M) for M in (A_hat, B, Q, R)))
        gap = float(jnp.max(jnp.abs(sol.K - K_best)))
        models[name] = A_hat
        lines.append(
            f"| {name} | {gn[0]:.2e} → {gn[-1]:.2e} ({len(gn) - 1}) | {bool(sol.converged)}, "
            f"{float(sol.spectral_radius):.4f} | {gap:.2e} | {np.linalg.norm(A_hat - A):.3f} "
            f"| {time.perf_counter() - t0:.0f} |"
        )
    lines += [
        f"(max abs entry of K_best: {float(jnp.max(jnp.abs(K_best))):.3f})",
        "",
        "One-step prediction error over the visited states (RMS against the noise-free true "
        "step; in brackets the extra mean squared error over the linearisation's, in units "
        "of the block's process-noise variance):",
        "",
        "| block | true linearisation | " + " | ".join(models) + " | process noise std |",
        "|---|---|---|---|---|",
    ]
    err_true = linearisation_error(A, B, dx, du, nxt)["blocks"]
    err_hat = {k: linearisation_error(M, B, dx, du, nxt)["blocks"] for k, M in models.items()}
    for name, _ in STATE_BLOCKS:
        cells = []
        for k in models:
            e = err_hat[k][name][0]
            extra = (
                (e**2 - err_true[name][0] ** 2) / noise_std[name] ** 2
                if name in noise_std
                else None
            )
            cells.append(f"{e:.2e}" + (f" ({extra:.1e})" if extra is not None else ""))
        noise = f"{noise_std[name]:.4f}" if name in noise_std else "0"
        lines.append(f"| {name} | {err_true[name][0]:.2e} | " + " | ".join(cells) + f" | {noise} |")

    t0 = time.perf_counter()
    lines += [
        "",
        "Inverse optimality for the true (A, B): the smallest distance (scaled units; the task's "
        "cost has ‖Q̃‖ = ‖R̃‖ = 1) from the set of costs (Q', R') that make the gain the "
        "stabilising LQR gain of the hover linearisation to {Q' ⪰ 0, R' ⪰ 1e-3·I}; 0 means "
        "some such cost exists.",
        "",
        "| gain | undelayed closed loop stable | distance | gradient norm at the end "
        "| L-BFGS iterations | dim of the cost set | λmin Q̃', R̃' at the minimiser |",
        "|---|---|---|---|---|---|---|",
    ]
    K_best0 = found["hover (d = 0)"]["K_best"]
    for name, K in (("L (control)", lat["K_L"]), ("best, d = 1", K_best),
                    ("best, d = 1, du_prev columns 0", no_du_prev(K_best)),
                    ("best, d = 0", K_best0),
                    ("best, d = 0, du_prev columns 0", no_du_prev(K_best0))):  # fmt: skip
        io = inverse_optimality(A, B, Q, R, K)
        if io is None:
            lines.append(f"| {name} | no | — | — | — | — | — |")
            continue
        lines.append(
            f"| {name} | yes | {io['dist']:.2e} | {io['grad']:.1e} | {io['iterations']} "
            f"| {io['dim']} | {io['min_eig_Q']:.2e}, {io['min_eig_R']:.2e} |"
        )
    lines.append(f"({time.perf_counter() - t0:.0f} s)")

    lines += ["", "### LQR on the least-squares model of the true steps over L's visited states",
              "", f"L's flights with action noise std {FIT_ACTION_STD} ({n_visit} x 400 "
              f"steps, PRNGKey({VISIT_KEY})), noise-free true steps as targets; held-out costs "
              "(same noise as above) of the LQR gain of the fitted model (Â, B̂), of (Â, B) "
              "and of (A, B̂) (A, B: the hover linearisation).", "",
              "| panel, reading | held-out L | K_fit = LQR(Â, B̂) | L − K_fit (paired) "
              "| LQR(Â, B) | LQR(A, B̂) | held-out best | ‖K_fit − K_L‖/‖K_L‖ "
              "| ‖K_fit − K_best‖/‖K_L‖ | velocity rows: ‖Â − A‖_F |",
              "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for label in ("hover (d = 0)", "hover-delay, latency"):
        f = found[label]
        dxL, duL, nxtL = visits[label, "fit"]
        A_ls, B_ls = least_squares_model(A, B, dxL, duL, nxtL)
        gains = {"L": f["K_L"], "best": f["K_best"]}
        for name, (Am, Bm) in {"fit": (A_ls, B_ls), "A fit": (A_ls, B),
                               "B fit": (A, B_ls)}.items():  # fmt: skip
            gains[name] = dlqr_affine(*(jnp.asarray(M) for M in (Am, Bm, Q, R))).K
        c = {k: v[0] for k, v in held_out(f["plant"], gains, f["test"]).items()}
        nL = np.linalg.norm(np.asarray(f["K_L"]))
        lines.append(
            f"| {label} | {fmt(*mean_se(c['L']))} | {fmt(*mean_se(c['fit']))} "
            f"| {fmt(*mean_se(c['L'] - c['fit']))} | {fmt(*mean_se(c['A fit']))} "
            f"| {fmt(*mean_se(c['B fit']))} | {fmt(*mean_se(c['best']))} "
            f"| {np.linalg.norm(np.asarray(gains['fit'] - f['K_L'])) / nL:.3f} "
            f"| {np.linalg.norm(np.asarray(gains['fit'] - f['K_best'])) / nL:.3f} "
            f"| {np.linalg.norm((A_ls - A)[8:11]):.3f} |"
        )

    # ---- 4: linearisation error over visited states
    lines += ["", "### Linearisation error over visited states", "",
              f"{n_visit} flights x 400 steps per gain (PRNGKey({VISIT_KEY})); cells: RMS "
              "error of the hover linearisation's one-step prediction / RMS of the true "
              "noise-free increment (ratio).", ""]  # fmt: skip
    names = [b for b, _ in STATE_BLOCKS]
    lines += ["| flights | ‖Δx‖ bin | n | " + " | ".join(names) + " |",
              "|---|---|---|" + "---|" * len(names)]  # fmt: skip
    for (label, gname), (dx, du, nxt) in visits.items():
        if gname == "fit":
            continue
        e = linearisation_error(A, B, dx, du, nxt)
        who = f"{label}, {'L' if gname == 'K_L' else 'best'}"
        cells = [f"{a:.1e} / {b:.1e} ({a / b:.3f})" for a, b in e["blocks"].values()]
        lines.append(f"| {who} | all | {e['n']} | " + " | ".join(cells) + " |")
        for row in e["bins"]:
            cells = [f"{row[nm][0]:.1e} ({row[nm][0] / row[nm][1]:.3f})" for nm in names]
            lines.append(
                f"| | {row['lo']:.2f}-{row['hi']:.2f} (mean {row['mean_norm']:.2f}) "
                f"| {row['n']} | " + " | ".join(cells) + " |"
            )
    scales = (1.0, 0.5, 0.25)
    lines += ["", "The same error when every visited deviation from the trim (Δx and Δu) is "
              "scaled by s (RMS; in brackets relative to s = 1; a quadratic nonlinearity gives "
              "s², i.e. 0.25 and 0.0625):", "",
              "| L's flights | s | velocity | attitude |", "|---|---|---|---|"]  # fmt: skip
    for label in ("hover (d = 0)", "hover-delay, latency"):
        dx, du, _ = visits[label, "K_L"]
        sc = scaled_error(A, B, dx, du, target[0], scales)
        for sv in scales:
            cells = [f"{sc[sv][b]:.2e} ({sc[sv][b] / sc[1.0][b]:.4f})"
                     for b in ("velocity", "attitude")]  # fmt: skip
            lines.append(f"| {label} | {sv:g} | " + " | ".join(cells) + " |")
    lines += ["", f"Process noise std per step: velocity {helicopter.DT / helicopter.MASS:.4f} "
              f"m/s, rates {helicopter.DT / helicopter.INERTIA:.4f} rad/s (none on position and "
              "attitude within one step).", ""]  # fmt: skip
    return lines


if __name__ == "__main__":
    print("helpers of analysis/best_linear_gain/best_linear_gain.py: run that script")
