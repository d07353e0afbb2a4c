#!/usr/bin/env bash
# The checks to run on a machine with an accelerator (a GPU), in order of value, each bounded
# in time so that the later ones still run when an earlier one is slow; everything each
# process needs is compiled from an empty cache (a cold start, what a fresh clone pays).
#
#   bash benchmarks/device.sh [OUT]        # OUT: where the log and tables go (default $OUT)
#
# 1. `loopid reproduce` (the whole of Figure 2 and the MDP study), cold: its report.md
#    (backend, device, wall time) and both tables, to compare with a CPU's
#    (docs/development/benchmark-history.md, section "gpu").
# 2. `loopid reproduce --quick`, cold, with the default workers (threads sharing one GPU) and
#    with --workers 1 (one cell after another): the time each takes, and both tables (the same
#    seeds give the same table on one backend whatever the workers).
# 3. benchmarks/seeds.py at 20 and 1,000 seeds: a hover cell's time per seed once compiled.
# 4. The tests of what an accelerator changes (the real device, batched LQR, lane sets).
# 5. benchmarks/lanes.py on the hover: one method at a time, one lane set, and the lane set in
#    blocks of iterations (the accelerator's default), after compiling, and their differences.
# Limits in seconds: FULL_S, QUICK_S (each), SEEDS_S, TEST_S (each test file), LANES_S.
# Python: $PYTHON (default python3).
set -u
out=${1:-${OUT:-/tmp/loopid-device}}
mkdir -p "$out"
log="$out/log.txt"
py=${PYTHON:-python3}
work=$(mktemp -d)
step() { echo "=== $* ($(date +%T))" | tee -a "$log"; }
timed() {  # timed LIMIT CACHE COMMAND...: run with its own empty compilation cache
    local limit=$1 cache=$2 start code
    shift 2
    start=$(date +%s)
    LOOPID_JAX_CACHE="$work/$cache" timeout -k 5 "$limit" "$@" >>"$log" 2>&1
    code=$?
    echo "exit $code after $(($(date +%s) - start)) s: $*" | tee -a "$log"
}
cells() {  # cells NAME RUN_DIR...: each finished cell's times, and when its file was written
    "$py" - "$out/cells_$1.json" "$started" "${@:2}" <<'PY' >>"$log" 2>&1
import json, sys
from pathlib import Path
import pyarrow.parquet as pq
out, start, dirs = sys.argv[1], float(sys.argv[2]), sys.argv[3:]
rows = {}
for d in map(Path, dirs):
    for f in sorted(d.glob("cells/**/*.parquet")):
        meta = {k.decode(): v.decode() for k, v in (pq.read_schema(f).metadata or {}).items()}
        keep = {k[7:]: v for k, v in meta.items() if k[7:] in ("wall_s", "first_s", "chunks")}
        rows[f"{d.name}/{f.relative_to(d)}"] = {**keep, "done_at_s": round(f.stat().st_mtime - start, 1)}
json.dump(rows, open(out, "w"), indent=1)
print(f"{len(rows)} cells recorded in {out}")
PY
}
"$py" -c "import jax; print('JAX', jax.__version__, jax.devices())" >>"$log" 2>&1

step "1. loopid reproduce, cold"
started=$(date +%s)
timed "${FULL_S:-300}" full "$py" -m loopid reproduce --out "$work/runs" --quiet
cells full "$work/runs" "$work/runs/mdp"
cp "$work/runs/report.md" "$out/report.md" 2>/dev/null
cp "$work/runs/results.parquet" "$out/results.parquet" 2>/dev/null
cp "$work/runs/mdp/results.parquet" "$out/mdp_results.parquet" 2>/dev/null

step "2. loopid reproduce --quick, cold: default workers, then --workers 1"
started=$(date +%s)
timed "${QUICK_S:-120}" quick "$py" -m loopid reproduce --quick --out "$work/quick" --quiet
cells quick "$work/quick"
cp "$work/quick/results.parquet" "$out/quick_results.parquet" 2>/dev/null
started=$(date +%s)
timed "${QUICK_S:-120}" quick1 "$py" -m loopid reproduce --quick --workers 1 --out "$work/quick1" --quiet
cells quick1 "$work/quick1"
cp "$work/quick1/results.parquet" "$out/quick1_results.parquet" 2>/dev/null

step "3. a hover cell of 20 and of 1,000 seeds"
timed "${SEEDS_S:-180}" seeds "$py" benchmarks/seeds.py --sizes 20,1000

step "4. the accelerator's tests (one pytest a file: a time limit loses one file's report)"
for f in tests/experiments/test_backend.py tests/algorithms/test_batched_lqr.py \
    tests/experiments/test_lane_sets.py; do
    timed "${TEST_S:-90}" "tests-$(basename "$f" .py)" "$py" -m pytest -q -p no:cacheprovider "$f"
done

step "5. a hover panel one method at a time, as a lane set, and in blocks of iterations"
timed "${LANES_S:-150}" lanes "$py" benchmarks/lanes.py --panels hover --seeds 20 --runs 3

step "done"
rm -rf "$work"
