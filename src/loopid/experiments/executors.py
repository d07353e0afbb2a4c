"""Executors: where the cells of a run are computed. The same seeds give the same table on any,
on one backend (:mod:`loopid.experiments.backend`: a GPU's table may differ from a CPU's in
rounding).

- ``local`` (default): on this machine, JAX's persistent compilation cache on
  (:func:`compile_cache`). ``workers = 1``: in this process, one cell after another; cells that
  share a compiled program (DAgger, Batch and Abbeel with the same scenario and ν) reuse it.
  ``workers > 1``: that many worker processes (standard library ``concurrent.futures``, spawned),
  each running one cell at a time, in the order of :func:`spread`; a worker that meets a program
  another one already compiled loads it from the shared persistent cache, and the cells that
  share a program wait while the first of them compiles it (:class:`_Warmup`). On a CPU each worker
  is pinned to its own share of the cores (:func:`core_shares`), so that the XLA threads of one
  do not take turns with another's (the funnel's policy gradient on 2 cores, two workers: 47 s
  pinned, 52 s not). Each process's BLAS runs on one thread (:mod:`loopid`): with a BLAS thread
  pool per process, whose threads spin while they wait, two workers on two cores slowed each
  other down 4-5x (the same cell: 150 s). On an accelerator, one worker process per device
  (:mod:`loopid.experiments.backend`); where this process holds the only device, the workers
  are threads of this process (``threads=True``, :mod:`loopid.experiments.threads`): they
  share its device, its compiled programs and its memory, and each compiles its cells'
  programs while the others compute (XLA compiles outside Python's lock), where worker
  processes would time-slice the device.
  (A CPU keeps processes: concurrent executions on XLA's CPU client deadlock when its thread
  pool is as small as the machine's two cores. Four threads on two cores hung with both pool
  threads inside jaxlib's batched LAPACK kernels (Cholesky, triangular solve), each waiting
  for work it had queued on the same, full pool.)
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
import queue
import threading
import time
from collections.abc import Callable, Hashable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Any, NamedTuple

from loopid.experiments.threads import DaemonThreads, stoppable

EXECUTORS = ("local", "ray")


class Job(NamedTuple):
    """One task: a scenario (any family's config), a method (or a lane set's tuple of methods,
    :mod:`loopid.experiments.tasks`), the seeds it runs (a whole cell's, or one chunk's),
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


def compile_cache(path: str | os.PathLike | None = None) -> str:
    """Turn on JAX's persistent compilation cache in this process; return its folder.

    ``path`` defaults to ``$LOOPID_JAX_CACHE``, else ``~/.cache/loopid/jax``. Every program that
    takes at least 0.5 s to compile is stored (the cells' programs take 5-60 s; the many tiny
    eager operations are not worth a disk entry), so a second run of the same cells, in any
    process, skips most compilation.
    """
    import jax

    if path is None:
        path = os.environ.get("LOOPID_JAX_CACHE", str(Path.home() / ".cache" / "loopid" / "jax"))
    path = str(path)
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return path


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
    client can deadlock under concurrent executions (module docstring)."""
    workers = min(check_workers(workers), max(len(jobs), 1))
    if workers > 1:
        yield from _run_pool(jobs, cell, on_job, workers, threads)
        return
    for job in jobs:
        progress = on_job(job) if on_job else None
        yield job, cell(job.scenario, job.method, job.seeds, progress=progress)


def spread(jobs: Sequence[Job]) -> list[int]:
    """The order in which parallel workers take the jobs: family by family (the type of their
    scenarios, in the order they first appear), the first job of each scenario, then the
    others in their order. Workers starting together then compile different programs, and the
    cells that share a program start once the first has compiled it into the shared cache
    (:class:`_Warmup`; round-robin would have two workers compile the same program at once); a
    second family's cells (``run_all``) fill the workers the first leaves idle."""
    families: dict[type, list[int]] = {}
    for i, job in enumerate(jobs):
        families.setdefault(type(job.scenario), []).append(i)
    order = []
    for indices in families.values():
        first: dict[str, int] = {}
        for i in indices:
            first.setdefault(jobs[i].scenario.name, i)
        firsts = set(first.values())
        order += list(first.values()) + [i for i in indices if i not in firsts]
    return order


_WORKER: dict = {}


def core_shares(workers: int, cores=None) -> list[tuple[int, ...]]:
    """The CPU cores each of ``workers`` processes may run on: ``cores`` (default: those this
    process may use) dealt out in turn, so that the shares are disjoint and differ in size by at
    most one; with more workers than cores, one core each, in turn. ``[]`` where the system
    cannot pin a process (no ``os.sched_setaffinity``)."""
    if not hasattr(os, "sched_setaffinity"):
        return []
    cores = sorted(os.sched_getaffinity(0) if cores is None else cores)
    if workers >= len(cores):
        return [(cores[i % len(cores)],) for i in range(workers)]
    return [tuple(cores[i::workers]) for i in range(workers)]


def _init_worker(
    cache_dir: str, messages, parent: int, devices=None, platform="cpu", cores=None
) -> None:
    """Worker process start: on an accelerator its own device (taken from the ``devices``
    queue), on a CPU its own cores (from the ``cores`` queue, before XLA starts its threads);
    float64 and the shared compile cache on; exit with the parent (a killed run must not leave
    workers computing cells nobody will save)."""
    if devices is not None:
        from loopid.experiments.backend import pin_device

        pin_device(platform, devices.get())
    if cores is not None:
        os.sched_setaffinity(0, cores.get())
    import loopid  # noqa: F401  (float64 on)

    compile_cache(cache_dir)
    _WORKER["messages"] = messages

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _pool_cell(
    cell: CellFunction, index: int, s, method: str, seeds, rows: bool, messages=None, stop=None
):
    """One cell in a worker: a process, or a thread given its ``messages`` queue and its pool's
    ``stop`` event (the cell then ends at its next iteration once the event is set:
    :mod:`loopid.experiments.threads`). Progress goes back to the parent as ``(index, n, row)``
    (``row`` None unless ``rows``), with ``n = 0`` (no row) when the cell starts and ``n = -1``
    (no row) when it has returned, so the parent waits for nothing more of it (a task may
    return before its last iteration: a memory check that sends it back,
    :class:`loopid.experiments.cell.Oversized`).

    The rows are copied to NumPy and sent by a thread of the worker, in order, so the cell's
    loop dispatches its next iteration without waiting for the last one's numbers (on an
    accelerator, a copy to the host waits for the device)."""
    messages = messages if messages is not None else _WORKER["messages"]
    sender = _RowSender(messages, index, copy=rows)
    messages.put((index, 0, None))  # started: the parent shows its bar from now on
    try:
        progress = sender.put if stop is None else stoppable(sender.put, stop)
        result = cell(s, method, seeds, progress=progress)
    finally:
        sender.close(drop=stop is not None and stop.is_set())  # every row sent, unless stopped
    messages.put((index, -1, None))  # returned: after every progress message of this cell
    return result


class _RowSender:
    """A thread that sends ``(index, n, row)`` to ``messages`` in the order ``put`` was called,
    each row's leaves copied to NumPy (:func:`_pool_cell`); without ``copy``, ``row`` is None."""

    def __init__(self, messages, index: int, copy: bool = True):
        self.messages, self.index, self.copy = messages, index, copy
        self.pending: queue.Queue = queue.Queue()
        self.thread = threading.Thread(target=self._send, daemon=True)
        self.thread.start()

    def put(self, n: int, row) -> None:
        self.pending.put((n, row))

    def close(self, drop: bool = False) -> None:
        """Send every row put so far (with ``drop``: none not yet being sent, whose copies would
        wait for the device to compute them) and end the thread."""
        while drop:
            try:
                self.pending.get_nowait()
            except queue.Empty:
                break
        self.pending.put(None)
        self.thread.join()

    def _send(self) -> None:
        import jax
        import numpy as np

        while (item := self.pending.get()) is not None:
            n, row = item
            row = jax.tree_util.tree_map(np.asarray, row) if self.copy else None
            self.messages.put((self.index, n, row))


def _process_pool(workers: int, messages):
    """``workers`` spawned worker processes (:func:`_init_worker`), each on its own device on an
    accelerator, or on its own cores on a CPU (module docstring), sharing this process's
    compilation cache and sending progress to ``messages``."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import jax

    from loopid.experiments import backend

    ctx = multiprocessing.get_context("spawn")  # never fork a process that runs XLA threads
    cache_dir = jax.config.jax_compilation_cache_dir or compile_cache()
    devices = cores = None
    if backend.accelerator():  # one device each
        devices = ctx.Queue()
        for index in range(workers):
            devices.put(index)
    elif shares := core_shares(workers):  # cores of its own each (module docstring)
        cores = ctx.Queue()
        for share in shares:
            cores.put(share)
    return ProcessPoolExecutor(
        workers, mp_context=ctx, initializer=_init_worker,
        initargs=(cache_dir, messages, os.getpid(), devices, backend.name(), cores),
    )  # fmt: skip


def _run_pool(jobs, cell, on_job, workers, threads=False) -> Iterator[tuple[Job, Any]]:
    """The jobs on ``workers`` worker processes (or threads), each started once a worker is free
    and its program is warm (:class:`_Warmup`), in the order of :func:`spread`."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, wait

    # progress comes back whether or not it is shown: it says when a program has compiled
    messages = queue.Queue() if threads else multiprocessing.get_context("spawn").Queue()
    callbacks: dict[int, Callable | None] = {}
    seen: dict[int, int] = {}  # the last iteration reported per job
    warmup = _Warmup(jobs)

    def deliver(message) -> None:
        index, n, row = message
        if index not in callbacks:
            callbacks[index] = on_job(jobs[index]) if on_job is not None else None
        seen[index] = jobs[index].scenario.iterations if n < 0 else n
        if n >= 2 or n < 0:
            warmup.warm(index)
        if n > 0 and callbacks[index] is not None:
            callbacks[index](n, row)

    def drain(until: int | None = None) -> None:
        """Deliver the progress messages that arrived; with ``until``, first wait (up to 5 s)
        for that job's last iteration, which may still be in flight when its result is in."""
        while True:
            try:
                waiting = until is not None and seen.get(until, 0) < jobs[until].scenario.iterations
                deliver(messages.get(timeout=5.0) if waiting else messages.get_nowait())
            except queue.Empty:
                return

    pool = DaemonThreads(workers) if threads else _process_pool(workers, messages)
    extra = (messages, pool.stop) if threads else ()  # a process has its own (_init_worker)
    futures: dict = {}

    def start_free_workers() -> None:
        while len(futures) < workers and (i := warmup.next()) is not None:
            job = jobs[i]
            args = (cell, i, job.scenario, job.method, job.seeds, on_job is not None, *extra)
            futures[pool.submit(_pool_cell, *args)] = i

    try:
        start_free_workers()
        while futures:
            done, _ = wait(set(futures), timeout=0.1, return_when=FIRST_COMPLETED)
            drain()
            finished, error = [], None
            for future in sorted(done, key=futures.get):
                index = futures.pop(future)
                try:
                    result = future.result()
                except BaseException as e:  # the cells finished beside it are still handed over
                    error = e
                    break
                drain(until=index)
                warmup.warm(index)
                finished.append((jobs[index], result))
            if error is None:
                start_free_workers()  # before the caller saves what finished
            yield from finished
            if error is not None:
                raise error
    finally:
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in processes:  # an interrupted run stops its workers now, not after their cells
            if p.is_alive():
                p.terminate()


class _Warmup:
    """Which job a free worker starts next: the first in :func:`spread`'s order whose program
    (:attr:`Job.program`) is warm, or has no job running yet.

    A program's first job compiles it (and writes it to the shared compilation cache); the
    program is warm once that job has reported its second iteration (or returned). Until then
    its other jobs wait and the free worker takes another program's, or waits too: two workers
    compiling the same program at once would each pay for it, each slowed by the other. Jobs
    start only while the caller takes results (the generator runs), so a worker that finishes
    while the caller saves a cell waits for that save."""

    def __init__(self, jobs: Sequence[Job]):
        self.keys = [
            job.program if job.program is not None else (job.scenario.name, job.method)
            for job in jobs
        ]
        self.order = spread(jobs)
        self.ready: set = set()  # warm programs
        self.warming: set = set()  # programs whose first job runs

    def next(self) -> int | None:
        for i in self.order:
            key = self.keys[i]
            if key in self.ready or key not in self.warming:
                self.order.remove(i)
                if key not in self.ready:
                    self.warming.add(key)
                return i
        return None

    def warm(self, index: int) -> None:
        self.warming.discard(self.keys[index])
        self.ready.add(self.keys[index])


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
        import jax

        # on a cluster with GPUs a task (one chunk of a cell) takes one of them
        gpus = 1 if ray.cluster_resources().get("GPU", 0) >= 1 else 0
        task = ray.remote(num_cpus=1, num_gpus=gpus, max_retries=0)(_ray_cell)
        cache_dir = jax.config.jax_compilation_cache_dir or compile_cache()
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
