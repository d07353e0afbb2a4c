"""The compute backend a run uses, and what it implies for processes, chunks and memory.

JAX runs a cell's programs on its default backend: the CPU, or an accelerator (a GPU or TPU).
The two want different executors:

- **CPU.** Several worker processes (one per core, at most
  :data:`~loopid.experiments.executors.MAX_DEFAULT_WORKERS`) share the cores; a chunk holds
  exactly :data:`~loopid.experiments.chunks.LANE_WIDTH` lanes (its working set then stays in the
  core's cache); the memory budget is the host's.
- **Accelerator.** One process per device: processes sharing one device time-slice it (measured
  on one H200: a hover cell 37-66 s with four worker processes against 6.6 s alone), so more
  workers than devices are folded to one per device, with one line saying so. Where a process
  can use one device only (:func:`shared_device`: one GPU, or a platform whose processes
  cannot be pinned to a device), the workers are threads of this process instead, sharing the
  device: each compiles its cells' programs (most of a cold run on a GPU) while the others
  compute (:mod:`loopid.experiments.pool`). Width is nearly
  free on a device, so a chunk holds as many seeds as its memory allows (no fixed width), and the
  budget is the device's own memory (:func:`device_bytes`), not the host's. Each worker process
  sees only its own device, and no process preallocates most of a device's memory
  (``XLA_PYTHON_CLIENT_PREALLOCATE=false``, set by ``import loopid`` before JAX starts).

The same seeds give the same table on one backend whatever the executor, workers or chunks (on
a GPU because ``import loopid`` asks XLA for deterministic ops: with its default flags a GPU
program's rounding can change between compilations); a table computed on an accelerator may
differ from a CPU's in the last bits (another compiler and
other math libraries), and where a rounding difference is amplified (a cost near the cap, a
diverging trajectory) by more.
"""

import os
from pathlib import Path

import jax

#: The share of a device's memory a run's chunks may use (the rest: XLA's own workspace and the
#: compiled programs).
DEVICE_FRACTION = 0.8

#: The environment variables that restrict a process to some devices, per platform (JAX names
#: both NVIDIA's and AMD's GPUs ``gpu``; the first variable holds the parent's list). A platform
#: without one (a TPU) runs one worker process: each would open every chip.
VISIBLE_DEVICES = {"gpu": ("CUDA_VISIBLE_DEVICES", "HIP_VISIBLE_DEVICES")}


def name() -> str:
    """JAX's default backend: ``"cpu"``, ``"gpu"``, ``"tpu"``, ..."""
    return jax.default_backend()


def accelerator() -> bool:
    """Whether cells run on an accelerator (not the CPU)."""
    return name() != "cpu"


#: Iterations a helicopter lane set runs per call on an accelerator (one ``lax.scan``, its rows
#: fetched once per block: :func:`loopid.algorithms.loop.run_lanes`' ``block``).
ACCELERATOR_BLOCK = 10


def default_block() -> int:
    """Iterations per call the helicopter's lane sets ask for: :data:`ACCELERATOR_BLOCK` on an
    accelerator, where each call and each fetch of its rows waits on the host; 1 on the CPU,
    where a call costs little next to an iteration and blocks showed no consistent gain
    (``docs/benchmarks.md``, "iteration blocks")."""
    return ACCELERATOR_BLOCK if accelerator() else 1


def device_count() -> int:
    """This process's devices on the default backend."""
    return jax.local_device_count()


def describe() -> str:
    """The backend in words for reports: ``"cpu"``, or e.g. ``"gpu (1 x NVIDIA H200)"``."""
    if not accelerator():
        return "cpu"
    kinds = sorted({d.device_kind for d in jax.local_devices()})
    return f"{name()} ({device_count()} x {', '.join(kinds)})"


def device_bytes() -> int | None:
    """The memory of the smallest local device (``bytes_limit`` of its memory statistics), or
    None on the CPU or where the device does not report it."""
    if not accelerator():
        return None
    limits = []
    for d in jax.local_devices():
        stats = d.memory_stats() or {}
        if "bytes_limit" in stats:
            limits.append(int(stats["bytes_limit"]))
    return min(limits) if limits else None


def worker_devices() -> int:
    """How many worker processes an accelerator can take: one per device where a process can be
    pinned to one (:data:`VISIBLE_DEVICES`), else one."""
    return device_count() if name() in VISIBLE_DEVICES else 1


def shared_device() -> bool:
    """Whether a run's workers are threads of this process sharing its device: on an
    accelerator where one worker process is all it can take (:func:`worker_devices`)."""
    return accelerator() and worker_devices() == 1


def fold_workers(workers: int, log=None) -> int:
    """``workers`` on a CPU or a :func:`shared_device` (threads); on other accelerators at most
    one process per device (:func:`worker_devices`), saying so in one line through ``log`` when
    it folds; threads on the first of several devices (a platform whose processes cannot be
    pinned to one) say so in one line too."""
    if shared_device() and device_count() > 1 and log is not None:
        log(
            f"{device_count()} {name()} devices, but a process cannot be given one of them here: "
            f"running the cells on the first, {workers} at a time"
        )
    if not accelerator() or shared_device() or workers <= worker_devices():
        return workers
    devices, count = worker_devices(), device_count()
    if log is not None:
        log(
            f"--workers {workers}: {count} {name()} device{'s' if count > 1 else ''}; running "
            f"{devices} worker process{'es' if devices > 1 else ''} (processes sharing a device "
            "time-slice it)"
        )
    return devices


def pin_device(platform: str, index: int) -> None:
    """Restrict this (worker) process to device ``index`` of its parent's ``platform`` devices,
    before JAX starts its backend here, and keep it from preallocating most of the device."""
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    variables = VISIBLE_DEVICES.get(platform)
    if variables is not None:
        visible = os.environ.get(variables[0])
        ids = visible.split(",") if visible else [str(i) for i in range(index + 1)]
        for variable in variables:
            os.environ[variable] = ids[index]


def compile_cache(path: str | os.PathLike | None = None) -> str:
    """Turn on JAX's persistent compilation cache in this process; return its folder.

    ``path`` defaults to ``$LOOPID_JAX_CACHE``, else ``~/.cache/loopid/jax``. Every compiled
    program is stored, however quickly it compiled, so a second run of the same cells, in any
    process, compiles nothing: the cells' own programs take 5-60 s to compile, and the hundreds
    of small ones around them (noise, setup, eager operations) took about a quarter of a second
    run of ``reproduce --quick`` when they were compiled again (they take about 1 MB on disk).
    """
    if path is None:
        path = os.environ.get("LOOPID_JAX_CACHE", str(Path.home() / ".cache" / "loopid" / "jax"))
    path = str(path)
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return path
