"""Bad input to ``loopid round``: one line, exit code 2, and the round directory unchanged."""

import numpy as np
import pytest
from rounds_helpers import transitions, write_config, write_round

from loopid import cli, rounds


def snapshot(root) -> dict:
    """Every file under ``root``: its bytes."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def loopid(capsys, *args) -> tuple[int, str]:
    with pytest.raises(SystemExit) as done:
        cli.main([str(a) for a in args])
    return done.value.code, capsys.readouterr().err


@pytest.fixture
def started(tmp_path):
    """A round directory after one update, and a fresh round's rows."""
    rng = np.random.default_rng(3)
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml"))
    first = write_round(tmp_path / "first.parquet", transitions(rng, 40))
    rounds.update(root, first)
    return root, first, transitions(rng, 40)


def _missing(rows):
    del rows["next_v"]


def _size(rows):
    for k in rows:
        rows[k] = rows[k][:-1]


def _nan(rows):
    rows["v"][7] = np.nan


def _source(rows):
    rows["source"][3] = "expert"


def _sizes(rows):  # a third state the config does not name
    rows["w"], rows["next_w"] = rows["p"], rows["p"]


CASES = {
    "missing column": (_missing, "missing column(s) next_v"),
    "wrong size": (_size, "39 transitions; a round takes [rounds] samples = 40"),
    "NaN": (_nan, "column 'v' holds nan at row 7"),
    "unknown source": (_source, "unknown source label(s) ['expert']"),
    "config sizes": (_sizes, "next_w are not next states of the config's states p, v"),
}


@pytest.mark.parametrize("case", CASES)
def test_bad_file_is_refused(started, tmp_path, capsys, case):
    root, _, rows = started
    spoil, message = CASES[case]
    spoil(rows)
    before = snapshot(root)
    code, err = loopid(capsys, "round", "update", root, write_round(tmp_path / "bad.parquet", rows))
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("loopid: error: ") and message in err, err
    assert snapshot(root) == before


def test_file_already_given_is_refused(started, tmp_path, capsys):
    root, first, _ = started
    again = tmp_path / "again.parquet"
    again.write_bytes((tmp_path / "first.parquet").read_bytes())  # same bytes, another name
    before = snapshot(root)
    for path in (first, again):
        code, err = loopid(capsys, "round", "update", root, path)
        assert code == 2 and err.count("\n") == 1 and "already given (the data of round 1)" in err
    assert snapshot(root) == before


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"system": "A = [[1.0, 0.0, 0.0]]"}, "model A must be finite"),
        ({"samples": 0}, "samples must be an integer >= 1"),
        ({"model": 'kind = "features"'}, "planner_kind 'lqr' solves a linear model"),
    ],
)
def test_bad_config_is_refused(tmp_path, capsys, edit, message):
    config = write_config(tmp_path / "c.toml", **edit)
    code, err = loopid(capsys, "round", "init", tmp_path / "dir", "--config", config)
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "dir").exists()


def test_export_refuses_a_bad_round_and_format(started, capsys):
    root, _, _ = started
    before = snapshot(root)
    code, err = loopid(capsys, "round", "export", root, "--round", "3")
    assert code == 2 and "--round must be 1..2" in err
    code, err = loopid(capsys, "round", "export", root, "--format", "pdf")
    assert code == 2 and "--format must be one of json, npz, c, got 'pdf'" in err
    assert snapshot(root) == before


def test_mpc_controller_is_not_exported_as_c(tmp_path, capsys):
    model = 'kind = "features"\ndegree = 2\n[planner]\nkind = "mpc"\nhorizon = 5\niterations = 3'
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml", model=model))
    before = snapshot(root)
    code, err = loopid(capsys, "round", "export", root, "--format", "c")
    assert code == 2 and err.count("\n") == 1
    assert "controller 1 plans online (MPC on the learned model): it has no gains" in err
    assert snapshot(root) == before
    assert rounds.export(root, "json").is_file()
