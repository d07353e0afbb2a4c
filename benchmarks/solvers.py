"""Speed of the control solvers against named references, measured side by side in one run.

    .venv/bin/python benchmarks/solvers.py

1. dlqr batched over 20 random stabilisable systems (n = 21, m = 4), time per system, against
   ``scipy.linalg.solve_discrete_are`` (+ the gain) per system. Goal: at least 6x faster.
2. tvlqr, T = 400, ``jax.vmap`` over 20 problems, time per problem, against a NumPy loop of the
   same recursion. Goal: at most 3 ms per problem on the 2-core machine.
3. ilqr on the funnel expert problem (true helicopter, raw state, T = 599): iterations, wall time.

Times are after compilation (``block_until_ready``). Ours and the reference are timed in
alternation, repetition by repetition, so that load from other processes on the shared machine
falls on both alike; each line prints the minimum and the median over the repetitions, and the
ratios of each.

SciPy's reference runs with the BLAS thread pool as installed (OpenBLAS, all cores). On a 2-core
machine shared with other processes the BLAS threads of a 42x42 QZ problem mostly wait on each
other, so the same solve limited to one BLAS thread (``threadpoolctl``) is printed on a separate,
labelled line as a second reference; the goal is stated against the first.
"""

from __future__ import annotations

import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sl

try:  # installed with scikit-learn (test extra); only for the second, 1-thread reference
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover
    threadpool_limits = None

import loopid  # noqa: F401  (float64)
from loopid.control import dlqr, ilqr, tvlqr
from loopid.systems import helicopter
from loopid.systems.base import trajectory_cost


def timed(fn, repeats):
    """Median wall time of ``fn()`` over ``repeats`` runs (first call excluded: compilation)."""
    return timed_alternating([fn], repeats)[0][1]


def timed_alternating(fns, repeats):
    """``[(min, median), ...]`` wall times of each ``fn()``, the functions run in turn.

    One warm-up call each (compilation), then ``repeats`` rounds of one call of every function,
    so that a burst of load from other processes hits all of them in the same round.
    """
    for fn in fns:
        jax.block_until_ready(fn())
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, ts in zip(fns, times, strict=True):
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            ts.append(time.perf_counter() - t0)
    return [(min(ts), statistics.median(ts)) for ts in times]


def random_systems(rng, count, n=21, m=4):
    A = rng.standard_normal((count, n, n)) / np.sqrt(n) * 1.1
    B = rng.standard_normal((count, n, m))
    M = rng.standard_normal((count, n, n))
    Q = M @ np.swapaxes(M, 1, 2) / n + 0.1 * np.eye(n)
    R = np.broadcast_to(np.eye(m), (count, m, m)).copy()
    return A, B, Q, R


def bench_dlqr(rng, count=20):
    A, B, Q, R = random_systems(rng, count)
    Aj, Bj, Qj, Rj = (jnp.asarray(x) for x in (A, B, Q, R))

    def scipy_all():
        for i in range(count):
            P = sl.solve_discrete_are(A[i], B[i], Q[i], R[i])
            np.linalg.solve(R[i] + B[i].T @ P @ B[i], B[i].T @ P @ A[i])

    def scipy_one_thread():
        with threadpool_limits(limits=1):
            scipy_all()

    fns = [lambda: dlqr(Aj, Bj, Qj, Rj).K, scipy_all]
    if threadpool_limits is not None:
        fns.append(scipy_one_thread)
    times = timed_alternating(fns, 30)
    per_system = [(lo / count, med / count) for lo, med in times]
    sol = dlqr(Aj, Bj, Qj, Rj)
    return per_system, bool(jnp.all(sol.converged)), int(jnp.max(sol.iterations))


def tvlqr_numpy(A, B, Q, R, Q_T):
    """The same backward recursion (no affine/linear terms) as a plain NumPy loop."""
    T = A.shape[0]
    P = Q_T
    K = np.empty((T, B.shape[2], A.shape[1]))
    for t in range(T - 1, -1, -1):
        PA, PB = P @ A[t], P @ B[t]
        Huu = R[t] + B[t].T @ PB
        Hux = B[t].T @ PA
        K[t] = np.linalg.solve(Huu, Hux)
        P = Q[t] + A[t].T @ PA - Hux.T @ K[t]
        P = 0.5 * (P + P.T)
    return K


def bench_tvlqr(rng, count=20, T=400, n=21, m=4):
    A = rng.standard_normal((count, T, n, n)) / np.sqrt(n)
    B = rng.standard_normal((count, T, n, m))
    Q = np.broadcast_to(np.eye(n), (count, T, n, n)).copy()
    R = np.broadcast_to(np.eye(m), (count, T, m, m)).copy()
    Q_T = np.broadcast_to(np.eye(n), (count, n, n)).copy()
    Aj, Bj, Qj, Rj, QTj = (jnp.asarray(x) for x in (A, B, Q, R, Q_T))
    solve = jax.jit(jax.vmap(lambda A, B, Q, R, QT: tvlqr(A, B, Q, R, Q_T=QT).K))
    ref_count = 3
    (o_lo, o_med), (r_lo, r_med) = timed_alternating(
        [
            lambda: solve(Aj, Bj, Qj, Rj, QTj),
            lambda: [tvlqr_numpy(A[i], B[i], Q[i], R[i], Q_T[i]) for i in range(ref_count)],
        ],
        15,
    )
    ours = (o_lo / count, o_med / count)
    ref = (r_lo / ref_count, r_med / ref_count)
    K_np = tvlqr_numpy(A[0], B[0], Q[0], R[0], Q_T[0])
    err = float(np.max(np.abs(np.asarray(solve(Aj, Bj, Qj, Rj, QTj))[0] - K_np)))
    return ours, ref, err


def bench_ilqr():
    from loopid.systems.helicopter.expert import funnel_expert_problem
    from loopid.systems.helicopter.tasks import make_task

    task = make_task("funnel")
    dynamics, cost, U0, _ = funnel_expert_problem(task)
    t0 = time.perf_counter()
    sol = jax.block_until_ready(ilqr(dynamics, cost, task.x0, U0))
    first = time.perf_counter() - t0
    wall = timed(lambda: ilqr(dynamics, cost, task.x0, U0).X, 3)
    dX = jax.vmap(helicopter.to_error)(sol.X, task.target)
    pos = float(np.max(np.linalg.norm(np.asarray(dX[:, 11:14]), axis=1)))
    cost_check = float(trajectory_cost(dX, sol.U, task.Q, task.R))
    return sol, first, wall, pos, cost_check


def main():
    rng = np.random.default_rng(0)
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}, float64")
    print("times: min / median over alternating repetitions; ratio = reference / ours\n")
    print(f"{'benchmark':44s} {'ours':>17s} {'reference':>19s} {'ratio':>11s}")
    per_system, conv, iters = bench_dlqr(rng)
    (o_lo, o_med), (r_lo, r_med) = per_system[:2]
    print(
        f"{'dlqr x20 (21x4), per system':44s} {o_lo * 1e6:6.0f} / {o_med * 1e6:4.0f} us "
        f"{r_lo * 1e6:6.0f} / {r_med * 1e6:6.0f} us {r_lo / o_lo:4.1f} / {r_med / o_med:4.1f}x"
        f"   (vs scipy solve_discrete_are, BLAS threads as installed; goal >= 6x;"
        f" converged={conv}, max iter {iters})"
    )
    if len(per_system) > 2:
        s_lo, s_med = per_system[2]
        print(
            f"{'':44s} {'':17s} {s_lo * 1e6:6.0f} / {s_med * 1e6:6.0f} us "
            f"{s_lo / o_lo:4.1f} / {s_med / o_med:4.1f}x"
            "   (second reference: the same SciPy solve limited to 1 BLAS thread)"
        )
    (o_lo, o_med), (r_lo, r_med), err = bench_tvlqr(rng)
    print(
        f"{'tvlqr T=400 vmap x20 (21x4), per problem':44s} "
        f"{o_lo * 1e3:6.2f} / {o_med * 1e3:4.2f} ms "
        f"{r_lo * 1e3:6.2f} / {r_med * 1e3:6.2f} ms {r_lo / o_lo:4.1f} / {r_med / o_med:4.1f}x"
        f"   (vs NumPy loop; goal <= 3 ms; max |dK| {err:.1e})"
    )
    sol, first, wall, pos, cost_check = bench_ilqr()
    print(
        f"{'ilqr funnel (T=599, raw state)':44s} {wall:9.2f} s (median)"
        f"   iterations {int(sol.iterations)}, converged {bool(sol.converged)}, "
        f"first call (with compile) {first:.1f} s"
    )
    print(
        f"{'':44s} cost {float(sol.cost):.2f} (task cost {cost_check:.2f}), "
        f"max position error {pos:.3f} m"
    )


if __name__ == "__main__":
    main()
