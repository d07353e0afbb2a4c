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
    formats = "json, npz, c, model, model-json, model-npz"
    assert code == 2 and f"--format must be one of {formats}, got 'pdf'" in err
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


def _printable_line(err: str) -> bool:
    return err.count("\n") == 1 and all(c.isprintable() for c in err.rstrip("\n"))


@pytest.mark.parametrize(
    ("name", "write", "message"),
    [
        ("parquet-as.csv", "parquet", "a .csv file holds text, this one holds Parquet (rename it"),
        ("csv-as.parquet", "csv", "a .parquet file holds Parquet, this one holds text (a CSV"),
        ("zip.csv", "zip", "a .csv file holds text, this one holds a ZIP archive"),
        ("binary.csv", "binary", "a .csv file holds text, this one holds binary data"),
        ("plain.csv.gz", "csv", "a .csv.gz file holds gzip-compressed data, this one holds text"),
        ("rows.txt", "csv", "a round's file is .parquet, .pq, .csv, .csv.gz, .csv.bz2, .csv.zst"),
    ],
)
def test_a_wrong_format_for_its_suffix_is_one_printable_line(
    started, tmp_path, capsys, name, write, message
):
    """A Parquet file named .csv (raw binary with NUL bytes, that the CSV reader once quoted to
    the terminal) and the like: one printable line naming the suffix and the format found."""
    root, _, rows = started
    path = tmp_path / name
    if write == "parquet":
        write_round(tmp_path / "rows.parquet", rows)
        path.write_bytes((tmp_path / "rows.parquet").read_bytes())
        assert b"\x00" in path.read_bytes()
    elif write == "csv":
        write_round(tmp_path / "rows.csv", rows)
        path.write_bytes((tmp_path / "rows.csv").read_bytes())
    elif write == "zip":
        np.savez(path.with_suffix(".npz"), x=np.ones(3))
        path.write_bytes(path.with_suffix(".npz").read_bytes())
    else:
        path.write_bytes(b"p,v\n\x00\x01\x02\x1b[31m\xff\xfe\n")
    before = snapshot(root)
    code, err = loopid(capsys, "round", "update", root, path)
    assert code == 2 and _printable_line(err) and message in err, repr(err)
    assert f"'{path}'" in err
    assert snapshot(root) == before


def _csv_with(rows, column: str, row: int, text: str) -> bytes:
    """The rows as CSV text with the field ``column`` of data row ``row`` replaced by ``text``."""
    lines = [",".join(rows)] + [
        ",".join(str(rows[k][i]) for k in rows) for i in range(len(rows["p"]))
    ]
    cells = lines[row + 1].split(",")
    cells[list(rows).index(column)] = text
    lines[row + 1] = ",".join(cells)
    return ("\n".join(lines) + "\n").encode()


@pytest.mark.parametrize(
    ("column", "row", "text", "message"),
    [
        ("v", 12, "NaN", "column 'v' holds nan at row 12"),
        ("next_p", 3, "-inf", "column 'next_p' holds -inf at row 3"),
        ("f", 30, "", "column 'f' has an empty value at row 30"),
        ("p", 17, "NA", "column 'p' must hold numbers; it holds 'NA' at row 17"),
        ("p", 21, "1.5e", "column 'p' must hold numbers; it holds '1.5e' at row 21"),
        ("source", 9, "expert", "unknown source label(s) ['expert'] (first at row 9)"),
    ],
)
def test_a_bad_value_names_its_row_and_column(
    started, tmp_path, capsys, column, row, text, message
):
    """A literal NaN in a CSV is a number that is not finite (it was once an "empty value" with
    no row); rows count from 0, the header excluded."""
    root, _, rows = started
    rows["source"] = list(rows["source"])
    path = tmp_path / "bad.csv"
    path.write_bytes(_csv_with(rows, column, row, text))
    before = snapshot(root)
    code, err = loopid(capsys, "round", "update", root, path)
    assert code == 2 and _printable_line(err) and message in err, err
    assert snapshot(root) == before


def test_a_step_out_of_range_names_its_row(tmp_path, capsys):
    rng = np.random.default_rng(8)
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml", model="time_varying = true"))
    rows = transitions(rng, 40, t=True)
    rows["t"][25] = 30
    code, err = loopid(capsys, "round", "update", root, write_round(tmp_path / "t.csv", rows))
    assert code == 2 and "column 't' must be steps 0..29; it holds 30 at row 25" in err, err


@pytest.mark.parametrize(
    ("damaged", "commands"),
    [
        ("state.npz", ("update", "export")),
        ("controllers/round-002.npz", ("export",)),  # update writes controller 3, reads none
        ("data/round-001.parquet", ("update",)),
    ],
)
def test_a_damaged_round_directory_file_is_named(started, tmp_path, capsys, damaged, commands):
    """A truncated file of the round directory: one line naming it, exit 2, nothing recomputed
    or rewritten (the directory holds what was given; only a copy can restore it)."""
    root, _, rows = started
    path = root / damaged
    path.write_bytes(path.read_bytes()[:100])
    before = snapshot(root)
    new = write_round(tmp_path / "new.parquet", rows)
    args = {"update": ("update", root, new), "export": ("export", root, "--format", "json")}
    for command in commands:
        code, err = loopid(capsys, "round", *args[command])
        assert code == 2 and _printable_line(err), err
        assert f"'{path}' is damaged (" in err and "restore it from a copy" in err, err
    assert snapshot(root) == before


def test_a_damaged_round_config_is_named(started, tmp_path, capsys):
    """A round directory's config.toml cut short with binary after it: one printable line
    naming it (the decoder's message once named no file)."""
    root, _, rows = started
    config = root / "config.toml"
    config.write_bytes(config.read_bytes()[:50] + b"\x00\xff\xfe")
    before = snapshot(root)
    new = write_round(tmp_path / "new.parquet", rows)
    for args in (("update", root, new), ("export", root)):
        code, err = loopid(capsys, "round", *args)
        assert code == 2 and _printable_line(err), err
        assert f"'{config}': not UTF-8 text (byte 0xff at offset 51)" in err, err
    assert snapshot(root) == before
