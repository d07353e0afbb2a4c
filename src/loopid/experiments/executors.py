"""Executors: where the cells of a run are computed. The same seeds give the same table on any.

- ``local`` (default): in this process, one cell after another, JAX's persistent compilation
  cache on (:func:`compile_cache`). Cells that share a compiled program (DAgger, Batch and
  Abbeel with the same scenario and ν) reuse it. (Cells on several threads of one process were
  tried and dropped: concurrent executions on XLA's CPU client deadlock when its thread pool is
  as small as the machine's two cores; use ``ray`` for cells in parallel.)
- ``ray`` (extra ``[ray]``): each cell is one Ray task (``num_cpus=1``) calling the same cell
  function; ``address`` joins an existing cluster, otherwise a local Ray is started with the
  machine's CPUs and shut down afterwards. Workers use the same compilation cache folder.

An executor is a generator: ``executor(jobs, seeds, cell, on_cell=..., **options)`` yields
``(job, table)`` as cells finish (in any order); the caller saves each at once.
"""

import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import NamedTuple

import pyarrow as pa

from loopid.experiments.scenarios import Scenario

EXECUTORS = ("local", "ray")


class Job(NamedTuple):
    """One cell: a scenario and a method."""

    scenario: Scenario
    method: str


#: ``cell(scenario, method, seeds, progress=None) -> table`` (see :func:`execute.run_cell`).
CellFunction = Callable[..., pa.Table]


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


def run_local(
    jobs: Sequence[Job],
    seeds,
    cell: CellFunction,
    *,
    on_cell: Callable | None = None,
) -> Iterator[tuple[Job, pa.Table]]:
    """Compute the cells in this process, in order; ``on_cell(scenario, method, iterations)``
    returns a per-iteration progress callback (or None)."""
    for job in jobs:
        s = job.scenario
        progress = on_cell(s.name, job.method, s.iterations) if on_cell else None
        yield job, cell(s, job.method, seeds, progress=progress)


def _ray_cell(s: Scenario, method: str, seeds, cache_dir: str) -> pa.Table:
    """The body of one Ray task (runs in a worker process)."""
    import loopid  # noqa: F401  (float64 on)
    from loopid.experiments import execute

    compile_cache(cache_dir)
    return execute.run_cell(s, method, seeds)


def run_ray(
    jobs: Sequence[Job],
    seeds,
    cell: CellFunction | None = None,
    *,
    on_cell: Callable | None = None,
    address: str | None = None,
    num_cpus: int | None = None,
) -> Iterator[tuple[Job, pa.Table]]:
    """Compute each cell as a Ray task; yield them as they finish.

    ``address``: an existing cluster (``ray.init(address=...)``); otherwise a local Ray with
    ``num_cpus`` (default: the machine's CPUs), shut down when the generator ends. ``cell`` and
    ``on_cell`` are accepted for the common signature; workers run :func:`execute.run_cell`
    (the driver sees a cell when it is finished).
    """
    import ray

    with ray_session(address, num_cpus) if not ray.is_initialized() else nullcontext():
        import jax

        task = ray.remote(num_cpus=1, max_retries=0)(_ray_cell)
        cache_dir = jax.config.jax_compilation_cache_dir or compile_cache()
        pending = {task.remote(job.scenario, job.method, seeds, cache_dir): job for job in jobs}
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


def executor(name: str) -> Callable[..., Iterator[tuple[Job, pa.Table]]]:
    """The executor called ``name`` (:data:`EXECUTORS`)."""
    check_executor(name)
    return {"local": run_local, "ray": run_ray}[name]
