"""Run directories (issue 5 "Must show" 7): resume skips finished cells, same table, foreign
configurations refused."""

import copy
import shutil
from pathlib import Path

import numpy as np
import pytest

import loopid.experiments.cell as cell
import loopid.experiments.execute as execute
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.experiments.results import read_table

SCENARIOS = [
    scenario("hover", iterations=3, seeds=2, test_trajectories=4),
    scenario("hover-delay", iterations=3, seeds=2, test_trajectories=4),
]
METHODS = ["expert"]


@pytest.fixture
def counted(monkeypatch):
    """Count the cells actually computed (run_cells calls the family's run once per cell)."""
    calls = []
    real = cell.family_of

    def family_of(s):
        family = real(s)

        def counting(method, s, seeds=None, **kw):
            calls.append((s.name, method))
            return family.run(method, s, seeds, **kw)

        counted = copy.copy(family)
        counted.run = counting
        return counted

    monkeypatch.setattr(cell, "family_of", family_of)
    return calls


def test_resume_skips_finished_cells(tmp_path, counted):
    logs = []
    first = execute.run_cells(tmp_path, SCENARIOS, METHODS, log=logs.append)
    assert counted == [("hover", "expert"), ("hover-delay", "expert")]
    assert first.num_rows == 2 * 2 * 3
    assert (tmp_path / "config.toml").exists() and (tmp_path / "results.parquet").exists()
    assert read_table(tmp_path / "results.parquet").equals(first)

    counted.clear()
    logs.clear()
    second = execute.run_cells(tmp_path, SCENARIOS, METHODS, log=logs.append)
    assert counted == []  # nothing recomputed
    assert all("already finished" in line for line in logs) and len(logs) == 2
    assert second.equals(first)

    # a run killed after its first cell: only the missing cell is computed, same table
    (tmp_path / "cells" / "hover-delay__expert.parquet").unlink()
    third = execute.run_cells(tmp_path, SCENARIOS, METHODS)
    assert counted == [("hover-delay", "expert")]
    assert third.equals(first)
    # the table holds what the cells say: the expert's flat line, per seed
    costs = np.asarray(third.column("test_cost")).reshape(2, 2, 3)
    np.testing.assert_array_equal(costs, np.repeat(costs[:, :, :1], 3, axis=2))


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A run directory holding the finished run of SCENARIOS × METHODS."""
    path = tmp_path_factory.mktemp("finished")
    execute.run_cells(path, SCENARIOS, METHODS)
    return path


@pytest.mark.parametrize(
    "change",
    [
        {"scenarios": [SCENARIOS[0].replace(test_trajectories=5), SCENARIOS[1]]},
        {"scenarios": [SCENARIOS[0]]},
        {"methods": ["expert", "dagger-t"]},
        {"seeds": [0, 1, 2]},
    ],
)
def test_different_configuration_refused(finished, tmp_path, counted, change):
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    before = sorted(p.name for p in (out / "cells").iterdir())
    kwargs = {"scenarios": SCENARIOS, "methods": METHODS, "seeds": None} | change
    with pytest.raises(ValueError, match="different configuration"):
        execute.run_cells(out, kwargs["scenarios"], kwargs["methods"], kwargs["seeds"])
    assert counted == []  # refused before computing anything
    assert sorted(p.name for p in (out / "cells").iterdir()) == before  # nothing touched
    # the same configuration is accepted (and skips everything)
    execute.run_cells(out, SCENARIOS, METHODS)
    assert counted == []


def test_rows_that_cannot_fit_the_budget_are_refused_at_once(tmp_path, capsys):
    """``--iterations 1000000000``: one line naming the iterations, exit 2, nothing written
    (it used to run silently until killed)."""
    from loopid.cli import main

    out = tmp_path / "huge"
    with pytest.raises(SystemExit) as e:
        main(["run", "hover", "--iterations", "1000000000", "--seeds", "2", "--methods", "expert",
              "--workers", "1", "--out", str(out)])  # fmt: skip
    assert e.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "1000000000 iterations" in lines[0], lines
    assert "lower --iterations" in lines[0]
    assert not out.exists()


def test_a_full_disk_leaves_nothing_behind_when_nothing_finished(tmp_path, monkeypatch):
    """The disk fills while the first chunk's arrays are written: the error is raised, and
    neither the temporary file nor ``config.toml`` nor the folders stay (a run that finished
    nothing leaves nothing behind)."""
    import errno

    def full_disk(f, **arrays):
        f.write(b"half an array")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez", full_disk)
    out = tmp_path / "new" / "run"
    s = scenario("hover", iterations=2, seeds=20, test_trajectories=4)
    with pytest.raises(OSError, match="No space left"):
        execute.run_cells(out, [s], ["expert"], workers=1)
    assert list(tmp_path.iterdir()) == []  # "new" was created by the run: it went too


def test_a_failed_write_removes_its_temporary_file(tmp_path):
    from loopid.files import replace_atomically

    def fails(tmp):
        tmp.write_bytes(b"part")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        replace_atomically(tmp_path / "a.parquet", fails)
    assert list(tmp_path.iterdir()) == []


def test_runs_given_together_equal_runs_given_one_by_one(finished, tmp_path, counted):
    """run_all (what ``loopid reproduce`` does with the helicopter's and the MDP study's run
    directories, one inside the other): each run's table and files as its own run_cells gives,
    every cell computed once; a finished run is skipped; scenario names shared by two runs are
    refused before anything is written."""
    Run = execute.Run
    out = tmp_path / "outer"
    runs = [Run(out, SCENARIOS[:1], METHODS), Run(out / "inner", SCENARIOS[1:], METHODS)]
    tables = execute.run_all(runs)
    assert sorted(counted) == [("hover", "expert"), ("hover-delay", "expert")]
    alone = read_table(finished / "results.parquet")
    assert tables[0].equals(alone.slice(0, 6)) and tables[1].equals(alone.slice(6, 6))
    assert read_table(out / "inner" / "results.parquet").equals(tables[1])
    counted.clear()
    assert execute.run_all(runs)[0].equals(tables[0]) and counted == []
    with pytest.raises(ValueError, match="names must differ across the runs"):
        execute.run_all([runs[0], Run(tmp_path / "other", SCENARIOS[:1], METHODS)])
    assert not (tmp_path / "other").exists()


def test_runs_together_that_finish_nothing_leave_nothing_behind(tmp_path, monkeypatch):
    """The disk fills at the first save: the outer run's folder (which holds the inner one)
    goes, with nothing saved in either."""
    import errno

    def full_disk(f, **arrays):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez", full_disk)
    out = tmp_path / "new" / "run"
    chunked = [s.replace(iterations=2, seeds=20) for s in SCENARIOS]  # a chunk is saved first
    runs = [
        execute.Run(out, chunked[:1], METHODS),
        execute.Run(out / "mdp", chunked[1:], METHODS),
    ]
    with pytest.raises(OSError, match="No space left"):
        execute.run_all(runs, workers=1)
    assert list(tmp_path.iterdir()) == []


def _disk_full_in(folder):
    """``np.savez`` that fails with a full disk for files under ``folder``/cells only."""
    import errno

    real = np.savez

    def savez(f, **arrays):
        if Path(f.name).is_relative_to(folder / "cells"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(f, **arrays)

    return savez


@pytest.mark.parametrize("failing", ["outer", "inner"])
def test_nested_runs_keep_what_the_other_saved(tmp_path, monkeypatch, failing):
    """One run's saves fail after the other's succeeded (one worker: the runs in the order
    given, the one that fails last): the run that saved keeps its cells; of the one that saved
    nothing, everything it wrote goes, its folder too where it holds no other run's."""
    out = tmp_path / "new" / "run"
    chunked = [s.replace(iterations=2, seeds=20) for s in SCENARIOS]
    outer, inner = (
        execute.Run(out, chunked[:1], METHODS),
        execute.Run(out / "mdp", chunked[1:], METHODS),
    )
    runs = [inner, outer] if failing == "outer" else [outer, inner]
    monkeypatch.setattr(np, "savez", _disk_full_in(out if failing == "outer" else out / "mdp"))
    with pytest.raises(OSError, match="No space left"):
        execute.run_all(runs, workers=1)
    saved = inner if failing == "outer" else outer
    assert list((Path(saved.out) / "cells").glob("*.parquet"))  # its chunks or its cell
    if failing == "outer":
        assert sorted(p.name for p in out.iterdir()) == ["mdp"]  # no config.toml, no cells
    else:
        assert not (out / "mdp").exists()


def test_runs_need_their_own_directories(tmp_path):
    with pytest.raises(ValueError, match="its own directory"):
        execute.run_all([execute.Run(tmp_path / "a", SCENARIOS[:1], METHODS),
                         execute.Run(tmp_path / "a", SCENARIOS[1:], METHODS)])  # fmt: skip
    with pytest.raises(ValueError, match="scenario names must differ, got"):
        execute.run_cells(tmp_path / "b", [SCENARIOS[0], SCENARIOS[0]], METHODS)
    assert list(tmp_path.iterdir()) == []


def _loopid(capsys, *args) -> tuple[int, list[str]]:
    from loopid.cli import main

    with pytest.raises(SystemExit) as e:
        main([str(a) for a in args])
    return e.value.code, capsys.readouterr().err.strip().splitlines()


def test_a_damaged_cell_file_is_named_then_moved_aside_and_computed_again(
    finished, tmp_path, counted, capsys
):
    """A truncated ``cells/*.npz`` (it once gave ``BadZipFile`` and exit 1 with no file named):
    ``loopid evaluate``, ``plot`` and ``animate`` name it in one line and exit 2, ``loopid.load``
    raises naming it, nothing recomputed or written; the rerun moves the cell's files to
    ``cells/damaged/`` (one line on stderr), computes that cell alone again and ends with the
    table and artifacts of the undamaged run."""
    import loopid
    from loopid.experiments import artifacts

    out = tmp_path / "run"
    shutil.copytree(finished, out)
    npz = out / "cells" / "hover__expert.npz"
    truncated = npz.read_bytes()[: npz.stat().st_size // 2]
    npz.write_bytes(truncated)
    before = {f: f.read_bytes() for f in out.rglob("*") if f.is_file()}
    for args in (
        ["evaluate", out, "--scenario", "hover"],
        ["plot", out],
        ["animate", out, "--method", "expert", "--out", tmp_path / "a.gif"],
    ):
        code, err = _loopid(capsys, *args)
        assert code == 2 and len(err) == 1, err
        assert err[0].startswith(f"loopid: error: '{npz}' is damaged (") and "again" in err[0]
    with pytest.raises(artifacts.Damaged, match=r"hover__expert\.npz' is damaged") as e:
        loopid.load(out, "hover", "expert", 0)
    assert e.value.path == npz
    after = {f: f.read_bytes() for f in out.rglob("*") if f.is_file()}
    assert after == before and not (tmp_path / "a.gif").exists() and counted == []

    table = execute.run_cells(out, SCENARIOS, METHODS)
    assert counted == [("hover", "expert")]  # that cell alone
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"'{npz}' is damaged (" in err[0], err
    assert f"moved it to '{out / 'cells' / 'damaged'}'" in err[0]
    assert (out / "cells" / "damaged" / "hover__expert.npz").read_bytes() == truncated
    assert sorted(p.name for p in (out / "cells" / "damaged").iterdir()) == [
        "hover__expert.json", "hover__expert.npz", "hover__expert.parquet",
    ]  # fmt: skip
    whole = read_table(finished / "results.parquet")
    assert table.equals(whole) and read_table(out / "results.parquet").equals(whole)
    _, again = artifacts.read(out / "cells", "hover", "expert")
    _, before = artifacts.read(finished / "cells", "hover", "expert")
    assert again.keys() == before.keys()
    assert all(np.array_equal(again[k], before[k]) for k in before)
    counted.clear()
    assert execute.run_cells(out, SCENARIOS, METHODS).equals(whole) and counted == []
    # damaged again: the copy set aside before stays, the new one is numbered
    npz.write_bytes(npz.read_bytes()[:100])
    assert execute.run_cells(out, SCENARIOS, METHODS).equals(whole)
    damaged = out / "cells" / "damaged"
    assert (damaged / "hover__expert.npz").read_bytes() == truncated
    assert (damaged / "hover__expert.npz.2").stat().st_size == 100


@pytest.mark.parametrize(
    ("name", "spoil", "why"),
    [
        ("hover__expert.parquet", lambda b: b[:-20], "Parquet"),
        ("hover__expert.json", lambda b: b[:10], "Unterminated string"),
        ("hover__expert.npz", lambda b: b[:200] + bytes([b[200] ^ 1]) + b[201:], "CRC-32"),
        ("hover__expert.npz", lambda b: b"", "File is not a zip file"),
    ],
)
def test_every_damage_to_a_cell_counts_as_unfinished(finished, tmp_path, counted, capsys,
                                                     name, spoil, why):  # fmt: skip
    """A truncated row file or JSON, a flipped bit in an array (the zip's CRC-32), an empty
    npz: the file named on stderr, the cell computed again, the same table."""
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    path = out / "cells" / name
    path.write_bytes(spoil(path.read_bytes()))
    table = execute.run_cells(out, SCENARIOS, METHODS)
    assert counted == [("hover", "expert")]
    err = capsys.readouterr().err
    assert f"'{path}' is damaged (" in err and why in err, err
    assert table.equals(read_table(finished / "results.parquet"))


def test_a_damaged_evaluate_table_is_named_before_anything_flies(finished, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    (out / "evaluate.parquet").write_bytes(b"PAR1\x00\x01")
    code, err = _loopid(capsys, "evaluate", out)
    assert code == 2 and len(err) == 1, err
    assert f"'{out / 'evaluate.parquet'}' is damaged (" in err[0] and "move it away" in err[0]
    assert (out / "evaluate.parquet").read_bytes() == b"PAR1\x00\x01"
