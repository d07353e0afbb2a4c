"""Speed of the control solvers against named references, measured side by side in one run.

    .venv/bin/python benchmarks/solvers.py

1. dlqr batched over 20 random stabilisable systems (n = 21, m = 4), time per system, against
   ``scipy.linalg.solve_discrete_are`` (+ the gain) per system. Goal: at least 6x faster.
2. tvlqr, T = 400, ``jax.vmap`` over 20 problems, time per problem, against a NumPy loop of the
   same recursion. Goal: at most 3 ms per problem on the 2-core machine.
3. ilqr on the funnel expert problem (true helicopter, raw state, T = 599): iterations, wall time.

Times are after compilation (``block_until_ready``), the median of repeated runs.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sl

import loopid  # noqa: F401  (float64)
from loopid.control import dlqr, ilqr, tvlqr
from loopid.systems import helicopter, tasks

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "control"))


def timed(fn, repeats):
    """Median wall time of ``fn()`` over ``repeats`` runs (first call excluded: compilation)."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


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
    ours = timed(lambda: dlqr(Aj, Bj, Qj, Rj).K, 20) / count

    def scipy_all():
        for i in range(count):
            P = sl.solve_discrete_are(A[i], B[i], Q[i], R[i])
            np.linalg.solve(R[i] + B[i].T @ P @ B[i], B[i].T @ P @ A[i])

    ref = timed(scipy_all, 10) / count
    sol = dlqr(Aj, Bj, Qj, Rj)
    return ours, ref, bool(jnp.all(sol.converged)), int(jnp.max(sol.iterations))


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
    ours = timed(lambda: solve(Aj, Bj, Qj, Rj, QTj), 10) / count
    ref = timed(lambda: [tvlqr_numpy(A[i], B[i], Q[i], R[i], Q_T[i]) for i in range(3)], 3) / 3
    K_np = tvlqr_numpy(A[0], B[0], Q[0], R[0], Q_T[0])
    err = float(np.max(np.abs(np.asarray(solve(Aj, Bj, Qj, Rj, QTj))[0] - K_np)))
    return ours, ref, err


def bench_ilqr():
    from test_ilqr import funnel_expert_problem

    task, dynamics, cost, U0 = funnel_expert_problem()
    t0 = time.perf_counter()
    sol = jax.block_until_ready(ilqr(dynamics, cost, task.x0, U0))
    first = time.perf_counter() - t0
    wall = timed(lambda: ilqr(dynamics, cost, task.x0, U0).X, 3)
    dX = jax.vmap(helicopter.to_error)(sol.X, task.target)
    pos = float(np.max(np.linalg.norm(np.asarray(dX[:, 11:14]), axis=1)))
    cost_check = float(tasks.trajectory_cost(dX, sol.U, task.Q, task.R))
    return sol, first, wall, pos, cost_check


def main():
    rng = np.random.default_rng(0)
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}, float64\n")
    print(f"{'benchmark':44s} {'ours':>12s} {'reference':>12s} {'ratio':>8s}")
    ours, ref, conv, iters = bench_dlqr(rng)
    print(
        f"{'dlqr x20 (21x4), per system':44s} {ours * 1e6:9.1f} us {ref * 1e6:9.1f} us "
        f"{ref / ours:7.1f}x   (vs scipy solve_discrete_are; converged={conv}, max iter {iters})"
    )
    ours, ref, err = bench_tvlqr(rng)
    print(
        f"{'tvlqr T=400 vmap x20 (21x4), per problem':44s} {ours * 1e3:9.2f} ms "
        f"{ref * 1e3:9.2f} ms {ref / ours:7.1f}x   (vs NumPy loop; max |dK| {err:.1e})"
    )
    sol, first, wall, pos, cost_check = bench_ilqr()
    print(
        f"{'ilqr funnel (T=599, raw state)':44s} {wall:9.2f} s  {'':12s} {'':8s}"
        f" iterations {int(sol.iterations)}, converged {bool(sol.converged)}, "
        f"first call (with compile) {first:.1f} s"
    )
    print(
        f"{'':44s} cost {float(sol.cost):.2f} (task cost {cost_check:.2f}), "
        f"max position error {pos:.3f} m"
    )


if __name__ == "__main__":
    main()
