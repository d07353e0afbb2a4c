#!/usr/bin/env bash
# The checks to run on a machine with an accelerator (a GPU), in order of value, each bounded
# in time so that the later ones still run when an earlier one is slow; everything each
# process needs is compiled from an empty cache (a cold start, what a fresh clone pays).
#
#   bash benchmarks/device.sh [OUT]        # OUT: where the log and tables go (default $OUT)
#
# 1. `loopid reproduce` (the whole of Figure 2 and the MDP study), cold: its report.md
#    (backend, device, wall time) and both tables, to compare with a CPU's
#    (docs/benchmarks.md, section "gpu").
# 2. benchmarks/seeds.py at 20 and 1,000 seeds: a hover cell's time per seed once compiled.
# 3. The tests of what an accelerator changes (the real device, batched LQR, lane sets).
# 4. `loopid reproduce --quick`, cold.
# Limits in seconds: FULL_S, SEEDS_S, TEST_S (each test file), QUICK_S. Python: $PYTHON (default python3).
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
"$py" -c "import jax; print('JAX', jax.__version__, jax.devices())" >>"$log" 2>&1

step "1. loopid reproduce, cold"
timed "${FULL_S:-300}" full "$py" -m loopid reproduce --out "$work/runs" --quiet
cp "$work/runs/report.md" "$out/report.md" 2>/dev/null
cp "$work/runs/results.parquet" "$out/results.parquet" 2>/dev/null
cp "$work/runs/mdp/results.parquet" "$out/mdp_results.parquet" 2>/dev/null

step "2. a hover cell of 20 and of 1,000 seeds"
timed "${SEEDS_S:-180}" seeds "$py" benchmarks/seeds.py --sizes 20,1000

step "3. the accelerator's tests (one pytest a file: a time limit loses one file's report)"
for f in tests/experiments/test_backend.py tests/algorithms/test_batched_lqr.py \
    tests/experiments/test_lane_sets.py; do
    timed "${TEST_S:-90}" "tests-$(basename "$f" .py)" "$py" -m pytest -q -p no:cacheprovider "$f"
done

step "4. loopid reproduce --quick, cold"
timed "${QUICK_S:-120}" quick "$py" -m loopid reproduce --quick --out "$work/quick" --quiet

step "done"
rm -rf "$work"
