"""A panel's learning methods as one lane set against the same methods one at a time, in one run.

The reference is today's default on a CPU: each of the seven learning methods (DAgger, Batch and
Abbeel with each ν) as its own program over the seeds (:func:`loopid.algorithms.loop.
run_learning`, the panel's one compiled cell). The other side is one lane set
(:func:`loopid.algorithms.loop.run_lanes`): every (method, seed) pair a lane of one program,
one call per iteration for all seven. Both run after their compilation (a first, untimed call
each), on the same seeds and test noise, alternating ``--runs`` times; printed: min / median /
max of each and the ratio of the medians (one at a time / lane set: above 1, the lane set is
faster), and whether the traces are bit for bit the same (they must be).

A third side runs the lane set in blocks of ``--block`` iterations (``run_lanes(block=...)``:
each block one ``lax.scan``, its rows fetched once; the default of the helicopter's lane sets
on an accelerator); printed: its ratio to the lane set of one call per iteration, and the
largest relative difference of its traces from that lane set's (0: bit for bit).

    .venv/bin/python benchmarks/lanes.py                     # hover and funnel, 10 seeds
    .venv/bin/python benchmarks/lanes.py --panels hover --seeds 20 --runs 5

On an accelerator, where width is nearly free, the lane set is the default of ``run_cells``.
"""

import argparse
import statistics
import time

import jax
import numpy as np

import loopid
from loopid.algorithms.exploration import NU_KINDS
from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop import iteration_block, run_lanes, run_learning
from loopid.experiments.backend import ACCELERATOR_BLOCK
from loopid.experiments.families import helicopter as H
from loopid.experiments.families.helicopter import assembly
from loopid.experiments.families.helicopter import methods as M
from loopid.experiments.families.helicopter.scenario import scenario

#: Iterations per panel: enough for the learning steps to dominate iteration 1's solve.
ITERATIONS = {"hover": 8, "hover-delay": 8, "funnel": 5}


def timed(f) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = f()
    return time.perf_counter() - t0, out


def largest_difference(a, b) -> float:
    """The largest relative difference between two lists of traces' float leaves."""
    worst = 0.0
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            r = np.abs(x - y) / np.maximum(np.abs(x), np.abs(y))
        r = np.where(same, 0.0, np.where(np.isnan(r), np.inf, r))  # NaN or inf on one side: inf
        worst = max(worst, float(np.max(r, initial=0.0)))
    return worst


def bench(name: str, seeds: int, runs: int, block: int) -> None:
    s = scenario(name, seeds=seeds, iterations=ITERATIONS[name])
    key = H.program_key(s)
    st = assembly._setup(key)
    cell = st.program
    learning = [m for m in M.METHODS if m not in H.NOT_LANES]
    schedules = [M.policy_fractions(m, s.iterations) for m in learning]
    which = [NU_KINDS.index(M.nu_kind(m)) for m in learning]
    ids = np.arange(seeds)
    noise = cell.noise(seed_keys(ids))
    options = dict(program=cell, noise=noise)

    def lanes(block=1):
        return run_lanes(st.loop, schedules, ids, which=which, block=block, **options)

    def one_at_a_time():
        return [
            run_learning(st.loop, f, ids, which=w, **options)
            for f, w in zip(schedules, which, strict=True)
        ]

    blocks = f"blocks of {iteration_block(s.iterations, block)}"
    lanes(), one_at_a_time(), lanes(block)  # compile all three
    times: dict[str, list[float]] = {"one at a time": [], "lane set": [], blocks: []}
    for _ in range(runs):
        t, alone = timed(one_at_a_time)
        times["one at a time"].append(t)
        t, together = timed(lanes)
        times["lane set"].append(t)
        t, in_blocks = timed(lambda: lanes(block))
        times[blocks].append(t)
    same = all(
        np.array_equal(x, y, equal_nan=True)
        for a, b in zip(alone, together, strict=True)
        for x, y in zip(
            jax.tree_util.tree_leaves((a.rows, a.final)),
            jax.tree_util.tree_leaves((b.rows, b.final)),
            strict=True,
        )
    )
    print(f"{name}: 7 learning methods x {seeds} seeds x {s.iterations} iterations")
    for side, ts in times.items():
        print(f"  {side:14s} min {min(ts):7.2f} s  median {statistics.median(ts):7.2f} s  "
              f"max {max(ts):7.2f} s")  # fmt: skip
    ratio = statistics.median(times["one at a time"]) / statistics.median(times["lane set"])
    print(f"  ratio (one at a time / lane set): {ratio:.3f}; bit for bit the same: {same}")
    ratio = statistics.median(times["lane set"]) / statistics.median(times[blocks])
    worst = largest_difference(
        [(t.rows, t.final) for t in together], [(t.rows, t.final) for t in in_blocks]
    )
    print(f"  ratio (lane set / {blocks}): {ratio:.3f}; largest relative difference: {worst:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--panels", default="hover,funnel")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--block", type=int, default=ACCELERATOR_BLOCK)
    args = parser.parse_args()
    print(f"loopid {loopid.__version__}, JAX {jax.__version__} on {jax.default_backend()}")
    for name in args.panels.split(","):
        bench(name, args.seeds, args.runs, args.block)


if __name__ == "__main__":
    main()
