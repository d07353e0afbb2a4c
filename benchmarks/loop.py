"""One cell of the loop: hover with delay, DAgger with ν_t, 20 seeds × 100 iterations, vs NumPy.

The cell of the paper's Figure 2 (its hover-delay panel, at full scale): 100 samples per iteration,
100 test trajectories of 400 steps per seed and iteration, 20 seeds, 100 iterations. The JAX row
is :func:`loopid.algorithms.loop.run_learning` on a compiled cell (warmed up on 2 iterations
first, so the time excludes compilation; it includes drawing the test noise). The reference is
the same cell written as a plain Python loop over seeds, iterations and time steps with NumPy
(the helicopter step of ``benchmarks/sim.py``, vectorised over the 100 test trajectories and
the ν queries, FTRL sufficient statistics, SciPy's DARE with the finite-horizon fallback), run
for 2 iterations and extrapolated to 100.

Simulator steps counted per seed: every iteration 100 × 400 test steps; every iteration n ≥ 2
one 400-step policy rollout and 100 ν queries (one step each).

    .venv/bin/python benchmarks/loop.py
"""

import time

import jax
import numpy as np
import scipy.linalg

import loopid  # noqa: F401  (float64)
from loopid.algorithms.contracts import LoopSpec
from loopid.algorithms.exploration import make_nu
from loopid.algorithms.loop import run_learning
from loopid.algorithms.loop_program import make_loop_program
from loopid.algorithms.model_based import linear_agent
from loopid.experiments.families.helicopter import methods as M
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.learners import ftrl_least_squares
from loopid.systems import helicopter as h
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_nominal_model, helicopter_plant
from loopid.systems.helicopter.tasks import make_task
from sim import np_quat_mul, np_step  # benchmarks/sim.py

METHOD = "dagger-t"
S = scenario("hover-delay", iterations=100, samples=100, test_trajectories=100, seeds=20)
REF_ITERATIONS = 2


def steps_per_seed(iterations: int) -> int:
    H = 400
    return iterations * S.test_trajectories * H + (iterations - 1) * (H + S.samples)


# ----------------------------------------------------------------------------- JAX
def jax_cell():
    task = make_task(S.task)
    plant = helicopter_plant(task, stop_norm=S.stop_norm, nu_pending=S.nu_pending)
    agent = linear_agent(
        helicopter_nominal_model(plant),
        ftrl_least_squares(S.ftrl_lambda),
        task.Q,
        task.R,
        plant.horizon,
    )
    nu = make_nu("t", plant, expert_gains(task))
    loop = LoopSpec(plant, agent, nu, samples=S.samples, n_test=S.test_trajectories)
    cell = make_loop_program(loop, S.iterations)
    fractions = M.policy_fractions(METHOD, S.iterations)
    seeds = np.arange(S.seeds)

    def go(iterations):
        return run_learning(loop, fractions[:iterations], seeds, program=cell)

    t0 = time.perf_counter()
    go(2)  # compiles start and step
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    trace = go(S.iterations)  # run_learning returns NumPy arrays: everything has finished
    return time.perf_counter() - t0, compile_s, trace


# ----------------------------------------------------------------------------- NumPy reference
class NumpyCell:
    """The same cell, one seed at a time, as plain Python + NumPy (see the module docstring)."""

    def __init__(self):
        task = make_task(S.task)
        self.x_star = np.asarray(h.hover_target())
        self.Q, self.R = np.asarray(task.Q), np.asarray(task.R)
        self.d = task.delay
        nom = helicopter_nominal_model(helicopter_plant(task))
        self.A0, self.B0 = np.asarray(nom.A), np.asarray(nom.B)
        self.qs_conj = np.concatenate([-self.x_star[17:20], self.x_star[20:]])[None]

    def to_error(self, x):
        e = np_quat_mul(np.broadcast_to(self.qs_conj, (x.shape[0], 4)), x[:, 17:21])[:, :3]
        return np.concatenate([x[:, :17] - self.x_star[:17], e, np.ones((x.shape[0], 1))], 1)

    def from_error(self, dx):
        e = dx[:, 17:20]
        w = np.sqrt(np.maximum(1 - np.sum(e * e, 1, keepdims=True), 0))
        q = np_quat_mul(np.broadcast_to(self.x_star[None, 17:21], (dx.shape[0], 4)),
                        np.concatenate([e, w], 1))  # fmt: skip
        return np.concatenate([self.x_star[:17] + dx[:, :17], q], 1)

    def lqr(self, A, B):
        """Steady-state affine LQR (SciPy DARE on the 20 error coordinates, feedforward from the
        affine column); the first gain of the 400-step finite-horizon LQR when it fails."""
        Q, R = self.Q, self.R
        try:
            a, b, c = A[:20, :20], B[:20], A[:20, 20]
            P = scipy.linalg.solve_discrete_are(a, b, Q[:20, :20], R)
            G = R + b.T @ P @ b
            K = np.linalg.solve(G, b.T @ P @ a)
            Acl = a - b @ K
            if np.max(np.abs(np.linalg.eigvals(Acl))) >= 1:
                raise np.linalg.LinAlgError
            q = np.linalg.solve(np.eye(20) - Acl.T, Acl.T @ P @ c)
            ff = np.linalg.solve(G, b.T @ (P @ c + q))
            return np.concatenate([K, ff[:, None]], 1)
        except (np.linalg.LinAlgError, ValueError):
            P = Q.copy()
            for _ in range(400):
                K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
                P = Q + A.T @ P @ (A - B @ K)
            return K

    def run_seed(self, seed: int, iterations: int):
        rng = np.random.default_rng(seed)
        n_test, m, H = S.test_trajectories, S.samples, 400
        eval_noise = rng.normal(size=(n_test, H, 6))
        ZZ, ZY, count = np.zeros((25, 25)), np.zeros((25, 21)), 0
        K = self.lqr(self.A0, self.B0)
        costs = []
        for n in range(1, iterations + 1):
            if n >= 2:
                # policy half: one 400-step rollout with restarts, uniform draws among valid steps
                rows, x, fifo, tau = [], self.x_star[None].copy(), np.zeros((self.d, 4)), 0
                for _ in range(H):
                    dx = self.to_error(x)
                    du = -dx @ K.T
                    safe = np.linalg.norm(np.concatenate([dx[0, :20], du[0]])) <= S.stop_norm
                    queue = np.concatenate([fifo, du])
                    x_next = np_step(x, queue[:1], rng.normal(size=(1, 6)))
                    if safe:
                        rows.append((dx[0], du[0], self.to_error(x_next)[0]))
                    restart = not safe or tau + 1 >= H
                    x = self.x_star[None].copy() if restart else x_next
                    fifo = np.zeros((self.d, 4)) if restart else queue[1:]
                    tau = 0 if restart else tau + 1
                pick = rng.choice(len(rows), size=min(m, len(rows)), replace=False)
                pol = [np.stack(a) for a in zip(*(rows[i] for i in pick), strict=True)]
                # ν_t: noisy target states and small actions, queried one step (pending = du)
                xi = np.sqrt(S.nu_state_var) * rng.normal(size=(m, 20))
                dx = np.concatenate([xi, np.ones((m, 1))], 1)
                du = np.sqrt(S.nu_action_var) * rng.normal(size=(m, 4))
                dxn = self.to_error(np_step(self.from_error(dx), du, rng.normal(size=(m, 6))))
                take = rng.random(m) < 0.5
                k = min(int(take.sum()), len(pol[0]))
                dx = np.concatenate([pol[0][:k], dx[k:]])
                du = np.concatenate([pol[1][:k], du[k:]])
                dxn = np.concatenate([pol[2][:k], dxn[k:]])
                z = np.concatenate([dx, du], 1)
                y = dxn - dx @ self.A0.T - du @ self.B0.T
                ZZ, ZY, count = ZZ + z.T @ z, ZY + z.T @ y, count + m
                W = np.linalg.solve(ZZ + S.ftrl_lambda * np.sqrt(count) * np.eye(25), ZY)
                K = self.lqr(self.A0 + W[:21].T, self.B0 + W[21:].T)
            # test: 100 trajectories vectorised, a Python loop over time
            x, fifo, total = np.tile(self.x_star, (n_test, 1)), np.zeros((n_test, self.d, 4)), 0.0
            with np.errstate(all="ignore"):
                for t in range(H):
                    dx = self.to_error(x)
                    du = -dx @ K.T
                    total = total + np.einsum("bi,ij,bj->b", dx, self.Q, dx)
                    total = total + np.einsum("bi,ij,bj->b", du, self.R, du)
                    queue = np.concatenate([fifo, du[:, None]], 1)
                    x, fifo = np_step(x, queue[:, 0], eval_noise[:, t]), queue[:, 1:]
                dx = self.to_error(x)
                total = total + np.einsum("bi,ij,bj->b", dx, self.Q, dx)
                total = np.where(np.isfinite(total), np.minimum(total, S.cost_cap), S.cost_cap)
            costs.append(total.mean())
        return costs


def main():
    print(f"devices: {jax.devices()}")
    jax_s, compile_s, trace = jax_cell()
    last = np.median(trace.rows.test_cost[:, -1])
    print(f"JAX: compile + 2 iterations {compile_s:.1f} s; median final test cost {last:.4g}")

    ref = NumpyCell()
    t0 = time.perf_counter()
    for seed in range(S.seeds):
        ref.run_seed(seed, REF_ITERATIONS)
    ref_2 = time.perf_counter() - t0
    # iteration 1 has no training; extrapolate per iteration from the 2 measured
    ref_s = ref_2 * S.iterations / REF_ITERATIONS

    steps = S.seeds * steps_per_seed(S.iterations)
    print(f"\nCell: {S.name} / {METHOD}, {S.seeds} seeds × {S.iterations} iterations, ")
    print(f"{S.samples} samples/iteration, {S.test_trajectories} test trajectories × 400 steps")
    print(f"simulator steps in the cell: {steps:.3e}")
    print(f"{'implementation':44s} {'time [s]':>9s} {'steps/s':>10s} {'speed-up':>9s}")
    rows = (
        ("JAX run_learning (after compilation)", jax_s),
        (f"NumPy loop ({REF_ITERATIONS} iterations, extrapolated)", ref_s),
    )
    for label, sec in rows:
        print(f"{label:44s} {sec:9.2f} {steps / sec:10.2e} {ref_s / sec:8.1f}x")
    print("goal: JAX row ≤ 15 s on the 2-core machine")


if __name__ == "__main__":
    main()
