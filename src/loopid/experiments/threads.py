"""Worker threads for cells that share one accelerator (:mod:`loopid.experiments.pool`).

On one GPU the local executor's workers are threads of one process: they share the device, its
compiled programs and its memory, and each compiles its cells' programs while the others
compute (XLA compiles outside Python's lock). Only on an accelerator: concurrent executions on
XLA's CPU client can deadlock (:mod:`loopid.experiments.pool`).

:class:`DaemonThreads` is the part of ``concurrent.futures.ThreadPoolExecutor`` the executor
uses, written here for two reasons:

- a run that stops (an interrupt, a failed cell, a caller that closes the generator) stops its
  running cells too: each checks its pool's ``stop`` event in its per-iteration progress
  callback (:func:`stoppable`) and ends with :class:`Stopped` at its next iteration, and
  :meth:`DaemonThreads.shutdown` waits for that (at most ``timeout`` seconds: a program being
  compiled cannot be stopped), so no cell goes on computing, on the device, after the run
  returned or the interpreter began to exit. A cell's loop dispatches its iterations without
  waiting for their results; the callback lets it run at most :data:`AHEAD` iterations ahead of
  the device, so that a stop is not kept waiting behind a queue of iterations already sent;
- its threads are daemons, so a thread still compiling when that wait ends does not hold up
  the process's exit (``ThreadPoolExecutor`` joins its threads at exit).
"""

import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future

#: How many iterations a cell on a thread may dispatch beyond the last one the device finished
#: (:func:`stoppable`): enough to keep the device busy while the host dispatches the next.
AHEAD = 2


class Stopped(Exception):
    """A cell's thread was told to stop (its run stopped); its result is not wanted."""


class DaemonThreads:
    """``workers`` daemon threads running the submitted calls in order of submission."""

    def __init__(self, workers: int):
        self.stop = threading.Event()
        self.tasks: queue.SimpleQueue = queue.SimpleQueue()
        self.threads = [
            threading.Thread(target=self._work, name=f"loopid-cell-{i}", daemon=True)
            for i in range(workers)
        ]
        for thread in self.threads:
            thread.start()

    def submit(self, fn: Callable, *args) -> Future:
        """Run ``fn(*args)`` on the next free thread; its future holds the result."""
        if self.stop.is_set():
            raise RuntimeError("submit after shutdown")
        future: Future = Future()
        self.tasks.put((future, fn, args))
        return future

    def _work(self) -> None:
        while (task := self.tasks.get()) is not None:
            future, fn, args = task
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(*args))
                except BaseException as e:
                    future.set_exception(e)

    def shutdown(self, timeout: float = 60.0, **_) -> None:
        """Cancel the calls not started, tell the running ones to stop (:func:`stoppable`) and
        wait up to ``timeout`` seconds for the threads to end. (``ThreadPoolExecutor``'s
        keyword arguments are accepted and ignored: queued calls are always cancelled.)"""
        while True:  # first, so that no thread starts a call after a stopped one
            try:
                task = self.tasks.get_nowait()
            except queue.Empty:
                break
            if task is not None:
                task[0].cancel()
        self.stop.set()
        for _ in self.threads:
            self.tasks.put(None)
        deadline = time.monotonic() + timeout
        for thread in self.threads:
            if thread is not threading.current_thread():
                thread.join(max(deadline - time.monotonic(), 0.0))


def stoppable(progress: Callable | None, stop: threading.Event) -> Callable:
    """A per-iteration progress callback that raises :class:`Stopped` once ``stop`` is set, and
    otherwise passes ``(n, row)`` on to ``progress`` (if any); before it returns, the row of
    iteration ``n - AHEAD`` is computed (``jax.block_until_ready``), so the cell's loop is never
    more than :data:`AHEAD` iterations ahead of the device. Numbers are unchanged: only when
    the host waits."""
    import jax

    sent: deque = deque()

    def check(n: int, row) -> None:
        if stop.is_set():
            raise Stopped(f"stopped at iteration {n}")
        if progress is not None:
            progress(n, row)
        sent.append(row)
        if len(sent) > AHEAD:
            jax.block_until_ready(sent.popleft())

    return check
