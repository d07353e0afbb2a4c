"""Executors: where the cells of a run are computed. The same seeds give the same table on any,
on one backend (:mod:`loopid.experiments.backend`: a GPU's table may differ from a CPU's in
rounding).

- ``local`` (default): on this machine, JAX's persistent compilation cache on
  (:func:`~loopid.experiments.backend.compile_cache`). ``workers = 1``: in this process, one
  cell after another; cells that share a compiled program (DAgger, Batch and Abbeel with the
  same scenario) reuse it. ``workers > 1``: that many worker processes, each running one
  cell at a time, pinned to its own cores on a CPU and to its own device on an accelerator, or,
  where this process holds the only device, threads sharing it; the cells that share a program
  wait while the first of them compiles it (:mod:`loopid.experiments.pool`).
- ``ray`` (extra ``[ray]``): each cell is one Ray task (``num_cpus=1``, and ``num_gpus=1`` on a
  cluster with GPUs) calling the same cell function; ``address`` joins an existing cluster,
  otherwise a local Ray is started with the machine's CPUs and shut down afterwards. Workers use
  the same compilation cache folder.

An executor is a generator: ``executor(jobs, fn, on_job=..., **options)`` yields ``(job,
result)`` as jobs finish (in any order), ``result`` being ``fn(scenario, method, seeds,
progress=...)`` of the job (a cell's chunk: :func:`loopid.experiments.cell.run_chunk`); the
caller saves each at once. A job is one task: a cell whose seeds fit one
chunk, or one chunk of a larger cell (:mod:`loopid.experiments.chunks`), so local workers and a
Ray cluster spread a large seed count as they spread cells.
"""

import os
from collections.abc import Callable, Hashable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from typing import Any, NamedTuple

from loopid.experiments.backend import compile_cache
from loopid.experiments.pool import run_pool

EXECUTORS = ("local", "ray")


class Job(NamedTuple):
    """One task: a scenario (any family's config), a method (or a lane set's tuple of methods,
    :mod:`loopid.experiments.jobs`), the seeds it runs (a whole cell's, or one chunk's),
    ``part``: the chunk's ``(start, stop)`` positions in the run's seed list (None for a whole
    cell), and ``program``: jobs with the same one run the same compiled programs (None: the
    scenario's and method's own; jobs with different ones may share some)."""

    scenario: Any
    method: str | tuple[str, ...]
    seeds: Any = None
    part: tuple[int, int] | None = None
    program: Hashable | None = None


#: ``fn(scenario, method, seeds, progress=None) -> result``
#: (:func:`loopid.experiments.cell.run_chunk`).
CellFunction = Callable[..., Any]


def jax_cache_dir() -> str:
    """The folder of this process's compilation cache, which the workers share: the one turned
    on, else the default one (:func:`~loopid.experiments.backend.compile_cache`), turned on
    now."""
    import jax

    return jax.config.jax_compilation_cache_dir or compile_cache()


def check_executor(name: str, address: str | None = None) -> None:
    """Raise ``ValueError`` (before anything is written) for an unknown executor, an address
    without Ray, or Ray missing."""
    if name not in EXECUTORS:
        raise ValueError(f"unknown executor {name!r}; choose from {', '.join(EXECUTORS)}")
    if address is not None and name != "ray":
        raise ValueError(f"--ray-address {address!r} needs --executor ray")
    if address is not None:
        _check_reachable(address)
    if name == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ValueError("--executor ray needs Ray: pip install 'loopid[ray]'") from None


def _check_reachable(address: str) -> None:
    """Fail fast (Ray itself retries for minutes) when nothing listens at ``host:port``."""
    import socket

    if address in ("auto", "local"):
        return
    hostport = address.removeprefix("ray://")
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(
            f"--ray-address must be HOST:PORT, ray://HOST:PORT or auto, got {address!r}"
        )
    try:
        socket.create_connection((host, int(port)), timeout=3).close()
    except OSError as e:
        raise ValueError(f"--ray-address {address!r}: cannot connect ({e})") from None


def check_workers(workers) -> int:
    """``workers`` as a positive int, or ``ValueError`` naming it."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"--workers must be a whole number >= 1, got {workers!r}")
    return workers


#: At most this many workers by default: each XLA CPU process runs threads of its own on every
#: core and holds 1.5-3 GB, so one per core would oversubscribe a large machine's cores and memory.
MAX_DEFAULT_WORKERS = 4


def default_workers() -> int:
    """The local executor's default worker count on the command line: one per CPU, at most
    :data:`MAX_DEFAULT_WORKERS`; on an accelerator one per device, or, where one device is all a
    process can use, :data:`MAX_DEFAULT_WORKERS` threads sharing it
    (:func:`loopid.experiments.backend.shared_device`)."""
    from loopid.experiments import backend

    if backend.shared_device():  # threads: each mostly waits for the device or the compiler
        return MAX_DEFAULT_WORKERS
    if backend.accelerator():
        return backend.worker_devices()
    return max(1, min(os.cpu_count() or 1, MAX_DEFAULT_WORKERS))


def run_local(
    jobs: Sequence[Job],
    cell: CellFunction,
    *,
    on_job: Callable | None = None,
    workers: int = 1,
    threads: bool = False,
) -> Iterator[tuple[Job, Any]]:
    """Compute the jobs on this machine; ``on_job(job)`` returns a per-iteration progress
    callback (or None), called when the job starts.

    ``workers = 1``: in this process, in order. ``workers > 1``: in that many spawned worker
    processes (at most one per job), yielding jobs as they finish; ``cell`` must then be a
    module-level function (it is pickled by name). ``threads``: the workers are threads of this
    process instead, for an accelerator this process holds alone; never on a CPU, whose XLA
    client can deadlock under concurrent executions (:mod:`loopid.experiments.pool`)."""
    workers = min(check_workers(workers), max(len(jobs), 1))
    if workers > 1:
        cache_dir = "" if threads else jax_cache_dir()
        yield from run_pool(jobs, cell, on_job, workers, threads, cache_dir)
        return
    for job in jobs:
        progress = on_job(job) if on_job else None
        yield job, cell(job.scenario, job.method, job.seeds, progress=progress)


def _ray_cell(cell: CellFunction, s, method: str, seeds, cache_dir: str):
    """The body of one Ray task (runs in a worker process): ``cell`` (a module-level function,
    pickled by name) on one scenario and method."""
    import loopid  # noqa: F401  (float64 on)

    compile_cache(cache_dir)
    return cell(s, method, seeds)


def run_ray(
    jobs: Sequence[Job],
    cell: CellFunction,
    *,
    on_job: Callable | None = None,
    address: str | None = None,
    num_cpus: int | None = None,
) -> Iterator[tuple[Job, Any]]:
    """Compute each job (a cell, or one chunk of one) as a Ray task; yield them as they finish.

    ``address``: an existing cluster (``ray.init(address=...)``); otherwise a local Ray with
    ``num_cpus`` (default: the machine's CPUs), shut down when the generator ends. Workers run
    ``cell`` (a module-level function); ``on_job`` is accepted for the common signature (the
    driver sees a job when it is finished).
    """
    import ray

    with ray_session(address, num_cpus) if not ray.is_initialized() else nullcontext():
        # on a cluster with GPUs a task (one chunk of a cell) takes one of them
        gpus = 1 if ray.cluster_resources().get("GPU", 0) >= 1 else 0
        task = ray.remote(num_cpus=1, num_gpus=gpus, max_retries=0)(_ray_cell)
        cache_dir = jax_cache_dir()
        pending = {
            task.remote(cell, job.scenario, job.method, job.seeds, cache_dir): job for job in jobs
        }
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            job = pending.pop(done[0])
            yield job, ray.get(done[0])


@contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None):
    """Connect to Ray for the ``with`` block: join the cluster at ``address``, or start a local
    one with ``num_cpus`` (default: the machine's CPUs); disconnect (and stop a local one)
    afterwards. A cluster that cannot be joined raises ``ValueError`` naming the address."""
    import logging

    import ray

    options = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
    ray_logger = logging.getLogger("ray")
    level = ray_logger.level
    ray_logger.setLevel(logging.ERROR)  # start-up notices would clutter --quiet and CI logs
    try:
        if address is not None:
            ray.init(address=address, **options)
        else:
            ray.init(num_cpus=num_cpus or os.cpu_count() or 1, **options)
    except (ConnectionError, RuntimeError, ValueError) as e:
        what = f"--ray-address {address!r}" if address else "a local Ray"
        raise ValueError(f"cannot start or join {what}: {' '.join(str(e).split())}") from None
    finally:
        ray_logger.setLevel(level)
    try:
        yield
    finally:
        ray.shutdown()


def executor(name: str) -> Callable[..., Iterator[tuple[Job, Any]]]:
    """The executor called ``name`` (:data:`EXECUTORS`)."""
    check_executor(name)
    return {"local": run_local, "ray": run_ray}[name]
