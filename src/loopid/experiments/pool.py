"""The local executor's parallel workers (:func:`loopid.experiments.executors.run_local` with
``workers > 1``): :func:`run_pool` computes the jobs on that many worker processes (standard
library ``concurrent.futures``, spawned), or threads, each running one job at a time, and
yields the jobs as they finish.

- **Order and waiting.** A free worker takes the next job in :func:`spread`'s order whose
  compiled program is warm (:class:`_Warmup`): the jobs that share a program
  (:attr:`~loopid.experiments.executors.Job.program`) wait while the first of them compiles it,
  and a worker that meets a program another one compiled loads it from the shared persistent
  compilation cache.
- **A CPU.** Each worker process is pinned to its own share of the cores (:func:`core_shares`),
  so that the XLA threads of one do not take turns with another's (the funnel's policy gradient
  on 2 cores, two workers: 47 s pinned, 52 s not). Each process's BLAS runs on one thread
  (:mod:`loopid`): with a BLAS thread pool per process, whose threads spin while they wait, two
  workers on two cores slowed each other down 4-5x (the same cell: 150 s). A CPU keeps
  processes: concurrent executions on XLA's CPU client deadlock when its thread pool is as small
  as the machine's two cores (four threads on two cores hung with both pool threads inside
  jaxlib's batched LAPACK kernels, each waiting for work it had queued on the same, full pool).
- **An accelerator.** One worker process per device (:mod:`loopid.experiments.backend`); where
  this process holds the only device, the workers are threads of this process (``threads``,
  :mod:`loopid.experiments.threads`): they share its device, its compiled programs and its
  memory, and each compiles its cells' programs while the others compute (XLA compiles outside
  Python's lock), where worker processes would time-slice the device.

Progress (:func:`_pool_cell`) comes back from every worker as ``(index, n, row)`` messages,
whether or not it is shown: it says when a program has compiled. A worker process exits with
its parent, so that a killed run leaves no worker computing cells that nobody will save.
"""

import os
import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from loopid.experiments.backend import compile_cache
from loopid.experiments.threads import DaemonThreads, stoppable

#: A job (:class:`loopid.experiments.executors.Job`): a scenario, a method, its seeds, ``program``.
Job = Any


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

    compile_cache(cache_dir)  # the parent's folder
    _WORKER["messages"] = messages

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _pool_cell(
    cell: Callable[..., Any],
    index: int,
    s,
    method: str,
    seeds,
    rows: bool,
    messages=None,
    stop=None,
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


def _process_pool(workers: int, messages, cache_dir: str):
    """``workers`` spawned worker processes (:func:`_init_worker`), each on its own device on an
    accelerator, or on its own cores on a CPU (module docstring), sharing the
    compilation cache in ``cache_dir`` and sending progress to ``messages``."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from loopid.experiments import backend

    ctx = multiprocessing.get_context("spawn")  # never fork a process that runs XLA threads
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


def run_pool(
    jobs: Sequence[Job], cell, on_job, workers: int, threads: bool, cache_dir: str
) -> Iterator[tuple[Job, Any]]:
    """The jobs on ``workers`` worker processes (or threads), each started once a worker is free
    and its program is warm (:class:`_Warmup`), in the order of :func:`spread`; worker processes
    use the compilation cache in ``cache_dir`` (threads share this process's)."""
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

    pool = DaemonThreads(workers) if threads else _process_pool(workers, messages, cache_dir)
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
