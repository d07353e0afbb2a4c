"""The ``loopid`` command line, as a user runs it (subprocess): files, resume, one-line errors."""

import os
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

import loopid


def loopid_cli(*args, tmp_path):
    env = dict(os.environ, LOOPID_JAX_CACHE=str(tmp_path / "jax-cache"))
    return subprocess.run(
        [sys.executable, "-m", "loopid", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )


def test_version(tmp_path):
    r = loopid_cli("--version", tmp_path=tmp_path)
    assert r.returncode == 0
    assert r.stdout.strip() == f"loopid {loopid.__version__}"


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["run", "nope"], "'nope'"),
        (["run", "hover", "--methods", "dagger-t,foo"], "'foo'"),
        (["run", "hover", "--seeds", "-1"], "-1"),
        (["run", "hover", "--seeds", "abc"], "--seeds"),
        (["run", "hover", "--iterations", "ten"], "--iterations"),
        (["run", "hover", "--samples", "0"], "samples"),
        (["reproduce", "--bogus"], "--bogus"),
    ],
)
def test_bad_input_exits_2_with_one_line(args, needle, tmp_path):
    out = tmp_path / "out"
    extra = ["--out", str(out)] if args[0] == "run" else []
    r = loopid_cli(*args, *extra, tmp_path=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert needle in lines[0] and "Traceback" not in r.stderr
    assert not out.exists()


@pytest.mark.slow
def test_run_writes_table_and_resumes(tmp_path):
    out = tmp_path / "run"
    args = ["run", "hover", "--methods", "dagger-t,expert", "--seeds", "2", "--iterations", "3",
            "--test-trajectories", "5", "--out", str(out), "--quiet"]  # fmt: skip
    r = loopid_cli(*args, tmp_path=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (out / "config.toml").exists()
    table = pq.read_table(out / "results.parquet")
    assert table.num_rows == 2 * 2 * 3
    cols = table.to_pydict()
    assert set(cols["method"]) == {"dagger-t", "expert"}
    assert np.isfinite(cols["test_cost"]).all()
    r = loopid_cli(*args, tmp_path=tmp_path)  # resume: every cell is finished, nothing reruns
    assert r.returncode == 0 and pq.read_table(out / "results.parquet").equals(table)
    # a different configuration in the same directory is refused, and changes nothing
    r = loopid_cli(*args[:-3], "--samples", "50", "--out", str(out), tmp_path=tmp_path)
    assert r.returncode == 2 and "different configuration" in r.stderr
    assert pq.read_table(out / "results.parquet").equals(table)
