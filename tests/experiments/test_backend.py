"""What the backend implies for a run (loopid.experiments.backend): on an accelerator one worker
process per device (more are folded, with one line), or threads of this process sharing the one
device it can use, chunks without the CPU's fixed lane width, a memory budget from the device's
memory (shared by the threads), and each worker pinned to its own device. The accelerator is
simulated on a CPU; on an accelerator the CPU's test is skipped and one more checks the real
device."""

import functools
import os

import pytest

from loopid.experiments import backend, chunks
from loopid.experiments.execute import run_cells
from loopid.experiments.families import family_of
from loopid.experiments.families.base import Family
from loopid.experiments.families.mdp import MDP_SCENARIOS


@pytest.fixture
def one_gpu(monkeypatch):
    """A simulated machine with one GPU of 80 GB."""
    monkeypatch.setattr(backend, "accelerator", lambda: True)
    monkeypatch.setattr(backend, "name", lambda: "gpu")
    monkeypatch.setattr(backend, "device_count", lambda: 1)
    monkeypatch.setattr(backend, "device_bytes", lambda: 80 * 10**9)


@pytest.mark.skipif(backend.accelerator(), reason="a CPU's facts; the next test checks a device")
def test_the_cpu_keeps_its_workers_cap_and_budget():
    assert backend.describe() == "cpu" and backend.device_bytes() is None
    assert not backend.shared_device()  # never threads on a CPU (pool's docstring)
    assert backend.fold_workers(4) == 4
    assert chunks.lane_width(40) == chunks.lane_width(2) == chunks.LANE_WIDTH == 10
    assert chunks.budget(2.0, 2) == 10**9


@pytest.mark.skipif(not backend.accelerator(), reason="needs an accelerator (run on a GPU)")
def test_a_real_accelerator_is_described_folded_and_budgeted_by_its_own_memory():
    assert backend.describe().startswith(f"{backend.name()} ({backend.device_count()} x ")
    devices = backend.worker_devices()
    assert backend.fold_workers(devices + 3) == (devices + 3 if devices == 1 else devices)
    assert chunks.lane_width(1000) == 1000  # no fixed width on a device
    memory = backend.device_bytes()  # None where the device does not report its memory
    if memory is not None:
        assert memory > 10**9 and chunks.budget(None, 1) == int(backend.DEVICE_FRACTION * memory)


def test_several_gpus_fold_workers_to_one_process_per_device_in_one_line(one_gpu, monkeypatch):
    from loopid.experiments import executors

    monkeypatch.setattr(backend, "device_count", lambda: 2)
    lines = []
    assert executors.default_workers() == 2
    assert not backend.shared_device() and backend.fold_workers(4, lines.append) == 2
    assert lines == [
        "--workers 4: 2 gpu devices; running 2 worker processes (processes sharing a device "
        "time-slice it)"
    ]
    assert backend.fold_workers(2, lines.append) == 2 and len(lines) == 1  # nothing to fold


def test_one_gpu_keeps_its_workers_as_threads_sharing_its_memory(one_gpu, monkeypatch):
    from loopid.experiments import executors

    lines = []
    assert backend.shared_device() and backend.fold_workers(4, lines.append) == 4 and not lines
    monkeypatch.setattr(executors.os, "cpu_count", lambda: 2)  # threads: not one per CPU
    assert executors.default_workers() == executors.MAX_DEFAULT_WORKERS
    assert chunks.budget(None, 4, threads=True) == int(backend.DEVICE_FRACTION * 80e9 / 4)
    # processes (Ray's tasks, several GPUs) each own a device: no sharing
    assert chunks.budget(None, 4) == int(backend.DEVICE_FRACTION * 80e9)


def test_an_accelerator_has_no_fixed_lane_width_and_budgets_the_devices_memory(one_gpu):
    assert chunks.lane_width(1000) == 1000 and chunks.lane_width(2) == chunks.MIN_CHUNK
    assert chunks.budget(None, 1) == int(backend.DEVICE_FRACTION * 80e9)
    assert chunks.budget(8.0, 1) == 8 * 10**9  # --memory still rules when given


def test_a_worker_is_pinned_to_its_own_device(monkeypatch):
    monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE", raising=False)
    monkeypatch.delenv("HIP_VISIBLE_DEVICES", raising=False)
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5,6")
    backend.pin_device("gpu", 1)
    assert os.environ["CUDA_VISIBLE_DEVICES"] == os.environ["HIP_VISIBLE_DEVICES"] == "5"
    assert os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES")
    backend.pin_device("gpu", 2)
    assert os.environ["CUDA_VISIBLE_DEVICES"] == "2"


def test_a_platform_that_cannot_pin_a_device_runs_threads_in_one_process(monkeypatch):
    """Four TPU chips: each worker process would open every chip, so the workers are threads
    of one process."""
    monkeypatch.setattr(backend, "accelerator", lambda: True)
    monkeypatch.setattr(backend, "name", lambda: "tpu")
    monkeypatch.setattr(backend, "device_count", lambda: 4)
    assert backend.worker_devices() == 1 and backend.shared_device()
    lines = []
    assert backend.fold_workers(4, lines.append) == 4
    assert lines == [
        "4 tpu devices, but a process cannot be given one of them here: running the cells on "
        "the first, 4 at a time"
    ]


def test_a_run_on_one_gpu_runs_its_workers_as_threads(one_gpu, tmp_path, monkeypatch):
    """--workers 2 on one GPU: no worker process; two threads of this process compute the
    cells, and the table equals one computed in order. The XLA work here runs on the CPU, whose
    client can deadlock under concurrent executions (pool's docstring), so the threads take
    turns through a lock: this test checks where cells run and what is saved, not concurrency
    (on a GPU, benchmarks/device.sh compares a run's table with --workers 1's)."""
    import concurrent.futures
    import threading

    import jax

    from loopid.experiments import execute

    def no_processes(*args, **kwargs):
        raise AssertionError("a worker process was started on one device")

    threads, one_at_a_time = set(), threading.Lock()

    def recorded(*args, run_chunk=execute.run_chunk, **kwargs):
        threads.add(threading.current_thread())
        with one_at_a_time:  # and nothing left in flight when the next takes its turn
            return jax.block_until_ready(run_chunk(*args, **kwargs))

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", no_processes)
    monkeypatch.setattr(execute, "run_chunk", recorded)
    s = MDP_SCENARIOS["mdp-trap"].replace(seeds=3, iterations=3)
    methods = ["dagger", "batch"]
    # each method its own program, so that both threads start at once (the family's methods
    # share one, whose second cell would wait for the first's second iteration)
    family = family_of(s)
    monkeypatch.setattr(family, "lane_sets", functools.partial(Family.lane_sets, family))
    lines = []
    table = run_cells(tmp_path / "run", [s], methods, workers=2, log=lines.append)
    assert threading.main_thread() not in threads and len(threads) == 2
    assert not any(line.startswith("--workers") for line in lines)  # nothing folded
    threads.clear()
    assert table.equals(run_cells(tmp_path / "one", [s], methods, workers=1))
    assert threads == {threading.main_thread()}


DETERMINISTIC = "--xla_gpu_deterministic_ops=true"
IN_PLACE = "--xla_cpu_copy_insertion_use_region_analysis=true"


@pytest.mark.parametrize(
    ("given", "expected"),
    [
        (None, f"{DETERMINISTIC} {IN_PLACE}"),
        (
            "--xla_force_host_platform_device_count=1",
            f"--xla_force_host_platform_device_count=1 {DETERMINISTIC} {IN_PLACE}",
        ),
        ("--xla_gpu_deterministic_ops=false", f"--xla_gpu_deterministic_ops=false {IN_PLACE}"),
        (
            "--xla_cpu_copy_insertion_use_region_analysis=false",
            f"--xla_cpu_copy_insertion_use_region_analysis=false {DETERMINISTIC}",
        ),
    ],
)
def test_import_sets_loopids_xla_flags_unless_the_user_chose(given, expected):
    """A GPU's table is the same from run to run and with any workers only with deterministic
    ops, and a CPU's loop updates its learner in place with region analysis (package
    docstring); importing loopid adds both flags before JAX starts a backend, keeps the user's
    other flags, and keeps a choice the user made."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if given is not None:
        env["XLA_FLAGS"] = given
    code = "import os, loopid, jax; jax.numpy.ones(1).block_until_ready()\n"
    code += "print(os.environ['XLA_FLAGS'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == expected


def test_the_compilation_cache_keeps_a_program_that_compiles_at_once(tmp_path):
    """``compile_cache`` stores every program, however quickly it compiles (a second
    ``reproduce --quick`` loads its hundreds of small programs too): the one-line programs that
    one process compiles are cache entries that a second process loads, compiling nothing."""
    import subprocess
    import sys

    code = (
        "import collections, sys, jax, jax.numpy as jnp\n"
        "from loopid.experiments.backend import compile_cache\n"
        "seen = collections.Counter()\n"
        "jax.monitoring.register_event_listener(lambda event, **_: seen.update([event]))\n"
        "compile_cache(sys.argv[1])\n"
        "jax.jit(lambda x: 2.0 * x + 1.0)(jnp.arange(3.0)).block_until_ready()\n"
        "print(seen['/jax/compilation_cache/cache_hits'],"
        " seen['/jax/compilation_cache/cache_misses'])\n"
    )

    def run() -> tuple[int, int]:
        out = subprocess.run(
            [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True
        )
        assert out.returncode == 0, out.stderr
        hits, misses = map(int, out.stdout.split())
        return hits, misses

    hits, compiled = run()
    assert hits == 0 and compiled >= 1 and len(list(tmp_path.iterdir())) >= compiled
    assert run() == (compiled, 0)  # every one of them loaded, none compiled
