"""Is B identifiable from ν_e's rows? The rank and conditioning of the learner's regressors.

Batch with ν_e (B_e) fits the hover offset model ``Δx' ≈ (A + A')Δx + (B + B')Δu`` by ridge
least squares on regressor rows ``z = [Δx; Δu]`` (Δx: the 21 error coordinates, the constant 1
included, so the model is affine; Δu: the 4 control changes), i.e. 25 columns. When every
Δu is an exact linear function of Δx the data matrix Z has rank at most 21 and B' cannot be
separated from A'. Under the ``latency`` reading of a delay the expert applies
``Δu_t = −K Δx_{t−1}`` (its gain on the state observed one step earlier), so the rows need
not be collinear; at delay 0 (and under ``fifo``, whose ν query holds the commanded
``Δu_t = −K Δx_t``) they are.

Measured here, per panel and reading (``hover`` d = 0; ``hover-delay`` under ``latency``;
``hover-delay`` under ``fifo`` with ``nu_pending = "hold"``): ν_e's rows drawn exactly as the
loop draws them (``loopid.algorithms.exploration.make_nus(plant, K_expert)[1]``, the expert's gains
from :func:`loopid.systems.helicopter.expert.expert_gains`), 100 rows per iteration
(the hover protocol), iteration i drawn with ``jax.random.fold_in(PRNGKey(seed), i)``, i = 1..100.
For one iteration (i = 1), the pooled rows of iterations 1-50 and of iterations 1-100:

- the singular values of Z [rows, 25] (with the constant column) and of Z without it
  [rows, 24]: largest, smallest, smallest / largest, and the numerical rank at relative
  tolerance ``RANK_RTOL`` (a singular value counts when it exceeds ``RANK_RTOL`` x the largest);
  also after scaling every column to unit root-mean-square (so the figures do not depend on
  the units of Δu against those of Δx);
- how much of Δu is *not* a linear function of [Δx] (the part that identifies B'): the
  residual of the least-squares regression of Δu on the 21 Δx columns, as the RMS of the
  residual over the RMS of Δu per action channel (0 means collinear), and the smallest
  singular value of the residual over the largest of Δu;
- the learner's view: the smallest eigenvalue of the rows' mean second moment ZᵀZ / n, and
  the eigenvalues (smallest, largest) of its Schur complement on the Δu block (the mean
  second moment of that residual, ``residᵀresid / n``: the data's information on B' once A'
  is fitted), against the learner's ridge λ/√n (λ = 1e-3; n the number of rows): a direction
  whose eigenvalue is far below the ridge is set by the ridge, not by the data;
- Batch's own fit on the same rows (the hover nominal plus the ridge fit, λ = 1e-3, by
  :func:`loopid.algorithms.model_based.linear_agent` with FTRL least squares): the entries of
  the fitted B that carry each control's effect within the step (against the true hover
  linearisation's), whether the LQR on it converged, and its gain's test cost
  (``--n-test`` trajectories of the test protocol, noise key ``TEST_KEY``). One seed: an
  illustration of what the rows support, not Batch's curve.

    .venv/bin/python analysis/nu_e_identifiability/nu_e_identifiability.py [--seed 0]
        [--iterations 100] [--rows 100] [--n-test 200] [--out results.md]

About a minute on 2 cores (each reading compiles its draws, fit and test once).
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import loopid  # noqa: F401  (float64)
from loopid.algorithms.exploration import make_nus
from loopid.algorithms.model_based import linear_agent
from loopid.learners import ftrl_least_squares
from loopid.models.linear_offset import hover_nominal, to_matrices
from loopid.systems import helicopter
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task

RANK_RTOL = 1e-10
RIDGE = 1e-3
TEST_KEY = 7
READINGS = (  # (label, task, delay_mode)
    ("hover, d = 0", "hover", "latency"),
    ("hover-delay, latency", "hover-delay", "latency"),
    ("hover-delay, fifo (hold)", "hover-delay", "fifo"),
)


def draw_rows(plant, seed: int, iterations: int, rows: int):
    """ν_e's rows (:class:`Transitions` ``[iterations, rows]``) as the loop draws them: iteration
    i (1-based) from ``fold_in(PRNGKey(seed), i)``."""
    nu_e = make_nus(plant, expert_gains(plant.task))[1]
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(seed), i))(
        jnp.arange(1, iterations + 1)
    )
    return jax.jit(jax.vmap(lambda k: nu_e(k, rows)))(keys)


def batch_fit(plant, tr, test_noise) -> dict:
    """Batch's model on the rows ``tr [k, rows]`` (the hover nominal plus the ridge fit, λ =
    1e-3, :func:`loopid.algorithms.model_based.linear_agent`), its key B entries, its LQR gain's
    status and that gain's test costs under ``test_noise``."""
    task = plant.task
    model = hover_nominal(helicopter.N_STATE, helicopter.N_ACTION)
    agent = linear_agent(model, ftrl_least_squares(RIDGE), task.Q, task.R, plant.horizon)
    flat = jax.tree_util.tree_map(lambda a: a.reshape((-1, *a.shape[2:])), tr)
    state = agent.update(agent.init(), flat)
    K, info = agent.policy(state)
    _, B_hat = to_matrices(model, state.W)
    costs, diverged = plant.eval_costs(K, test_noise)
    costs = np.asarray(costs)
    return {
        "B": np.asarray(B_hat),
        "converged": bool(info.converged),
        "mean": costs.mean(),
        "se": costs.std(ddof=1) / np.sqrt(costs.size),
        "median": float(np.median(costs)),
        "diverged": int(np.sum(np.asarray(diverged))),
    }


def spectrum(Z: np.ndarray) -> dict:
    """Singular-value summary of ``Z`` [rows, cols]."""
    s = np.linalg.svd(Z, compute_uv=False)
    return {
        "max": s[0],
        "min": s[-1],
        "ratio": s[-1] / s[0],
        "rank": int(np.sum(s > RANK_RTOL * s[0])),
        "cols": Z.shape[1],
        "s": s,
    }


def unit_columns(Z: np.ndarray) -> np.ndarray:
    rms = np.sqrt(np.mean(Z * Z, axis=0))
    return Z / np.where(rms > 0, rms, 1.0)


def analyse(dx: np.ndarray, du: np.ndarray) -> dict:
    """Every figure of the module docstring for one set of rows (dx [n, 21], du [n, 4])."""
    Z = np.concatenate([dx, du], axis=1)
    Z_noc = np.concatenate([dx[:, :-1], du], axis=1)
    coef, *_ = np.linalg.lstsq(dx, du, rcond=None)
    resid = du - dx @ coef
    rms_du = np.sqrt(np.mean(du * du, axis=0))
    rms_res = np.sqrt(np.mean(resid * resid, axis=0))
    n = Z.shape[0]
    second = np.linalg.eigvalsh(Z.T @ Z / n)
    schur = np.linalg.eigvalsh(resid.T @ resid / n)
    return {
        "n": n,
        "Z": spectrum(Z),
        "Z_noc": spectrum(Z_noc),
        "Z_unit": spectrum(unit_columns(Z)),
        "unexplained": rms_res / rms_du,
        "resid_ratio": np.linalg.svd(resid, compute_uv=False)[-1]
        / np.linalg.svd(du, compute_uv=False)[0],
        "eig_min": second[0],
        "schur": schur,
        "resid_ms": rms_res**2,
        "rms_du": rms_du,
        "ridge": RIDGE / np.sqrt(n),
    }


def table(results: list[tuple[str, str, dict]]) -> list[str]:
    lines = [
        "| reading | rows | rank Z (of 25) | σmin/σmax Z | cond Z | rank, no const (of 24) "
        "| σmin/σmax, no const | σmin/σmax, unit columns | RMS Δu per channel | Δu not explained "
        "by Δx (RMS ratio per channel) | σmin(resid)/σmax(Δu) | λmin(ZᵀZ/n) "
        "| Δu-block Schur complement λmin, λmax | its diagonal (per channel) | ridge λ/√n |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, rows_label, r in results:
        unexplained = " ".join(f"{v:.2g}" for v in r["unexplained"])
        rms = " ".join(f"{v:.2g}" for v in r["rms_du"])
        schur = f"{r['schur'][0]:.2e}, {r['schur'][-1]:.2e}"
        diag = " ".join(f"{v:.1e}" for v in r["resid_ms"])
        lines.append(
            f"| {label} | {rows_label} (n = {r['n']}) | {r['Z']['rank']} | {r['Z']['ratio']:.2e} "
            f"| {1 / r['Z']['ratio']:.2e} | {r['Z_noc']['rank']} | {r['Z_noc']['ratio']:.2e} "
            f"| {r['Z_unit']['ratio']:.2e} | {rms} | {unexplained} | {r['resid_ratio']:.2e} "
            f"| {r['eig_min']:.2e} | {schur} | {diag} | {r['ridge']:.1e} |"
        )
    return lines


#: Entries of B (row, column) that carry the controls' effect within the step: rates p, q, r
#: from aileron, elevator, rudder; East and Down velocity from the collective.
B_ENTRIES = (("p←Δc1", 14, 0), ("q←Δc2", 15, 1), ("r←Δc3", 16, 2), ("v_E←Δc4", 9, 3),
             ("v_D←Δc4", 10, 3))  # fmt: skip


def fit_table(fits: list[tuple[str, str, dict]], B_true: np.ndarray, n_test: int) -> list[str]:
    names = " | ".join(name for name, _, _ in B_ENTRIES)
    lines = [
        f"| reading | rows | {names} | dlqr converged | test cost mean ± s.e. | median "
        f"| diverged (of {n_test}) |",
        "|---|---|" + "---|" * len(B_ENTRIES) + "---|---|---|---|",
        "| true linearisation | | "
        + " | ".join(f"{B_true[r, c]:.4g}" for _, r, c in B_ENTRIES)
        + " | | | | |",
    ]
    for label, rows_label, f in fits:
        entries = " | ".join(f"{f['B'][r, c]:.4g}" for _, r, c in B_ENTRIES)
        lines.append(
            f"| {label} | {rows_label} | {entries} | {f['converged']} | {f['mean']:.4g} ± "
            f"{f['se']:.2g} | {f['median']:.4g} | {f['diverged']} |"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--rows", type=int, default=100, help="ν_e rows per iteration")
    ap.add_argument("--n-test", type=int, default=200, help="test trajectories of the fits")
    ap.add_argument("--out", help="also write the tables as Markdown here")
    args = ap.parse_args()
    t_all = time.perf_counter()
    pools = list(dict.fromkeys([1, min(50, args.iterations), args.iterations]))
    results, spectra, fits = [], [], []
    for label, task_name, mode in READINGS:
        t0 = time.perf_counter()
        plant = helicopter_plant(make_task(task_name), delay_mode=mode)
        tr = draw_rows(plant, args.seed, args.iterations, args.rows)
        dx, du, mask = np.asarray(tr.dx), np.asarray(tr.du), np.asarray(tr.mask)
        test_noise = plant.eval_noise(jax.random.PRNGKey(TEST_KEY), args.n_test)
        for k in pools:
            keep = mask[:k].reshape(-1)
            r = analyse(dx[:k].reshape(-1, dx.shape[-1])[keep], du[:k].reshape(-1, 4)[keep])
            rows_label = "iteration 1" if k == 1 else f"iterations 1-{k}"
            results.append((label, rows_label, r))
            spectra.append((label, rows_label, r["Z"]["s"]))
            fit = batch_fit(plant, jax.tree_util.tree_map(lambda a, k=k: a[:k], tr), test_noise)
            fits.append((label, rows_label, fit))
        secs = time.perf_counter() - t0
        print(f"{label}: {args.iterations} x {args.rows} rows and fits in {secs:.1f} s", flush=True)
    target = make_task("hover").target
    _, B_true = helicopter.linearize(target[0], target[1])
    lines = [
        f"ν_e rows as the loop draws them; seed {args.seed} (iteration i: fold_in(PRNGKey("
        f"{args.seed}), i)), {args.rows} rows per iteration; numerical rank at relative "
        f"tolerance {RANK_RTOL:g}; Z = [Δx (21, constant included); Δu (4)].",
        "",
        *table(results),
        "",
        f"Batch's fit on the same rows (hover nominal + ridge λ = {RIDGE:g}, LQR on the fit; "
        f"test: {args.n_test} trajectories of 400 steps, noise key PRNGKey({TEST_KEY})):",
        "",
        *fit_table(fits, np.asarray(B_true), args.n_test),
        "",
        "Singular values of Z (25 columns), largest to smallest:",
        "",
    ]
    for label, rows_label, s in spectra:
        lines.append(f"- {label}, {rows_label}: " + " ".join(f"{v:.2e}" for v in s))
    lines += ["", f"total {time.perf_counter() - t_all:.1f} s"]
    text = "\n".join(lines)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
