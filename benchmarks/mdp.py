"""Value iteration on 20 random MDPs (S = 500, A = 8, γ = 0.95), batched in JAX, against a
plain NumPy loop (one MDP at a time, one matrix-vector product per backup, the same stopping
rule). Each is timed 3 times, alternating so both see the same machine load, after compilation;
prints the best of each, its CPU seconds (process time: CPU / wall is the number of cores it kept
busy) and the ratio. Both use every core: NumPy's OpenBLAS runs its matrix-vector products on
``OPENBLAS_NUM_THREADS`` threads (default: the core count), and XLA splits each backup's
``[S·A, S] @ [S]`` product over its intra-op thread pool (measured: per-thread CPU time is even
over 2 threads). Both are bound by reading P (16 MB per MDP and backup) from the cache.

    .venv/bin/python benchmarks/mdp.py
"""

import os
import time

import jax
import numpy as np

import loopid  # noqa: F401  (float64)
from loopid.control.value_iteration import value_iteration
from loopid.systems.mdp import random_mdp

B, S, A, GAMMA, TOL = 20, 500, 8, 0.95, 1e-8


def numpy_vi(P, C, gamma, tol):
    """Value iteration for one MDP: V ← min_a C + γ P V until γδ/(1−γ) ≤ tol."""
    P2 = P.reshape(S * A, S)
    V = np.zeros(S)
    threshold = tol * (1 - gamma) / gamma
    iterations = 0
    while True:
        V_new = (C + gamma * (P2 @ V).reshape(S, A)).min(axis=1)
        delta = np.abs(V_new - V).max()
        V = V_new
        iterations += 1
        if delta <= threshold:
            return V, iterations


def best_of_alternating(fs, repeats=3):
    """Best (wall, CPU) seconds and an output of each function in ``fs``, run in turn
    ``repeats`` times."""
    times, outs = [[] for _ in fs], [None] * len(fs)
    for _ in range(repeats):
        for i, f in enumerate(fs):
            t0, c0 = time.perf_counter(), time.process_time()
            outs[i] = f()
            times[i].append((time.perf_counter() - t0, time.process_time() - c0))
    return [min(t) for t in times], outs


def main():
    mdps = random_mdp(jax.random.split(jax.random.key(0), B), S, A, gamma=GAMMA)
    P, C = np.asarray(mdps.P), np.asarray(mdps.C)

    def jax_run():
        sol = value_iteration(mdps.P, mdps.C, mdps.gamma, tol=TOL)
        return jax.block_until_ready(sol)

    jax_run()  # compile

    def numpy_run():
        return [numpy_vi(P[i], C[i], GAMMA, TOL) for i in range(B)]

    ((t_jax, c_jax), (t_np, c_np)), (sol, outs) = best_of_alternating([jax_run, numpy_run])
    err = max(np.abs(np.asarray(sol.V[i]) - outs[i][0]).max() for i in range(B))
    print(f"value iteration, {B} MDPs, S={S}, A={A}, gamma={GAMMA}, tol={TOL:g}")
    print(f"{os.cpu_count()} cores, jax on {jax.devices()[0].device_kind}")
    blas = os.environ.get("OPENBLAS_NUM_THREADS", "default")
    print(f"OPENBLAS_NUM_THREADS={blas}, load average {os.getloadavg()[0]:.2f}")
    print(f"{'implementation':<28}{'seconds':>10}{'cpu s':>10}{'backups':>10}")
    print(f"{'jax batched (vi)':<28}{t_jax:>10.3f}{c_jax:>10.3f}{int(sol.iterations):>10}")
    backups = max(o[1] for o in outs)
    print(f"{'numpy loop over MDPs':<28}{t_np:>10.3f}{c_np:>10.3f}{backups:>10}")
    print(f"ratio numpy / jax: {t_np / t_jax:.2f}x   max |V_jax - V_numpy| = {err:.1e}")


if __name__ == "__main__":
    main()
