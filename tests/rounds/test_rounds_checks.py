"""A round's file against its round directory: the same rows in another format or compression are
refused, a partial overlap warns with its fraction, and a split far from the plan is refused
unless accepted."""

import shutil

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
from rounds_helpers import transitions, write_config, write_round
from scipy.stats import binom
from test_rounds_bad_input import loopid, snapshot

from loopid import rounds
from loopid.rounds import checks


@pytest.fixture
def started(tmp_path):
    """A round directory after one update from ``first.parquet`` (snappy, Parquet's default),
    and the rows of that file."""
    rng = np.random.default_rng(11)
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml"))
    rows = transitions(rng, 40)
    rows["p"][0] = 0.0  # a zero, to be given again as -0.0
    first = tmp_path / "first.parquet"
    pq.write_table(pa.table(rows), first, compression="snappy")
    rounds.update(root, first)
    return root, rows, rng


def test_the_same_rows_in_another_format_are_refused(started, tmp_path, capsys):
    """The rows of the first file as Parquet with zstd (bytes that differ), as CSV (text whose
    numbers parse back to the same float64) and as gzip-compressed CSV: each refused with one
    line naming the file the rows were learned from, and the directory unchanged."""
    root, rows, _ = started
    zstd, csv, gz = tmp_path / "again.parquet", tmp_path / "again.csv", tmp_path / "again.csv.gz"
    pq.write_table(pa.table(rows), zstd, compression="zstd")
    pacsv.write_csv(pa.table(rows), csv)
    with pa.CompressedOutputStream(str(gz), "gzip") as out:
        pacsv.write_csv(pa.table(rows), out)
    assert zstd.read_bytes() != (tmp_path / "first.parquet").read_bytes()
    before = snapshot(root)
    for path in (zstd, csv, gz):
        code, err = loopid(capsys, "round", "update", root, path)
        assert code == 2 and err.count("\n") == 1, err
        assert f"'{path}': every row equals a row already learned" in err
        assert f"round 1 ('{tmp_path / 'first.parquet'}')" in err
        assert snapshot(root) == before
    # the same rows labelled otherwise are the same data; a sign of zero is not a new value
    relabelled = dict(rows, source=[{"nu": "policy", "policy": "nu"}[s] for s in rows["source"]])
    relabelled["p"] = rows["p"].copy()
    relabelled["p"][0] = -0.0
    with pytest.raises(ValueError, match="every row equals a row already learned"):
        rounds.update(root, write_round(tmp_path / "relabelled.parquet", relabelled))


def test_rows_one_ulp_apart_are_new(started, tmp_path):
    """Equality is exact: every value moved by one unit in the last place makes every row new."""
    root, rows, _ = started
    moved = {k: np.nextafter(v, np.inf) if k != "source" else v for k, v in rows.items()}
    assert rounds.update(root, write_round(tmp_path / "moved.parquet", moved)).round == 3


def test_a_partial_overlap_warns_with_its_fraction(started, tmp_path, capsys):
    """10 of 40 rows repeated from round 1 and 6 from round 2: learned, with a warning giving
    16 of 40 (40 %) and both earlier files; the CLI prints it as one line on stderr."""
    root, rows, rng = started
    second = transitions(rng, 40)
    rounds.update(root, write_round(tmp_path / "second.csv", second))
    third = transitions(rng, 40)
    for k in third:
        third[k] = np.asarray(third[k], dtype=object if k == "source" else float)
        third[k][:10] = np.asarray(rows[k], dtype=third[k].dtype)[5:15]
        third[k][10:16] = np.asarray(second[k], dtype=third[k].dtype)[:6]
    third["source"] = third["source"].tolist()
    path = write_round(tmp_path / "third.parquet", third)
    shutil.copy(path, tmp_path / "third-cli.parquet")
    with pytest.warns(checks.RoundWarning) as said:
        assert rounds.update(root, path).round == 4
    (message,) = [str(w.message) for w in said]
    assert "16 of 40 rows (40 %) equal rows already learned" in message
    assert f"round 1 ('{tmp_path / 'first.parquet'}'), round 2 ('{tmp_path / 'second.csv'}')" in (
        message
    )
    # the CLI on a fresh copy of the directory before the third update: one warning line
    cli_root = tmp_path / "cli"
    rounds.init(cli_root, write_config(tmp_path / "c2.toml"))
    rounds.update(cli_root, tmp_path / "first.parquet")
    rounds.update(cli_root, tmp_path / "second.csv")
    code = _cli_update(capsys, cli_root, tmp_path / "third-cli.parquet")
    err = capsys.readouterr().err
    assert code == 0
    warned = [line for line in err.splitlines() if line.startswith("loopid: warning: ")]
    assert len(warned) == 1 and "16 of 40 rows (40 %)" in warned[0], err


def _cli_update(capsys, *args) -> int:
    from loopid import cli

    try:
        cli.main(["round", "update", *(str(a) for a in args)])
    except SystemExit as done:
        return done.code
    return 0


def _split(rng, samples: int, policy: int) -> dict:
    rows = transitions(rng, samples)
    rows["source"] = ["policy"] * policy + ["nu"] * (samples - policy)
    return rows


def test_a_split_far_from_the_plan_is_refused_unless_accepted(tmp_path, capsys):
    """Plan 100/100 (DAgger's ½ of 200): 150/50 lies outside the 99.9 % binomial interval
    [77, 123] and is refused with one line; --accept-split learns from it. The interval's ends
    are inside, one row beyond them is not."""
    rng = np.random.default_rng(4)
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml", samples=200))
    lo, hi = checks.interval(200, 0.5)
    assert (lo, hi) == (77, 123)
    # the interval's definition: at most 0.05 % of the binomial's mass on either side of it
    assert binom.cdf(lo - 1, 200, 0.5) <= 0.0005 < binom.cdf(lo, 200, 0.5)
    assert binom.sf(hi, 200, 0.5) <= 0.0005 < binom.sf(hi - 1, 200, 0.5)
    before = snapshot(root)
    for policy in (150, hi + 1, lo - 1):
        path = write_round(tmp_path / f"split-{policy}.parquet", _split(rng, 200, policy))
        code, err = loopid(capsys, "round", "update", root, path)
        assert code == 2 and err.count("\n") == 1, err
        assert (
            f"{policy} policy rows and {200 - policy} nu rows, against a plan of 100 and 100"
            in (err)
        )
        assert "99.9 % of rounds drawn as planned have 77 to 123 policy rows" in err
        assert "--accept-split" in err
    assert snapshot(root) == before
    with pytest.raises(ValueError, match="150 policy rows and 50 nu rows"):
        rounds.update(root, tmp_path / "split-150.parquet")
    assert _cli_update(capsys, root, tmp_path / "split-150.parquet", "--accept-split") == 0
    capsys.readouterr()
    assert (
        rounds.update(root, write_round(tmp_path / "hi.parquet", _split(rng, 200, hi))).round == 3
    )
    assert (
        rounds.update(root, write_round(tmp_path / "lo.parquet", _split(rng, 200, lo))).round == 4
    )
    done = rounds.update(root, tmp_path / "split-124.parquet", accept_split=True)
    assert done.round == 5 and done.row["rows_policy"] == 124


def test_batch_plans_no_policy_rows(tmp_path):
    """Batch's plan is all ν (p = 0): the interval is [0, 0], and one policy row is refused."""
    rng = np.random.default_rng(6)
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml", rounds='method = "batch"'))
    assert checks.interval(40, 0.0) == (0, 0)
    with pytest.raises(
        ValueError, match="1 policy rows and 39 nu rows, against a plan of 0 and 40"
    ):
        rounds.update(root, write_round(tmp_path / "one.parquet", _split(rng, 40, 1)))
    assert rounds.update(root, write_round(tmp_path / "nu.parquet", _split(rng, 40, 0))).round == 2


def test_a_committed_copy_is_read_without_its_episode_columns(started, tmp_path):
    """A directory whose committed copy holds an ``episode`` column with an empty value and a
    ``terminated`` column of words (a version that ignored those columns took it) still learns
    the next file; the new file's own columns are still checked."""
    root, _, rng = started
    copy = root / "data" / "round-001.parquet"
    table = pq.read_table(copy)
    labels = pa.array([None] + ["e1"] * (table.num_rows - 1), pa.string())
    table = table.append_column("episode", labels)
    table = table.append_column("terminated", pa.array(["no"] * table.num_rows))
    pq.write_table(table, copy)
    with pytest.raises(ValueError, match="column 'episode' has 1 empty value"):
        rounds.update(root, write_round(tmp_path / "bad.parquet", dict(
            transitions(rng, 40), episode=labels.to_pylist())))  # fmt: skip
    assert rounds.update(root, write_round(tmp_path / "next.parquet", transitions(rng, 40)))
