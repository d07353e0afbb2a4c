"""The local executor's worker processes and threads: order, progress, results, failures (no JAX
work).

The cell function here stands in for :func:`loopid.experiments.cell.run_cell`: it reports
every iteration and returns a small table, so the pool's mechanics are tested in seconds; the
CLI test ``test_worker_processes_give_the_in_process_table`` checks real cells.
"""

import os
import time

import numpy as np
import pyarrow as pa
import pytest

from loopid.experiments.executors import Job, check_workers, run_local
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.experiments.pool import core_shares, spread


def fake_cell(s, method, seeds, progress=None):
    """Iterations 1..N reported, then a table naming the cell and the process that ran it."""
    if method == "boom":
        raise RuntimeError(f"cell {s.name}/{method} failed")
    for n in range(1, s.iterations + 1):
        if progress is not None:
            progress(n, {"n": np.asarray(n)})
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    return pa.table(
        {"cell": [f"{s.name}/{method}"], "pid": [os.getpid()], "seeds": [len(seeds)],
         "cores": [cores]}
    )  # fmt: skip


def timed_cell(s, method, seeds, progress=None):
    """A cell whose method ``a`` takes 2 s an iteration (it "compiles"), any other 10 ms; a
    table of when it started, reported iteration 2 (or ended, with one) and ended."""
    started = time.time()
    for n in range(1, s.iterations + 1):
        time.sleep(2.0 if method == "a" else 0.01)
        progress(n, {"n": np.asarray(n)})
        if n == min(2, s.iterations):
            second = time.time()
    return pa.table({"started": [started], "second": [second], "ended": [time.time()]})


def jobs(methods=("a", "b", "c"), iterations=3, seeds=(0, 1)):
    return [
        Job(scenario(name, iterations=iterations), m, np.asarray(seeds))
        for name in ("hover", "hover-delay", "funnel")
        for m in methods
    ]


def test_spread_puts_each_scenarios_first_cell_first():
    js = jobs()
    order = spread(js)
    assert sorted(order) == list(range(len(js)))
    assert [js[i].scenario.name for i in order[:3]] == ["hover", "hover-delay", "funnel"]
    assert [js[i].method for i in order[:3]] == ["a", "a", "a"]
    assert order[3:] == [1, 2, 4, 5, 7, 8]  # then the rest in the given order


def test_spread_takes_the_families_one_after_another():
    from loopid.experiments.families.mdp import MDP_SCENARIOS

    mdp = [Job(MDP_SCENARIOS[n], m, np.arange(2)) for n in ("mdp-random", "mdp-trap") for m in "ab"]
    js = jobs()
    mixed = [mdp[0], *js[:4], mdp[1], mdp[2], *js[4:], mdp[3]]  # the MDP's first in front
    order = [mixed[i] for i in spread(mixed)]
    assert order == [mdp[0], mdp[2], mdp[1], mdp[3], *(js[i] for i in spread(js))]


@pytest.mark.parametrize("threads", [False, True])
def test_cells_of_one_program_wait_while_the_first_compiles(threads):
    """Two workers; the hover's cells a, b and c share one program, whose first cell is slow to
    its second iteration (it compiles); e is a hover cell with a program of its own and f the
    funnel's one cell, both quick. The free worker takes f and then e, and waits instead of
    starting b or c (which would compile the same program again); they start once a has
    reported its second iteration, before a ends. Without progress shown as well."""
    hover = scenario("hover", iterations=3)
    js = [Job(hover, m, np.arange(2), program="hover") for m in ("a", "b", "c")]
    js += [Job(hover, "e", np.arange(2)), Job(scenario("funnel", iterations=1), "f", np.arange(2))]
    done = {
        (j.scenario.name, j.method): t.to_pydict()
        for j, t in run_local(js, timed_cell, workers=2, threads=threads)
    }
    assert len(done) == 5
    compiled = done[("hover", "a")]["second"][0]
    for other in [("funnel", "f"), ("hover", "e")]:  # the other worker kept busy meanwhile
        assert done[other]["started"][0] < compiled, other
    for m in ("b", "c"):
        assert done[("hover", m)]["started"][0] >= compiled, m
    assert done[("hover", "b")]["started"][0] < done[("hover", "a")]["ended"][0]


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2", True])
def test_check_workers_names_the_bad_value(bad):
    with pytest.raises(ValueError, match="--workers"):
        check_workers(bad)


@pytest.mark.parametrize("threads", [False, True])
def test_workers_compute_every_cell_once_with_its_progress(threads):
    js = jobs()
    seen: dict = {}

    def on_job(job):
        name, method = job.scenario.name, job.method
        assert (name, method) not in seen  # called once per job, when it starts
        seen[(name, method)] = []
        return lambda n, row: seen[(name, method)].append((n, int(row["n"])))

    done = list(run_local(js, fake_cell, on_job=on_job, workers=2, threads=threads))

    def key(j):
        return (j.scenario.name, j.method)

    assert sorted(key(j) for j, _ in done) == sorted(map(key, js))
    for job, table in done:
        assert table.column("cell").to_pylist() == [f"{job.scenario.name}/{job.method}"]
        assert table.column("seeds").to_pylist() == [2]
        # every iteration's progress arrived before the cell was handed over, in order
        assert seen[(job.scenario.name, job.method)] == [(n, n) for n in (1, 2, 3)]
    pids = {table.column("pid")[0].as_py() for _, table in done}
    if threads:
        assert pids == {os.getpid()}
        return
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    if hasattr(os, "sched_getaffinity") and len(os.sched_getaffinity(0)) >= 2:
        # each worker ran on its own cores: the processes' core sets are disjoint
        cores = {t.column("pid")[0].as_py(): set(t.column("cores")[0].as_py()) for _, t in done}
        sets = list(cores.values())
        assert all(a.isdisjoint(b) for i, a in enumerate(sets) for b in sets[i + 1 :])
        assert set().union(*sets) <= os.sched_getaffinity(0)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
@pytest.mark.parametrize("workers", [1, 2, 3, 4, 6, 7, 9])
def test_core_shares_deal_the_cores_out_evenly(workers):
    cores = {0, 2, 3, 5, 8, 9}
    shares = core_shares(workers, cores)
    assert len(shares) == workers
    if workers <= len(cores):  # disjoint, every core used, sizes within one
        flat = [c for share in shares for c in share]
        assert sorted(flat) == sorted(cores)
        assert max(map(len, shares)) - min(map(len, shares)) <= 1
    else:  # one core each, every core used as evenly as it can be
        assert all(len(share) == 1 for share in shares)
        counts = [sum(share == (c,) for share in shares) for c in cores]
        assert max(counts) - min(counts) <= 1


def test_one_worker_runs_in_this_process():
    done = list(run_local(jobs(methods=("a",), seeds=(0,)), fake_cell, workers=1))
    assert [t.column("pid")[0].as_py() for _, t in done] == [os.getpid()] * 3


@pytest.mark.parametrize("threads", [False, True])
def test_a_failing_cell_raises_in_the_caller(threads):
    js = jobs(methods=("a", "boom"), iterations=1)
    with pytest.raises(RuntimeError, match="boom"):
        list(run_local(js, fake_cell, workers=2, threads=threads))


def test_threads_stop_their_cells_when_the_run_stops():
    """A run stopped after its first cells (an interrupt, a failure, a closed generator): the
    cells not started never start, and the running ones stop at their next iteration, before
    ``close`` returns, so nothing goes on computing (on the device) after the run."""
    import threading

    from loopid.experiments.threads import Stopped

    running, stopped, started = threading.Event(), [], []

    def cell(s, method, seeds, progress=None):
        started.append(method)
        if method == "a":  # the first cells: return at once
            return method
        n = 0
        try:
            while True:  # a long cell: ends only when told to, at an iteration
                n += 1
                progress(n, {"n": n})
                running.set()
        except Stopped:
            stopped.append(method)
            raise

    run = run_local(jobs(methods=("a", "b")), cell, workers=2, threads=True)
    for _ in range(3):  # the three scenarios' first cells; the "b" cells start before the last
        job, result = next(run)
        assert job.method == result == "a"
    assert running.wait(10)  # a "b" cell is in its loop
    run.close()
    assert started.count("b") == len(stopped) >= 1, (started, stopped)  # every one stopped
    assert not any(t.name.startswith("loopid-cell") for t in threading.enumerate())
    assert len(started) < len(jobs(methods=("a", "b")))  # the last "b" never started


def test_a_cell_on_a_thread_stays_at_most_two_iterations_ahead_of_the_device(monkeypatch):
    """``stoppable`` waits for the row of iteration n - AHEAD before returning from n, so a
    stop is not kept waiting behind iterations already dispatched."""
    import threading

    import jax

    from loopid.experiments.threads import AHEAD, stoppable

    waited = []
    monkeypatch.setattr(jax, "block_until_ready", lambda row: waited.append(row["n"]))
    progress = stoppable(None, threading.Event())
    for n in range(1, 6):
        progress(n, {"n": n})
        assert waited == list(range(1, n - AHEAD + 1)), (n, waited)


def test_default_workers_is_one_per_cpu_up_to_the_cap(monkeypatch):
    import loopid.experiments.executors as ex

    for cpus, expected in [(None, 1), (1, 1), (2, 2), (64, ex.MAX_DEFAULT_WORKERS)]:
        monkeypatch.setattr(ex.os, "cpu_count", lambda c=cpus: c)
        assert ex.default_workers() == expected
