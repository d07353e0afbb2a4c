"""Seed chunks (loopid.experiments.chunks): the plan, the same table whatever the chunking, resume
after a kill, the memory estimate against a measured peak, and the one-line refusals."""

import copy
import functools
import json
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from loopid.experiments import artifacts, chunks
from loopid.experiments.execute import run_cells
from loopid.experiments.families import helicopter
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.experiments.results import metadata, read_table
from loopid.experiments.seeds import seeds_from_value, seeds_value

SMALL = dict(iterations=3, samples=50, test_trajectories=10)


def test_split_pads_equal_chunks_and_covers_every_position_once():
    seeds = np.array([5, 3, 9, 1, 7, 2, 8])
    parts = chunks.split(seeds, list(range(7)), 3)
    assert [(c.start, c.stop) for c in parts] == [(0, 3), (3, 6), (6, 7)]
    assert all(c.seeds.size == 3 for c in parts)
    assert parts[-1].seeds.tolist() == [8, 8, 8]  # padded with the last seed
    # 7 seeds at most 4 per chunk: 2 chunks of 4, not 4 + 3 (one compiled shape, least padding);
    # never fewer than MIN_CHUNK = 3 seeds a program
    assert [c.seeds.size for c in chunks.split(seeds, list(range(7)), 4)] == [4, 4]
    assert chunks.split(seeds, [2], 1)[0].seeds.tolist() == [9, 9, 9]
    # resuming: only the missing positions, each chunk within a run of consecutive positions
    parts = chunks.split(seeds, [0, 1, 5, 6], 3)
    assert [(c.start, c.stop) for c in parts] == [(0, 2), (5, 7)]


def test_plan_runs_chunks_of_one_lane_width_and_a_task_over_budget_comes_back_in_chunks_that_fit(
    tmp_path, monkeypatch
):
    """30 seeds run in chunks of LANE_WIDTH (3 of 10) whatever the budget, 25 and 2 seeds in
    chunks of 10 too, padded (one program shape for every seed count); a task
    measures its programs at its own 10 seeds before it runs and, over its share of the budget,
    returns Oversized instead of rows; its seeds then come back as chunks that fit."""
    from loopid.experiments import cell
    from loopid.experiments.jobs import plan, resplit
    from loopid.experiments.rundir import RunDir

    s = scenario("hover", seeds=30, **SMALL)
    family = cell.family_of(s)
    jobs = plan(RunDir(tmp_path), [(s, "dagger-t")], np.arange(30), family)
    assert chunks.LANE_WIDTH == 10
    assert [job.part for job in jobs] == [(0, 10), (10, 20), (20, 30)]
    for count, parts in ((25, [(0, 10), (10, 20), (20, 25)]), (2, [(0, 2)])):
        few = plan(RunDir(tmp_path), [(s, "dagger-t")], np.arange(count), family)
        assert [job.part for job in few] == parts
        assert {len(job.seeds) for job in few} == {10}
        assert list(few[-1].seeds[parts[-1][1] - parts[-1][0] :]) == [count - 1] * (
            10 - parts[-1][1] + parts[-1][0]
        )  # padded with copies of the last seed
    asked = []

    def memory(s, method, seeds):
        asked.append(seeds)
        return 1000 * seeds

    measured = copy.copy(family)
    measured.memory = memory
    monkeypatch.setattr(cell, "family_of", lambda s: measured)
    result = cell.run_chunk(s, "dagger-t", jobs[1].seeds, limit=6000)
    assert result == cell.Oversized(10_000) and asked == [10]
    # 6 seeds fit 6,000 bytes: positions 10..19 as 2 chunks of 5
    again = resplit(jobs[1], result.nbytes, np.arange(30), 6000)
    assert [(job.part, len(job.seeds)) for job in again] == [((10, 15), 5), ((15, 20), 5)]
    assert {job.program for job in again} == {(*jobs[1].program[:-1], 5)}  # other programs
    with pytest.raises(ValueError, match=r"^hover / dagger-t: a chunk of 3 seeds needs about"):
        resplit(jobs[1], result.nbytes, np.arange(30), 2000)


def test_the_jobs_of_one_compiled_program_share_its_key(tmp_path, monkeypatch):
    """``Job.program`` (what the workers wait on while its first job compiles): one method at a
    time, the helicopter's learning methods share one key per scenario, over their chunks; the
    expert and the policy gradient have keys of their own, and a lane set's job (another
    program: its lanes are every method's seeds) another again."""
    from loopid.experiments.families import family_of
    from loopid.experiments.families.helicopter.methods import METHODS
    from loopid.experiments.jobs import lane_sets, plan
    from loopid.experiments.rundir import RunDir

    panels = [scenario(name, seeds=30, **SMALL) for name in ("hover", "funnel")]
    todo = [(s, m) for s in panels for m in METHODS]
    family = family_of(panels[0])
    one = plan(RunDir(tmp_path), todo, np.arange(30), family)
    keys = {(job.scenario.name, job.method): set() for job in one}
    for job in one:
        keys[(job.scenario.name, job.method)].add(job.program)
    assert all(len(k) == 1 for k in keys.values())  # every chunk of a cell: one key
    for name in ("hover", "funnel"):
        learning = {keys[(name, m)].pop() for m in METHODS if m not in ("expert", "pg")}
        alone = [keys[(name, m)].pop() for m in ("expert", "pg")]
        assert len(learning) == 1 and len({*learning, *alone}) == 3, name
    assert len({job.program for job in one}) == 6  # none shared across the panels
    lanes = plan(RunDir(tmp_path), todo, np.arange(30), family, groups=lane_sets(family, todo))
    lane_set = [job for job in lanes if isinstance(job.method, tuple)]
    assert len({job.program for job in lane_set}) == 2  # one per panel, over its chunks
    assert not {job.program for job in lane_set} & {job.program for job in one}
    # the MDP family's methods all run its scenario's one program: one key; a family that
    # groups nothing (each method alone, the default): a key per method
    from loopid.experiments.families.base import Family
    from loopid.experiments.families.mdp import MDP_SCENARIOS

    mdp = MDP_SCENARIOS["mdp-random"]
    todo = [(mdp, m) for m in ("dagger", "batch", "abbeel")]
    family = family_of(mdp)
    jobs = plan(RunDir(tmp_path / "mdp"), todo, np.arange(2), family)
    assert len(jobs) == 3 and len({job.program for job in jobs}) == 1
    monkeypatch.setattr(family, "lane_sets", functools.partial(Family.lane_sets, family))
    jobs = plan(RunDir(tmp_path / "alone"), todo, np.arange(2), family)
    assert len({job.program for job in jobs}) == 3


def test_stacked_arrays_are_saved_as_their_join_one_piece_at_a_time(tmp_path):
    """A chunked cell's arrays are written piece by piece (artifacts.Stacked): ``np.load`` reads
    back exactly the joined array, with the dtype, beside ordinary arrays; the pieces are read
    only while writing; pieces that do not stack into the stated shape are refused."""
    rng = np.random.default_rng(0)
    parts = [rng.normal(size=(k, 4, 3)) for k in (3, 3, 2)]
    read = []

    def pieces():
        for i, p in enumerate(parts):
            read.append(i)
            yield p

    stacked = artifacts.Stacked((8, 4, 3), np.dtype(np.float64), pieces)
    assert read == []
    artifacts.save_npz(tmp_path / "a.npz", {"seeds": np.arange(8), "K": stacked, "x": parts[0]})
    assert read == [0, 1, 2]
    with np.load(tmp_path / "a.npz", allow_pickle=False) as data:
        assert data.files == ["seeds", "K", "x"]
        assert np.array_equal(data["K"], np.concatenate(parts)) and data["K"].dtype == np.float64
        assert np.array_equal(data["x"], parts[0]) and np.array_equal(data["seeds"], np.arange(8))
    for shape in [(9, 4, 3), (8, 4, 2)]:
        with pytest.raises(ValueError, match=r"stack|rows"):
            artifacts.save_npz(
                tmp_path / "b.npz", {"K": artifacts.Stacked(shape, np.float64, lambda: iter(parts))}
            )


def test_chunk_size_is_the_most_seeds_that_fit_and_refuses_in_one_line():
    assert chunks.chunk_size(1000, 10, 5000, "x") == 10
    assert chunks.chunk_size(1000, 10, 350, "x") == 3  # 100 bytes a seed at most
    with pytest.raises(ValueError, match=r"^hover / expert: a chunk of 3 seeds needs about 300 B"):
        chunks.chunk_size(1000, 10, 250, "hover / expert")


def test_budget_and_processes():
    assert chunks.budget(2.0, 4) == 500_000_000
    assert 0 <= chunks.budget(None, 1) < chunks.available_bytes()
    with pytest.raises(ValueError, match="--memory must be a positive number"):
        chunks.budget(-1.0)
    with pytest.raises(ValueError, match=r"--workers 99999: this machine has \d+ CPUs"):
        chunks.check_processes(99999)


@pytest.mark.parametrize("seeds", [[0, 1, 2], [4, 5, 6, 7], [3, 1, 2]])
def test_config_records_seeds_compactly(seeds):
    value = seeds_value(seeds)
    assert seeds_from_value(value).tolist() == seeds
    assert value == {0: 3, 4: {"start": 4, "count": 4}, 3: [3, 1, 2]}[seeds[0]]


def _budget_for(s, method, seeds, per_chunk):
    """--memory (GB) that gives chunks of ``per_chunk`` seeds in one process."""
    estimate = helicopter.memory(s, method, seeds)
    return estimate / seeds * (per_chunk + 0.5) / 1e9


def test_chunked_cell_equals_one_chunk_and_resumes_after_a_kill(tmp_path, monkeypatch):
    """7 seeds of hover-delay DAgger (ν_t) in chunks of 3 (3 + 3 + 1 padded to 3) give the table
    of one chunk of 7, row for row; a run killed after its first chunk resumes at the second and
    ends with the same table and artifacts."""
    s = scenario("hover-delay", seeds=7, **SMALL)
    whole = run_cells(tmp_path / "one", [s], ["dagger-t"], memory=100.0)
    assert not (tmp_path / "one/cells/hover-delay__dagger-t.chunks").exists()
    memory = _budget_for(s, "dagger-t", 7, 3)

    saves = []
    original = chunks.ChunkFiles.save

    def killed_after_first(self, chunk, table, final):
        original(self, chunk, table, final)
        saves.append(chunk.start)
        raise KeyboardInterrupt  # the run dies with one chunk saved

    monkeypatch.setattr(chunks.ChunkFiles, "save", killed_after_first)
    with pytest.raises(KeyboardInterrupt):
        run_cells(tmp_path / "chunked", [s], ["dagger-t"], memory=memory)
    monkeypatch.setattr(chunks.ChunkFiles, "save", original)
    left = chunks.ChunkFiles(tmp_path / "chunked/cells", "hover-delay", "dagger-t")
    assert left.finished() == [(0, 3)] and left.missing(7) == [3, 4, 5, 6]

    resumed = run_cells(tmp_path / "chunked", [s], ["dagger-t"], memory=memory)
    assert resumed.equals(whole)
    assert read_table(tmp_path / "chunked/results.parquet").equals(whole)
    assert not left.path.exists()  # merged into the cell's files
    a = np.load(tmp_path / "one/cells/hover-delay__dagger-t.npz")
    b = np.load(tmp_path / "chunked/cells/hover-delay__dagger-t.npz")
    assert sorted(a.files) == sorted(b.files)
    for name in a.files:
        assert np.array_equal(a[name], b[name]), name
    info = json.loads((tmp_path / "chunked/cells/hover-delay__dagger-t.json").read_text())
    assert info["seeds"] == list(range(7))


def test_a_damaged_saved_chunk_is_moved_aside_and_its_seeds_run_again(tmp_path, capsys):
    """A killed chunked run left two chunks, one of them truncated since: the rerun's check
    (:meth:`RunDir.finished`) moves that chunk's files to ``cells/damaged/``, names it in one
    line, and its seeds are missing again; the sound chunk is kept."""
    from loopid.experiments.results import SCHEMA
    from loopid.experiments.rundir import RunDir

    files = chunks.ChunkFiles(tmp_path / "cells", "hover", "dagger-t")
    for start in (0, 3):
        seeds = np.arange(start, start + 3)
        files.save(chunks.Chunk(start, start + 3, seeds), SCHEMA.empty_table(), {"K": seeds})
    npz = files.stem(0, 3).with_suffix(".npz")
    npz.write_bytes(npz.read_bytes()[:-10])
    assert not RunDir(tmp_path).finished("hover", "dagger-t")
    assert files.finished() == [(3, 6)] and files.missing(6) == [0, 1, 2]
    assert sorted(p.name for p in (tmp_path / "cells" / "damaged").iterdir()) == [
        "hover__dagger-t.chunks.000000000-000000003.npz",
        "hover__dagger-t.chunks.000000000-000000003.parquet",
    ]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"'{npz}' is damaged (" in err[0], err


_PEAK = textwrap.dedent(
    """
    import resource, sys, numpy as np
    import loopid
    from loopid.experiments.families import helicopter as H
    from loopid.experiments.families.helicopter.scenario import scenario
    name, method, S = sys.argv[1], sys.argv[2], int(sys.argv[3])
    s = scenario(name, iterations=2, seeds=S)
    rss0 = int(open("/proc/self/statm").read().split()[1]) * 4096
    estimate = H.memory(s, method, S)
    H.run(method, s, np.arange(S))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(rss0, estimate, peak)
    """
)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "method", "seeds"), [("hover", "dagger-t", 300), ("funnel", "expert", 300)]
)
def test_memory_estimate_within_a_factor_of_two_of_the_measured_peak(name, method, seeds):
    """The process's peak RSS (ru_maxrss) running the cell against its RSS before plus the
    estimate, within a factor of 2. The seed counts are large enough (300: about 1.7 GB of noise
    buffers on the hover) that the cell's buffers, not compilation (0.4-0.8 GB), set the peak."""
    out = subprocess.run(
        [sys.executable, "-c", _PEAK, name, method, str(seeds)],
        capture_output=True, text=True, check=True, env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )  # fmt: skip
    rss0, estimate, peak = map(int, out.stdout.split()[-3:])
    predicted = rss0 + estimate
    assert 0.5 <= predicted / peak <= 2.0, (rss0, estimate, peak)


@pytest.mark.slow
def test_cli_memory_budget_gives_the_same_table(tmp_path, cache):
    """The issue's check: ``loopid run hover --seeds 40`` under a small budget gives the table of
    the same command with 16 GB, every row and column. 16 GB runs chunks of one lane width
    (``chunks.LANE_WIDTH`` = 10: 4 chunks of 10); 30 MB holds 5 seeds (5.76 MB a seed, mostly
    the test noise while it is drawn): 8 chunks of 5, other column counts in every batched sum.
    (The issue's 100 MB now gives chunks of the lane width too.) With 100 test trajectories this
    caught ``jnp.sum`` over the cost's 21 error coordinates depending on the batch width (9 of
    the 120 test costs 1 ulp apart, chunks of 14 against one of 40), now summed in a fixed order
    (``plant.ordered_sum``)."""
    from conftest import cli

    common = ["run", "hover", "--seeds", "40", "--iterations", "3", "--methods", "dagger-t",
              "--workers", "1", "--quiet"]  # fmt: skip
    small = cli(*common, "--memory", "0.03", "--out", tmp_path / "small", cache=cache)
    assert small.returncode == 0, small.stderr
    large = cli(*common, "--memory", "16", "--out", tmp_path / "large", cache=cache)
    assert large.returncode == 0, large.stderr
    chunk_counts = [
        int(metadata(tmp_path / f"{run}/cells/hover__dagger-t.parquet")["chunks"])
        for run in ("small", "large")
    ]
    assert chunk_counts == [8, 4]
    a = read_table(tmp_path / "small/results.parquet")
    assert a.num_rows == 40 * 3 and a.equals(read_table(tmp_path / "large/results.parquet"))
    assert "seeds = 40" in (tmp_path / "small/config.toml").read_text()  # a count, not a list


def test_cli_refusals_are_one_line_with_nothing_left_behind(tmp_path, cache):
    """An impossible budget, an --out that cannot be written and too many workers: exit 2, one
    line naming the value, no traceback, no run directory."""
    from conftest import cli

    out = tmp_path / "run"
    tiny = cli("run", "hover", "--seeds", "40", "--iterations", "2", "--methods", "expert",
               "--memory", "0.0001", "--out", out, cache=cache)  # fmt: skip
    for result, pattern in [
        (tiny, r"^loopid: error: hover / expert: a chunk of 3 seeds needs about .* memory budget"),
        (cli("run", "hover", "--out", "/proc/x", cache=cache), r"--out '/proc/x' cannot be"),
        (cli("run", "hover", "--workers", "99999", "--out", out, cache=cache), r"--workers 99999"),
    ]:
        lines = result.stderr.strip().splitlines()
        assert result.returncode == 2, result.stderr
        assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
        assert re.search(pattern, lines[0]), lines[0]
    assert not out.exists()
