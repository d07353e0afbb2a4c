"""The ``loopid`` command line's executors, as a user runs them: a killed run resumes to the same
table, and worker processes and Ray give the in-process table (hover and a finite MDP).

Its own file so that a parallel ``make test`` (pytest-xdist, one file per worker) runs these
beside ``tests/test_cli.py``'s reproduce and study runs instead of after them. The tests share
one JAX compilation cache (``cache``), so only the first run of a program compiles.
"""

import signal
import subprocess
import time

import pyarrow.parquet as pq
import pytest

from conftest import cell_mtimes, cli


@pytest.mark.slow
def test_killed_run_resumes_to_the_same_table(tmp_path, cache):
    args = ["run", "hover", "--methods", "expert,batch-t,dagger-t", "--seeds", "2",
            "--iterations", "4", "--test-trajectories", "10", "--quiet"]  # fmt: skip
    whole = tmp_path / "whole"
    r = cli(*args, "--out", whole, cache=cache)
    assert r.returncode == 0, r.stderr
    expected = pq.read_table(whole / "results.parquet")

    killed = tmp_path / "killed"
    p = cli(*args, "--out", killed, cache=cache, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not cell_mtimes(killed) and p.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    p.send_signal(signal.SIGKILL)
    p.wait()
    first = cell_mtimes(killed)
    assert len(first) == 1  # killed after its first finished cell
    assert not list(killed.glob("*.png"))

    r = cli(*args, "--out", killed, cache=cache)
    assert r.returncode == 0, r.stderr
    assert "already finished, skipped" not in r.stderr  # --quiet
    again = pq.read_table(killed / "results.parquet")
    assert again.equals(expected)  # same rows, same order, no duplicates
    name = next(iter(first))
    assert cell_mtimes(killed)[name] == first[name]  # the finished cell was not recomputed

    # a different configuration in the same directory is refused, and changes nothing
    r = cli(*args[:-1], "--samples", "50", "--out", killed, cache=cache)
    assert r.returncode == 2 and "different configuration" in r.stderr
    assert pq.read_table(killed / "results.parquet").equals(expected)


@pytest.mark.slow
def test_worker_processes_give_the_in_process_table(tmp_path, cache):
    args = ["run", "hover", "--methods", "expert,batch-t", "--seeds", "2", "--iterations", "2",
            "--test-trajectories", "10", "--quiet"]  # fmt: skip
    r = cli(*args, "--workers", "1", "--out", tmp_path / "one", cache=cache)
    assert r.returncode == 0, r.stderr
    r = cli(*args, "--workers", "2", "--out", tmp_path / "two", cache=cache)
    assert r.returncode == 0, r.stderr
    one = pq.read_table(tmp_path / "one" / "results.parquet")
    assert pq.read_table(tmp_path / "two" / "results.parquet").equals(one)


@pytest.mark.slow
def test_ray_executor_gives_the_local_table(tmp_path, cache):
    pytest.importorskip("ray")
    args = ["run", "hover", "--methods", "expert,batch-t", "--seeds", "2", "--iterations", "2",
            "--test-trajectories", "10", "--quiet"]  # fmt: skip
    r = cli(*args, "--out", tmp_path / "local", cache=cache)
    assert r.returncode == 0, r.stderr
    r = cli(*args, "--executor", "ray", "--out", tmp_path / "ray", cache=cache)
    assert r.returncode == 0, r.stderr
    local = pq.read_table(tmp_path / "local" / "results.parquet")
    assert pq.read_table(tmp_path / "ray" / "results.parquet").equals(local)
    assert (tmp_path / "ray" / "report.md").exists()


@pytest.mark.slow
def test_ray_executor_gives_the_local_table_for_an_mdp(tmp_path, cache):
    pytest.importorskip("ray")
    args = ["run", "mdp-trap", "--seeds", "2", "--iterations", "3", "--quiet"]
    r = cli(*args, "--workers", "1", "--out", tmp_path / "local", cache=cache)
    assert r.returncode == 0, r.stderr
    r = cli(*args, "--executor", "ray", "--out", tmp_path / "ray", cache=cache)
    assert r.returncode == 0, r.stderr
    local = pq.read_table(tmp_path / "local" / "results.parquet")
    assert local.num_rows == 3 * 2 * 3
    assert pq.read_table(tmp_path / "ray" / "results.parquet").equals(local)
    assert "j_best ≤ bound" in (tmp_path / "ray" / "report.md").read_text()
