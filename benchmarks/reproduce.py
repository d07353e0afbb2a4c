"""Whole ``loopid reproduce`` commands, this tree against a named reference, in one run.

The reference is a git revision of this repository (``--reference``, default
:data:`REFERENCE`: the last commit before the compile-once work), checked out
into a temporary worktree and run from it with this environment's Python, so that both sides
share the machine, the packages and the moment. The two sides alternate, ``--runs`` times each;
every run starts with an empty compilation cache (``LOOPID_JAX_CACHE``: a cold start, what a
fresh clone pays) unless ``--warm``. Printed: each side's wall time (min / median / max) and
the XLA programs its first run's cells compiled and loaded from the cache, their
ratio (reference / this tree: above 1 is faster), and whether the two tables are equal
(``pyarrow.Table.equals``), else which (scenario, method) cells differ and by how much.

    .venv/bin/python benchmarks/reproduce.py                 # --quick, 3 runs each
    .venv/bin/python benchmarks/reproduce.py --readings literal   # the same work on both sides
    .venv/bin/python benchmarks/reproduce.py --full --runs 1 # the whole of Figure 2 (~10 min a run)
    .venv/bin/python benchmarks/reproduce.py --reference HEAD~3 --warm

On an accelerator the same script runs both sides on it (each side's report.md names the
device); compare a GPU's figures with a GPU's only.
"""

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parent.parent

#: The default reference: the last commit before the compile-once work (programs of one lane
#: width, the learning loop at LLVM level 1, fewer small programs). Earlier references: 1589106
#: (before the engine's batching and backend work).
REFERENCE = "4ee9c89"


def worktree(rev: str, where: Path) -> Path:
    """A detached checkout of ``rev`` at ``where`` (removed by :func:`remove_worktree`)."""
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(where), rev],
                   check=True)  # fmt: skip
    return where


def remove_worktree(where: Path) -> None:
    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(where)],
                   check=False, capture_output=True)  # fmt: skip


def run_once(tree: Path, args: list[str], out: Path, cache: Path) -> float:
    """Wall seconds of ``python -m loopid reproduce ARGS --out OUT`` run from ``tree``'s sources."""
    env = {**os.environ, "PYTHONPATH": str(tree / "src"), "LOOPID_JAX_CACHE": str(cache),
           "PYTHONWARNINGS": "ignore"}  # fmt: skip
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "loopid", "reproduce", *args, "--quiet", "--out", str(out)],
        cwd=tree, env=env, capture_output=True, text=True,
    )  # fmt: skip
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"{tree}: reproduce failed ({done.returncode}): {done.stderr[-2000:]}")
    return seconds


def differences(a_file: Path, b_file: Path) -> list[str]:
    """The cells whose rows differ between two results tables, with the largest relative
    difference of their test cost; empty when the tables are equal."""
    a, b = pq.read_table(a_file), pq.read_table(b_file)
    if a.equals(b):
        return []
    if a.num_rows != b.num_rows:
        return [f"row counts differ: {a.num_rows} and {b.num_rows}"]
    lines = []
    cells = sorted(set(zip(a["scenario"].to_pylist(), a["method"].to_pylist(), strict=True)))
    for scenario, method in cells:
        mask = pc.and_(pc.equal(a["scenario"], scenario), pc.equal(a["method"], method))
        x, y = a.filter(mask), b.filter(mask)
        if x.equals(y):
            continue
        cx, cy = x["test_cost"].to_numpy(), y["test_cost"].to_numpy()
        rel = np.max(np.abs(cx - cy) / np.maximum(np.abs(cx), 1e-300))
        lines.append(f"{scenario} / {method}: test cost up to {rel:.2g} relative")
    return lines


def programs(out: Path) -> str:
    """The XLA programs a run's cells built (``compiled`` and ``loaded`` in each cell file's
    metadata, Figure 2's and the MDP panel's), or "not recorded" (a tree from before the
    counting)."""
    compiled = loaded = 0
    files = [*out.glob("cells/*__*.parquet"), *out.glob("mdp/cells/*__*.parquet")]
    for f in files:
        meta = pq.read_schema(f).metadata or {}
        if b"loopid.compiled" not in meta:
            return "not recorded"
        compiled += int(meta[b"loopid.compiled"])
        loaded += int(meta[b"loopid.loaded"])
    return f"{compiled} compiled, {loaded} loaded"


def spread(xs: list[float]) -> str:
    return f"{min(xs):.1f} / {statistics.median(xs):.1f} / {max(xs):.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", default=REFERENCE, help="git revision to compare with")
    parser.add_argument("--full", action="store_true", help="the whole protocol, not --quick")
    parser.add_argument("--runs", type=int, default=None, help="runs per side (3 quick, 1 full)")
    parser.add_argument("--warm", action="store_true", help="keep each side's compile cache")
    parser.add_argument("--readings", default=None,
                        help="a readings preset both sides run (literal: same work)")  # fmt: skip
    parser.add_argument("--keep", type=Path, default=None,
                        help="copy this tree's first run directory here")  # fmt: skip
    opts = parser.parse_args()
    runs = opts.runs or (1 if opts.full else 3)
    args = [] if opts.full else ["--quick"]
    if opts.readings is not None:
        args += ["--readings", opts.readings]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ref = worktree(opts.reference, tmp / "reference")
        try:
            times: dict[str, list[float]] = {"reference": [], "this tree": []}
            for i in range(runs):
                for side, tree in (("reference", ref), ("this tree", ROOT)):
                    cache = tmp / f"cache-{side}" / ("warm" if opts.warm else str(i))
                    out = tmp / f"out-{side}-{i}"
                    times[side].append(run_once(tree, args, out, cache))
                    print(f"{side} run {i + 1}: {times[side][-1]:.1f} s", flush=True)
            built = {side: programs(tmp / f"out-{side}-0") for side in times}
            if opts.keep is not None:
                shutil.copytree(tmp / "out-this tree-0", opts.keep, dirs_exist_ok=True)
            changed = []
            for table in ("results.parquet", "mdp/results.parquet"):  # Figure 2, the MDP panel
                a, b = tmp / "out-reference-0" / table, tmp / "out-this tree-0" / table
                if a.is_file() and b.is_file():
                    changed += differences(a, b)
        finally:
            remove_worktree(ref)
    what = "loopid reproduce" + ("" if opts.full else " --quick")
    if opts.readings is not None:
        what += f" --readings {opts.readings}"
    start = "warm cache" if opts.warm else "cold: empty compile cache"
    print(f"\n{what}, {runs} run(s) a side, {start}; {os.cpu_count()} CPUs ({cpu_line()})")
    print("| side | wall s (min / median / max) | XLA programs (first run) |\n|---|---|---|")
    for side, xs in times.items():
        label = f"reference ({opts.reference})" if side == "reference" else side
        print(f"| {label} | {spread(xs)} | {built[side]} |")
    ratio = statistics.median(times["reference"]) / statistics.median(times["this tree"])
    print(f"\nreference / this tree (medians): {ratio:.2f}x")
    print("tables: equal" if not changed else "tables differ:\n- " + "\n- ".join(changed))


def cpu_line() -> str:
    """The CPU's model and whether it has AVX-512 (``/proc/cpuinfo`` on Linux; elsewhere
    :func:`platform.processor`): times are only comparable on the same kind of CPU."""
    import platform

    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine()
    model = next((ln.split(":", 1)[1].strip() for ln in info.splitlines()
                  if ln.startswith("model name")), platform.machine())  # fmt: skip
    return f"{model}, AVX-512 {'yes' if ' avx512f' in info else 'no'}"


if __name__ == "__main__":
    main()
