"""Simulator throughput: jitted JAX helicopter under linear feedback vs a NumPy step loop.

Closed loop Δu_t = −K Δx_t[:20] with K the steady-state LQR gain of ``linearize(hover, hover)``
(SciPy DARE, hover weights), 400-step rollouts from hover trim with process noise std 1:
``lax.scan`` over time, ``vmap`` over the batch. The JAX rows draw the noise inside the loop
(row t of ``noise_sequence`` per trajectory) and, separately, run noise-free (the dynamics and
policy alone). The reference is the same step written in NumPy (vectorised over the batch, a
Python loop over time), measured on a few steps and extrapolated. Times are after compilation
(``block_until_ready``), best of a few repeats.

A second table times the loop's test evaluation (one iteration of a hover-delay cell: 20 seeds ×
100 test trajectories of 400 steps under the expert's gain): ``Plant.eval_seeds``, every
trajectory of every seed as one column batch ``[21, 2000]``, against the layout it replaced,
``lax.map`` over seeds of ``vmap`` over trajectories of ``Plant.eval_one`` (batch axis leading).

    .venv/bin/python benchmarks/sim.py
"""

import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

import loopid  # noqa: F401  (float64)
from loopid.systems import helicopter as h
from loopid.systems.helicopter.tasks import HOVER_WEIGHTS, cost_matrices

T = 400
BATCHES = (1, 100, 1_000, 10_000)


def lqr_gain() -> np.ndarray:
    x = h.hover_target()
    A, B = (np.asarray(M) for M in h.linearize(x, x))
    Q, R = (np.asarray(M) for M in cost_matrices(HOVER_WEIGHTS))
    A, B, Q = A[:20, :20], B[:20], Q[:20, :20]
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    return np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)


def make_rollout(K, noisy: bool, chunk: int | None = None):
    """Batched closed-loop rollout (x0 [B, 21], keys [B]) -> x_T [B, 21].

    Every trajectory starts from its own state, so XLA cannot hoist a batch-invariant loop.
    ``chunk``: run the vmapped rollout over chunks of this many trajectories in sequence
    (``lax.map(..., batch_size=chunk)``), which keeps the working set in cache.
    """
    K = jnp.asarray(K)
    x_star = h.hover_target()

    def one(x0, key):
        def body(x, t):
            du = -K @ h.to_error(x, x_star)[:20]
            n = jax.random.normal(jax.random.fold_in(key, t), (6,)) if noisy else jnp.zeros(6)
            return h.step(x, du, n), None

        x, _ = jax.lax.scan(body, x0, jnp.arange(T))
        return x

    if chunk is None:
        return jax.jit(jax.vmap(one))
    return jax.jit(lambda x0, keys: jax.lax.map(lambda a: one(*a), (x0, keys), batch_size=chunk))


def start_states(b, seed=0):
    """Hover trim perturbed by 0.1 in the first 17 coordinates, [b, 21]."""
    rng = np.random.default_rng(seed)
    x = np.tile(np.asarray(h.hover_target()), (b, 1))
    x[:, :17] += 0.1 * rng.normal(size=(b, 17))
    return jnp.asarray(x)


# ----------------------------------------------------------------------------- NumPy reference
def np_quat_mul(p, q):
    pv, pw, qv, qw = p[:, :3], p[:, 3:], q[:, :3], q[:, 3:]
    vec = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([vec, pw * qw - np.sum(pv * qv, axis=1, keepdims=True)], axis=1)


def np_rotmat(q):
    x, y, z, w = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )


def np_step(x, du, noise):
    u = x[:, 0:4] + du
    ned_dot, ned, pqr, q = x[:, 8:11], x[:, 11:14], x[:, 14:17], x[:, 17:21]
    r = h.DT * pqr
    n = np.linalg.norm(r, axis=1, keepdims=True)
    small = n < 1e-4
    vec = np.where(small, 0.5 * r, np.sin(0.5 * n) * r / np.where(small, 1.0, n))
    dq = np.concatenate([vec, np.sqrt(1 - np.sum(vec * vec, 1, keepdims=True))], 1)
    Rm = np_rotmat(q)
    uvw = np.einsum("bji,bj->bi", Rm, ned_dot)
    fb = h.MASS * np.stack(
        [
            h.DRAG_U * uvw[:, 0],
            h.SIDE_FORCE + h.DRAG_V * uvw[:, 1],
            h.LIFT + h.DRAG_W * uvw[:, 2] + h.COLLECTIVE * u[:, 3],
        ],
        1,
    )
    force = np.einsum("bij,bj->bi", Rm, fb) + np.array([0, 0, h.MASS * h.GRAVITY]) + noise[:, :3]
    torque = h.INERTIA * (h.TORQUE_BIAS + h.RATE_DAMPING * pqr + h.CONTROL_GAIN * u[:, :3])
    torque = torque + noise[:, 3:]
    return np.concatenate(
        [
            u,
            du,
            ned_dot + h.DT / h.MASS * force,
            ned + h.DT * ned_dot,
            pqr + h.DT / h.INERTIA * torque,
            np_quat_mul(q, dq),
        ],
        1,
    )


def np_rollout(K, batch, steps, rng):
    x_star = np.asarray(h.hover_target())
    x = np.tile(x_star, (batch, 1))
    qs_conj = np.concatenate([-x_star[17:20], x_star[20:]])[None]
    for _ in range(steps):
        e = np_quat_mul(np.broadcast_to(qs_conj, (batch, 4)), x[:, 17:21])[:, :3]
        dx = np.concatenate([x[:, :17] - x_star[:17], e], 1)
        x = np_step(x, -dx @ K.T, rng.normal(size=(batch, 6)))
    return x


def best_time(fn, repeats=3):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main():
    K = lqr_gain()
    # correctness of the reference: one NumPy step equals one JAX step
    rng = np.random.default_rng(0)
    x = np.asarray(h.hover_target()) + 0.1 * rng.normal(size=(8, 21))
    x[:, 17:] /= np.linalg.norm(x[:, 17:], axis=1, keepdims=True)
    du, n = rng.normal(size=(8, 4)), rng.normal(size=(8, 6))
    err = np.max(np.abs(np_step(x, du, n) - np.asarray(jax.vmap(h.step)(x, du, n))))
    print(f"NumPy reference vs JAX step: max |diff| = {err:.1e}")
    print(f"devices: {jax.devices()}")
    rows = []
    cases = (
        ("JAX vmap, noise-free", False, None, BATCHES),
        ("JAX vmap in chunks of 1000, noise-free", False, 1000, BATCHES[-1:]),
        ("JAX vmap, noise in loop (threefry)", True, None, BATCHES),
    )
    for label, noisy, chunk, batches in cases:
        roll = make_rollout(K, noisy, chunk)
        for b in batches:
            keys, x0 = jax.random.split(jax.random.key(0), b), start_states(b)
            roll(x0, keys).block_until_ready()
            sec = best_time(lambda r=roll, k=keys, x=x0: r(x, k).block_until_ready())
            rows.append((label, b, sec, b * T / sec))
    for b, steps in ((1, 400), (100, 100)):
        sec = best_time(lambda b=b, s=steps: np_rollout(K, b, s, rng), repeats=2) * T / steps
        rows.append(("NumPy step loop (extrapolated)", b, sec, b * T / sec))
    ref = max(r[3] for r in rows if r[0].startswith("NumPy"))
    print(f"\n400-step closed-loop rollouts, hover LQR, {jax.device_count()} device(s)")
    print(f"{'implementation':40s} {'batch':>6s} {'time [s]':>9s} {'steps/s':>10s} "
          f"{'vs NumPy':>9s}")  # fmt: skip
    for label, b, sec, sps in rows:
        print(f"{label:40s} {b:6d} {sec:9.4f} {sps:10.2e} {sps / ref:8.1f}x")
    print("time = one batch of 400-step rollouts; 'vs NumPy' = against the faster NumPy row")


def bench_test_evaluation():
    from loopid.algorithms.keys import seed_keys
    from loopid.algorithms.loop_program import eval_noise
    from loopid.systems.helicopter.expert import expert_gains
    from loopid.systems.helicopter.plant import helicopter_plant
    from loopid.systems.helicopter.tasks import make_task

    seeds, n_test = 20, 100
    task = make_task("hover-delay")
    plant = helicopter_plant(task)
    K = jnp.broadcast_to(expert_gains(task), (seeds, plant.horizon, 4, 21))
    W = eval_noise(plant, seed_keys(np.arange(seeds)), n_test, "last").test
    per_seed = jnp.moveaxis(W, (2, 3), (0, 1))  # [S, n_test, horizon, 6]
    columns = jax.jit(plant.eval_seeds)

    def one_seed(a):
        return jax.vmap(lambda v: plant.eval_one(a[0], v))(a[1])

    rows = jax.jit(lambda K, w: jax.lax.map(one_seed, (K, w)))
    a, b = columns(K, W)[0], rows(K, per_seed)[0]
    err = float(jnp.max(jnp.abs(a - b) / b))
    t_col = best_time(lambda: columns(K, W)[0].block_until_ready(), repeats=5)
    t_row = best_time(lambda: rows(K, per_seed)[0].block_until_ready(), repeats=5)
    steps = seeds * n_test * plant.horizon
    print(f"\nTest evaluation of one loop iteration (hover-delay, {seeds} seeds x {n_test} "
          f"trajectories x {plant.horizon} steps), max relative difference {err:.1e}")  # fmt: skip
    print(f"{'implementation':52s} {'time [ms]':>9s} {'steps/s':>10s} {'ratio':>6s}")
    for label, sec in (
        ("Plant.eval_seeds (column batch [21, S*n_test])", t_col),
        ("lax.map(seeds) of vmap(eval_one) (reference)", t_row),
    ):
        print(f"{label:52s} {1e3 * sec:9.1f} {steps / sec:10.2e} {t_row / sec:5.1f}x")


if __name__ == "__main__":
    main()
    bench_test_evaluation()
