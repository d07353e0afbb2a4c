"""Lane sets through the pipeline (``run_cells(lanes=True)``, the default on an accelerator): the
helicopter's learning methods as one program per seed chunk give the table and saved arrays of
the methods run one by one, bit for bit, and a lane set killed between chunks resumes to it."""

import numpy as np
import pytest

from loopid.experiments import chunks
from loopid.experiments.execute import run_cells
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.experiments.results import metadata, read_table

pytestmark = pytest.mark.slow  # two compilations of the hover cell (~20 s each)

#: three ν kinds (the expert's rollouts among them) and Abbeel's schedule, plus the expert alone
METHODS = ["dagger-t", "batch-e", "abbeel", "dagger-en", "expert"]
LANES = METHODS[:4]
HOVER = scenario("hover", seeds=6, iterations=3, samples=50, test_trajectories=10)


@pytest.fixture(scope="module")
def one_by_one(tmp_path_factory):
    """The reference: each method its own cell, in two seed chunks of 3."""
    out = tmp_path_factory.mktemp("one_by_one")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(chunks, "LANE_WIDTH", 3)
        run_cells(out, [HOVER], METHODS, workers=1, lanes=False)
    return out


def _arrays(run_dir, method):
    with np.load(run_dir / "cells" / f"hover__{method}.npz") as f:
        return {k: f[k] for k in f.files}


def _assert_same_run(a, b):
    assert read_table(a / "results.parquet").equals(read_table(b / "results.parquet"))
    for m in METHODS:
        x, y = _arrays(a, m), _arrays(b, m)
        assert x.keys() == y.keys(), m
        for k in x:
            np.testing.assert_array_equal(x[k], y[k], err_msg=f"{m} {k}")


def test_a_killed_lane_set_resumes_to_the_table_of_the_methods_one_by_one(
    one_by_one, tmp_path, monkeypatch
):
    monkeypatch.setattr(chunks, "LANE_WIDTH", 3)
    out = tmp_path / "lanes"
    started = []

    def on_cell(name, method, total):
        def advance(done):
            started.append((method, done))
            if done > 3 * HOVER.iterations:  # the second chunk's first iteration: kill it
                raise KeyboardInterrupt

        return advance

    with pytest.raises(KeyboardInterrupt):
        run_cells(out, [HOVER], METHODS, workers=1, lanes=True, on_cell=on_cell)
    # the first chunk of every lane-set method was saved, as one task (all four advanced)
    assert {m for m, _ in started} == set(LANES)
    for m in LANES:
        assert chunks.ChunkFiles(out / "cells", "hover", m).missing(6) == [3, 4, 5]
    run_cells(out, [HOVER], METHODS, workers=1, lanes=True)
    _assert_same_run(one_by_one, out)
    lane_set = metadata(out / "cells" / "hover__abbeel.parquet")
    assert lane_set["lane_set"] == ",".join(LANES)
    for m in LANES:  # the lane set's times are shared among its cells, both of them
        meta = metadata(out / "cells" / f"hover__{m}.parquet")
        assert 0 < float(meta["first_s"]) <= float(meta["wall_s"]), (m, meta)
    assert "lane_set" not in metadata(out / "cells" / "hover__expert.parquet")


def test_blocks_of_iterations_as_an_accelerator_runs_them_give_the_same_table(
    one_by_one, tmp_path, monkeypatch
):
    """The accelerator's default, forced on the CPU: the lane set's 3 iterations as one block
    (one ``lax.scan``) give the table and arrays of the methods one by one, bit for bit."""
    from loopid.algorithms import loop
    from loopid.experiments import backend

    blocks = []

    def in_blocks(program, keys, noise, schedules, which, block, progress):
        blocks.append(block)
        return run_blocks(program, keys, noise, schedules, which, block, progress)

    run_blocks = loop._blocks
    monkeypatch.setattr(loop, "_blocks", in_blocks)
    monkeypatch.setattr(chunks, "LANE_WIDTH", 3)
    monkeypatch.setattr(backend, "default_block", lambda: backend.ACCELERATOR_BLOCK)
    out = tmp_path / "blocks"
    run_cells(out, [HOVER], METHODS, workers=1, lanes=True, memory=16.0)
    assert blocks == [3, 3]  # the lane set's two seed chunks, each one block of 3 iterations
    _assert_same_run(one_by_one, out)


def test_the_rows_check_counts_the_widest_lane_sets_methods(tmp_path, monkeypatch):
    """A lane set keeps the rows of all its methods' seeds: the check before anything runs
    counts the widest lane set's methods (4 here), not the scenario's lane sets (2: the
    learning methods and the expert). 10⁶ iterations of 2 seeds, each method's chunk padded to
    the lane width (10): about 4 GB of rows for 2 methods, 7 GB for 4; a 5 GB budget refuses it
    at once."""
    from loopid.experiments import execute

    def planned(*args, **kwargs):
        raise AssertionError("the run was planned: the rows check let it through")

    monkeypatch.setattr(execute, "plan", planned)
    huge = HOVER.replace(seeds=2, iterations=10**6)
    with pytest.raises(ValueError, match="1000000 iterations of 40 seeds a task"):
        run_cells(tmp_path / "huge", [huge], METHODS, workers=1, lanes=True, memory=5.0)
