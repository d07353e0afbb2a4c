"""What the backend implies for a run (loopid.experiments.backend): on an accelerator one worker
process per device (more are folded, with one line), chunks without the CPU's speed cap, a
memory budget from the device's memory, and each worker pinned to its own device. The
accelerator is simulated on a CPU; on an accelerator the CPU's test is skipped and one more
checks the real device."""

import os

import pytest

from loopid.experiments import backend, chunks
from loopid.experiments.execute import run_cells
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
    assert backend.fold_workers(4) == 4
    assert chunks.speed_seeds(40) == chunks.SPEED_SEEDS == 12 and chunks.speed_seeds(5) == 5
    assert chunks.budget(2.0, 2) == 10**9


@pytest.mark.skipif(not backend.accelerator(), reason="needs an accelerator (run on a GPU)")
def test_a_real_accelerator_is_described_folded_and_budgeted_by_its_own_memory():
    assert backend.describe().startswith(f"{backend.name()} ({backend.device_count()} x ")
    assert backend.fold_workers(backend.worker_devices() + 3) == backend.worker_devices()
    assert chunks.speed_seeds(1000) == 1000  # no speed cap on a device
    memory = backend.device_bytes()  # None where the device does not report its memory
    if memory is not None:
        assert memory > 10**9 and chunks.budget(None, 1) == int(backend.DEVICE_FRACTION * memory)


def test_an_accelerator_folds_workers_to_one_per_device_in_one_line(one_gpu):
    lines = []
    assert backend.fold_workers(4, lines.append) == 1
    assert len(lines) == 1 and lines[0].startswith("--workers 4: 1 gpu device;"), lines
    assert backend.fold_workers(1, lines.append) == 1 and len(lines) == 1  # nothing to fold


def test_an_accelerator_has_no_speed_cap_and_budgets_the_devices_memory(one_gpu):
    assert chunks.speed_seeds(1000) == 1000
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


def test_a_platform_that_cannot_pin_a_device_runs_one_worker(monkeypatch):
    """Four TPU chips: each worker process would open every chip, so one runs."""
    monkeypatch.setattr(backend, "accelerator", lambda: True)
    monkeypatch.setattr(backend, "name", lambda: "tpu")
    monkeypatch.setattr(backend, "device_count", lambda: 4)
    lines = []
    assert backend.worker_devices() == 1 and backend.fold_workers(4, lines.append) == 1
    assert lines == [
        "--workers 4: 4 tpu devices; running 1 worker process (processes sharing a device "
        "time-slice it)"
    ]


def test_a_run_on_an_accelerator_runs_one_process_per_device(one_gpu, tmp_path, monkeypatch):
    """--workers 2 on one GPU: one line, and the cells run in this process (no pool)."""
    from loopid.experiments import executors

    def no_pool(*args, **kwargs):
        raise AssertionError("a worker pool was started on one device")

    monkeypatch.setattr(executors, "_run_pool", no_pool)
    s = MDP_SCENARIOS["mdp-trap"].replace(seeds=3, iterations=3)
    lines = []
    table = run_cells(tmp_path / "run", [s], ["dagger"], workers=2, log=lines.append)
    assert table.num_rows == 3 * 3
    assert lines[0].startswith("--workers 2: 1 gpu device; running 1 worker process")
