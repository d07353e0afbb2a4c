"""Cost per seed and peak memory as the seed count grows: one hover DAgger (ν_t) cell, 50
iterations, 100 test trajectories, at 20, 200 and 2,000 seeds (``--huge``: also 10,000).

Each size runs in a fresh process through :func:`loopid.experiments.execute.run_cells` with the
default memory budget (:func:`loopid.experiments.chunks.budget`, one process), so it runs in seed
chunks of :data:`loopid.experiments.chunks.LANE_WIDTH` lanes (fewer if the budget asks).
Printed per size: the chunks, the wall time of the whole command, the cell's time after its
first chunk's compilation and two iterations (``wall_s − first_s`` of the cell, per seed and
relative to the 20-seed cell: the reference), and the process's peak RSS.
Cost should grow linearly in the seeds, and the peak stay flat once chunking starts.

    .venv/bin/python benchmarks/seeds.py [--huge] [--sizes 20,200]
"""

import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time

ONE_SIZE = textwrap.dedent(
    """
    import json, resource, sys, tempfile
    import loopid
    from loopid.experiments.execute import run_cells
    from loopid.experiments.executors import compile_cache
    from loopid.experiments.rundir import RunDir
    from loopid.experiments.families.helicopter.scenario import scenario
    from loopid.experiments.chunks import budget

    compile_cache()
    seeds = int(sys.argv[1])
    s = scenario("hover", iterations=50, test_trajectories=100, seeds=seeds)
    with tempfile.TemporaryDirectory() as out:
        run_cells(out, [s], ["dagger-t"])
        meta = RunDir(out).cell_metadata("hover", "dagger-t")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"meta": meta, "peak": peak, "budget": budget(None, 1)}))
    """
)


def one(seeds: int) -> dict:
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, "-c", ONE_SIZE, str(seeds)],
        capture_output=True, text=True, check=True,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )  # fmt: skip
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["command_s"] = time.perf_counter() - t0
    return result


def main() -> None:
    sizes = [20, 200, 2000] + ([10_000] if "--huge" in sys.argv else [])
    if "--sizes" in sys.argv:  # e.g. --sizes 20,200
        sizes = [int(x) for x in sys.argv[sys.argv.index("--sizes") + 1].split(",")]
    print(f"hover / dagger-t, 50 iterations, 100 test trajectories; {os.cpu_count()} CPUs")
    head = f"{'seeds':>7}{'chunks':>8}{'command s':>11}{'run s':>9}{'ms/seed':>9}{'ratio':>7}"
    print(head + f"{'peak GB':>9}{'budget GB':>11}")
    reference = None
    with tempfile.TemporaryDirectory():
        for seeds in sizes:
            r = one(seeds)
            meta = r["meta"]
            run = float(meta["wall_s"]) - float(meta["first_s"])
            per_seed = run / seeds
            reference = reference or per_seed
            print(
                f"{seeds:>7}{int(meta.get('chunks', 1)):>8}{r['command_s']:>11.1f}{run:>9.1f}"
                f"{1e3 * per_seed:>9.1f}{per_seed / reference:>7.2f}{r['peak'] / 1e9:>9.2f}"
                f"{r['budget'] / 1e9:>11.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
