"""Learner speed: FTRL update + solve vs a NumPy refit on all aggregated data.

Hover model sizes: 25 features ([Δx; Δu]), 21 targets, 100 new rows per iteration, 20 seeds
(vmapped). Reference: NumPy refit on the aggregated n = 10,000 rows, per seed, i.e. what
"refit on everything so far" costs at iteration 100 without sufficient statistics. Goal: >= 10×.
Extra rows: OGD update, and the funnel's time-varying FTRL (T = 599 steps, 500 rows) through its
scatter-add fast path against the generic vmap-over-steps path; then the funnel at protocol scale
(20 seeds vmapped, 500 rows each, T = 599): the update alone, the same update with the state
donated (in place: what is left once the input state need not be copied), and the 20 x 599
ridge solves alone, so the two halves of the funnel's learner cost can be tracked separately;
last, the solves the loop runs, only the steps that the 500 rows reached
(``touched_weights``), against the 20 x 599.

Run: .venv/bin/python benchmarks/learners.py
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

import loopid  # noqa: F401  (float64)
from loopid.learners import ftrl_least_squares, indexed, ogd, touched_weights

F, TGT, B, SEEDS, N_AGG, LAM = 25, 21, 100, 20, 10_000, 1e-3


def timeit(fn, *args, reps=50):
    """Median wall time of fn(*args) in seconds, after a warm-up (compilation) call."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def numpy_refit(X, Y, lam=LAM):
    n = X.shape[0]
    return np.linalg.solve(X.T @ X / n + lam / np.sqrt(n) * np.eye(X.shape[1]), X.T @ Y / n)


def main():
    rng = np.random.default_rng(0)
    rows = []

    # FTRL: one update with 100 rows + the solve, vmapped over 20 seeds.
    ftrl = ftrl_least_squares(LAM)
    X_agg = rng.normal(size=(SEEDS, N_AGG, F))
    Y_agg = rng.normal(size=(SEEDS, N_AGG, TGT))
    states = jax.vmap(lambda x, y: ftrl.update(ftrl.init(F, TGT), x, y))(
        jnp.asarray(X_agg[:, :-B]), jnp.asarray(Y_agg[:, :-B])
    )
    Xb, Yb = jnp.asarray(X_agg[:, -B:]), jnp.asarray(Y_agg[:, -B:])

    @jax.jit
    def ftrl_step(states, X, Y):
        new = jax.vmap(ftrl.update)(states, X, Y)
        return new, jax.vmap(ftrl.weights)(new)

    t_ftrl = timeit(ftrl_step, states, Xb, Yb)
    W_jax = np.asarray(ftrl_step(states, Xb, Yb)[1])

    def numpy_all_seeds():
        return [numpy_refit(X_agg[s], Y_agg[s]) for s in range(SEEDS)]

    t_np = timeit(numpy_all_seeds, reps=10)
    err = max(np.abs(W_jax[s] - w).max() for s, w in enumerate(numpy_all_seeds()))
    rows.append(("FTRL update(100 rows)+solve, 20 seeds", t_ftrl, "NumPy refit n=10,000 x20", t_np))

    # OGD update, same sizes.
    og = ogd(0.01)
    og_states = jax.vmap(lambda _: og.init(F, TGT))(jnp.arange(SEEDS))
    og_step = jax.jit(jax.vmap(og.update))
    t_ogd = timeit(og_step, og_states, Xb, Yb)
    rows.append(("OGD update(100 rows), 20 seeds", t_ogd, "FTRL update+solve (above)", t_ftrl))

    # Funnel: time-varying FTRL, T = 599, 500 rows, one seed: scatter-add vs vmap over steps.
    T, b = 599, 500
    fast = indexed(ftrl, T)
    slow = indexed(ftrl._replace(update_indexed=None), T)
    Xf, Yf = jnp.asarray(rng.normal(size=(b, F))), jnp.asarray(rng.normal(size=(b, TGT)))
    idx = jnp.asarray(rng.integers(0, T, size=b))
    s0 = fast.init(F, TGT)

    def step_of(learner):
        return jax.jit(lambda s, X, Y, i: learner.weights(learner.update(s, X, Y, index=i)))

    t_fast = timeit(step_of(fast), s0, Xf, Yf, idx, reps=20)
    t_slow = timeit(step_of(slow), s0, Xf, Yf, idx, reps=5)
    rows.append(("indexed FTRL T=599, 500 rows (scatter)", t_fast, "vmap over steps", t_slow))

    # Funnel at protocol scale: 20 seeds, update and solve timed apart (interleaved rounds).
    up = jax.vmap(lambda s, X, Y, m, i: fast.update(s, X, Y, m, index=i))
    Xs = jnp.asarray(rng.normal(size=(SEEDS, b, F)))
    Ys = jnp.asarray(rng.normal(size=(SEEDS, b, TGT)))
    ms = jnp.asarray(rng.random((SEEDS, b)) < 0.9)
    ids = jnp.asarray(rng.integers(0, T, size=(SEEDS, b)), dtype=jnp.int32)
    upd, upd_donated = jax.jit(up), jax.jit(up, donate_argnums=0)
    solve = jax.jit(jax.vmap(fast.weights))
    s20 = jax.vmap(lambda _: fast.init(F, TGT))(jnp.arange(SEEDS))
    for k in range(5):  # a few iterations' data, so the solves see real statistics
        s20 = upd(s20, Xs, Ys, ms, (ids + 37 * k) % T)
    args = (Xs, Ys, ms, ids)
    owned = upd_donated(jax.tree_util.tree_map(jnp.copy, s20), *args)
    jax.block_until_ready((upd(s20, *args), solve(s20), owned))
    base = ftrl_least_squares(LAM)
    touched = jax.jit(jax.vmap(lambda s, W, i, m: touched_weights(base, s, W, i, m)))
    W20 = solve(s20)
    assert np.array_equal(np.asarray(touched(s20, W20, ids, ms)), np.asarray(W20))
    times = {"update": [], "donated": [], "solve": [], "touched": []}
    rounds = (
        ("update", lambda: upd(s20, *args)),
        ("solve", lambda: solve(s20)),
        ("touched", lambda: touched(s20, W20, ids, ms)),
    )
    for _ in range(10):
        for key, fn in rounds:
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times[key].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        owned = jax.block_until_ready(upd_donated(owned, *args))
        times["donated"].append(time.perf_counter() - t0)
    t_up, t_don, t_sol = (float(np.median(times[k])) for k in ("update", "donated", "solve"))
    rows.append(("funnel update, 20 seeds x 500 rows", t_up, "same, state donated", t_don))
    rows.append(("funnel solve, 20 x 599 ridge systems", t_sol, "funnel update (above)", t_up))
    t_tch = float(np.median(times["touched"]))
    rows.append(("funnel solve, the 20 x 500 rows' steps", t_tch, "all 20 x 599 (above)", t_sol))

    print(f"device: {jax.devices()[0].device_kind}; max |W_jax - W_numpy| = {err:.1e}")
    print(f"{'case':42s} {'time':>10s}  {'reference':28s} {'ref time':>10s} {'ratio':>8s}")
    for name, t, ref, tr in rows:
        print(f"{name:42s} {t * 1e3:8.3f}ms  {ref:28s} {tr * 1e3:8.3f}ms {tr / t:7.1f}x")


if __name__ == "__main__":
    main()
