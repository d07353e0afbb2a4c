"""The ``loopid`` command line, as a user runs it: files, schema, resume, Ray, one-line errors.

The slow tests share one JAX compilation cache (``cache``), so only the first compiles.
"""

import re
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

import loopid
from conftest import cell_mtimes, cli
from loopid.algorithms.methods import METHODS
from loopid.cli import main
from loopid.experiments.results import SCHEMA
from loopid.experiments.scenarios import SCENARIOS

PINNED = Path(__file__).parent / "fixtures" / "reproduce_quick_literal.parquet"


def test_version(tmp_path):
    r = cli("--version", cache=tmp_path)
    assert r.returncode == 0
    assert r.stdout.strip() == f"loopid {loopid.__version__}"


# ---- bad input: exit 2, one line naming the value, no traceback, nothing written --------------


@pytest.fixture
def no_cache(monkeypatch):
    """Run ``main`` in this process without touching JAX's global compilation-cache setting."""
    import loopid.experiments.executors as executors

    monkeypatch.setattr(executors, "compile_cache", lambda path=None: "")


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


BAD = [
    (["run", "nope"], "'nope'"),
    (["run", "hover", "--methods", "dagger-t,foo"], "'foo'"),
    (["run", "hover", "--seeds", "-1"], "-1"),
    (["run", "hover", "--seeds", "abc"], "--seeds"),
    (["run", "hover", "--iterations", "ten"], "--iterations"),
    (["run", "hover", "--samples", "0"], "samples"),
    (["run", "hover", "--executor", "dask"], "'dask'"),
    (["run", "hover", "--ray-address", "auto"], "--ray-address"),
    (["run", "hover", "--executor", "ray", "--ray-address", "127.0.0.1:1"], "cannot connect"),
    (["run", "hover", "--executor", "ray", "--ray-address", "nowhere"], "'nowhere'"),
    (["run", "hover", "--config", "{dir}/missing.toml"], "missing.toml"),
    (["run", "hover", "--config", "{unknown}"], "iteratons"),
    (["run", "hover", "--config", "{badvalue}"], "iterations"),
    (["run", "hover", "--config", "{badtask}"], "task"),
    (["run", "hover", "--config", "{badmethods}"], "methods"),
    (["run", "hover", "--config", "{badmethod}"], "'dagger-x'"),
    (["run", "hover", "--config", "{nottoml}"], "TOML"),
    (["run", "mdp-trap", "--methods", "dagger-t"], "'dagger-t'"),
    (["run", "mdp-trap", "--test-trajectories", "3"], "--test-trajectories"),
    (["run", "gym"], "--config"),
    (["run", "gym", "--config", "{unknown}", "--seeds", "3"], "iteratons"),
    (["run", "hover", "--set", "colour=red"], "colour"),
    (["run", "hover", "--set", "iterations"], "key=value"),
    (["run", "hover", "--set", "delay_mode=delayed"], "delay_mode must be one of fifo, latency"),
    (["run", "mdp-trap", "--set", "nu=everywhere"], "'everywhere'"),
    (["reproduce", "--bogus"], "--bogus"),
    (["reproduce", "--seeds", "0"], "seeds"),
    (["reproduce", "--executor", "spark"], "'spark'"),
    (["reproduce", "--workers", "0"], "--workers"),
    (["run", "hover", "--workers", "2", "--executor", "ray"], "--workers"),
    (["run", "hover-delay", "--config", "{badreading}"], "delay_mode must be one of fifo, latency"),
    (["study", "--seeds", "0"], "seeds"),
    (["study", "--reproduce", "{dir}/nowhere"], "--reproduce"),
    (["plot", "{dir}"], "results.parquet"),
    (["plot", "{corrupt}"], "not a readable Parquet table"),
]


@pytest.mark.parametrize(("args", "needle"), BAD)
def test_bad_input_exits_2_with_one_line(args, needle, tmp_path, no_cache, capsys):
    files = {
        "dir": tmp_path,
        "unknown": write(tmp_path / "u.toml", "iteratons = 3\n"),
        "badvalue": write(tmp_path / "v.toml", 'iterations = "ten"\n'),
        "badtask": write(tmp_path / "t.toml", 'task = "loop-the-loop"\n'),
        "badmethods": write(tmp_path / "m.toml", 'methods = "dagger-t"\n'),
        "badmethod": write(tmp_path / "n.toml", 'methods = ["dagger-x"]\n'),
        "nottoml": write(tmp_path / "x.toml", "iterations = = 3\n"),
        "badreading": write(tmp_path / "r.toml", 'delay_mode = "delayed"\n'),
        "corrupt": tmp_path / "c",
    }
    (tmp_path / "c").mkdir()
    write(tmp_path / "c" / "results.parquet", "not parquet")
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "out"
    args = [a.format(**files) for a in args]
    extra = ["--out", str(out)] if args[0] in ("run", "reproduce", "study") else []
    with pytest.raises(SystemExit) as e:
        main([*args, *extra])
    assert e.value.code == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("loopid: error:") and needle in lines[0], err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_bad_input_from_the_console_script(tmp_path):
    """The same through a real process: one line on stderr, exit 2, no traceback."""
    r = cli("run", "hover", "--seeds", "-1", "--out", tmp_path / "o", cache=tmp_path)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["loopid: error: seeds must be an integer >= 1, got -1"]
    assert not (tmp_path / "o").exists()


# ---- end to end (slow) --------------------------------------------------------------------


@pytest.fixture(scope="session")
def quick(tmp_path_factory, cache) -> Path:
    """``loopid reproduce --quick`` into a fresh directory (fills the shared cache).

    The end-to-end runs of this file use one worker process: they are compile-bound, and on
    two cores two workers each start JAX and compile what they meet (neither has stored it in
    the cache yet) for no gain in wall time
    (``reproduce --quick`` cold, measured: 76 s and 108 CPU-s with one worker, 85 s and 149
    CPU-s with two). Worker processes have their own tests (``test_cli_executors.py``)."""
    out = tmp_path_factory.mktemp("quick") / "run"
    r = cli("reproduce", "--quick", "--workers", "1", "--out", out, cache=cache)
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.slow
def test_reproduce_quick_adds_the_finite_mdp_study(quick):
    """The extra figure: DAgger, Batch and Abbeel on the finite MDPs, exact J and the bound."""
    mdp = quick / "mdp"
    assert {p.name for p in mdp.iterdir()} >= {"config.toml", "results.parquet", "figure.png"}
    cols = pq.read_table(mdp / "results.parquet").to_pydict()
    assert set(zip(cols["scenario"], cols["method"], strict=True)) == {
        (s, m) for s in ("mdp-random", "mdp-trap") for m in ("dagger", "batch", "abbeel")
    }
    assert np.all(np.asarray(cols["j_best"]) <= np.asarray(cols["bound"]))
    assert "j_best ≤ bound" in (mdp / "report.md").read_text()


@pytest.mark.slow
def test_reproduce_quick_writes_the_four_files(quick):
    assert {p.name for p in quick.iterdir()} >= {
        "config.toml",
        "results.parquet",
        "figure.png",
        "report.md",
    }
    table = pq.read_table(quick / "results.parquet")
    assert table.schema.names[: len(SCHEMA)] == SCHEMA.names
    assert table.schema.remove_metadata().equals(SCHEMA) or all(
        table.schema.field(f.name).type == f.type for f in SCHEMA
    )
    cols = table.to_pydict()
    cells = set(zip(cols["scenario"], cols["method"], strict=True))
    assert cells == {(s, m) for s in SCENARIOS for m in METHODS}
    # 2 seeds x 4 iterations per cell, each (cell, seed, iteration) once
    keys = list(zip(cols["scenario"], cols["method"], cols["seed"], cols["iteration"], strict=True))
    assert len(keys) == len(set(keys)) == len(cells) * 2 * 4
    for f in SCHEMA:
        if f.type == "double":
            assert not np.isnan(np.asarray(cols[f.name], dtype=float)).any(), f.name
    assert (quick / "figure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (quick / "report.md").read_text()
    for n in range(1, 6):
        assert f"\n{n}. **" in report
    assert "Wall time" in report and "this command:" in report


@pytest.mark.slow
def test_study_quick_writes_every_file_and_covers_every_reading(tmp_path, cache, quick):
    """``loopid study --quick``, sharing the default reading's cells with a reproduce run."""
    from loopid.experiments.study import FIGURES, READING_FIELDS, READINGS

    before = cell_mtimes(quick)
    out = tmp_path / "study"
    r = cli(
        "study", "--quick", "--quiet", "--workers", "1", "--out", out, "--reproduce", quick,
        cache=cache,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert cell_mtimes(quick) == before  # the reproduce run's cells were reused, not redone
    names = {p.name for p in out.iterdir()}
    files = {"study.md", "study.parquet", "results.parquet", "config.toml"}
    assert {*files, *(f"study_{f}.png" for f in FIGURES)} <= names
    shared = {p.name for p in (quick / "cells").iterdir()}  # rows, saved policies and models
    copied = {p.name for p in (out / "cells").iterdir()}
    assert shared <= copied  # every cell of the default reading came from the reproduce run
    for name in shared:
        a, b = (quick / "cells" / name).read_bytes(), (out / "cells" / name).read_bytes()
        assert a == b
    table = pq.read_table(out / "study.parquet")
    cols = table.to_pydict()
    assert set(cols["reading"]) == {rd.id for rd in READINGS}
    for rd in READINGS:  # every (panel, method) of every reading, 2 seeds x 4 iterations
        rows = [i for i, x in enumerate(cols["reading"]) if x == rd.id]
        cells = {(cols["scenario"][i], cols["method"][i]) for i in rows}
        assert cells == {(p, m) for p in rd.panels for m in METHODS}, rd.id
        assert len(rows) == len(cells) * 2 * 4
        for field, value in rd.changes.items():  # the reading is in the columns
            text = str(value).lower() if isinstance(value, bool) else value
            assert {cols[field][i] for i in rows} == {text}, (rd.id, field)
    assert set(READING_FIELDS) <= set(table.column_names)
    for name in table.column_names:
        if pa_is_float(table.schema.field(name).type):
            assert not np.isnan(np.asarray(cols[name], dtype=float)).any(), name
    text = (out / "study.md").read_text()
    for rd in READINGS:
        assert f"### {rd.id}:" in text
    assert text.count("**holds**") + text.count("**does not hold**") >= 5 * len(READINGS) - 5
    assert not re.search(r"\bnan\b", text, re.IGNORECASE)
    for f in FIGURES:
        assert (out / f"study_{f}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_reproduce_quick_literal_equals_the_table_before_the_defaults_changed(tmp_path, cache):
    """``reproduce --quick --readings literal`` gives ``tests/fixtures/
    reproduce_quick_literal.parquet``, the table computed before the default readings changed,
    when the literal readings were the defaults. After the study in this file, whose one-factor
    readings compiled most of its programs.

    Every row, and every count, divergence and solver verdict in it, is the pinned one; every
    float agrees to 1e-10 relative. On the CPU that pinned the table it was bit for bit but for
    the hover panels' policy gradient (1e-12: its rollouts' sums now run in another order). XLA
    compiles for the CPU's own vector instructions, so another CPU rounds differently: on an AMD
    EPYC with AVX2 and no AVX-512, 13 test costs differ by up to 2.4e-14 relative and the
    funnel's losses by up to 1.1e-12. A changed reading or a wrong loop moves them by far more.
    The same table bit for bit, on one machine, across executors and chunkings, is checked in
    ``test_cli_executors.py`` and ``tests/experiments/test_chunks.py``."""
    out = tmp_path / "literal"
    r = cli(
        "reproduce", "--quick", "--readings", "literal", "--quiet", "--workers", "1",
        "--out", out, cache=cache,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    ours = pq.read_table(out / "results.parquet")
    pinned = pq.read_table(PINNED)
    assert ours.num_rows == pinned.num_rows == 216
    assert ours.schema.equals(pinned.schema)
    for column in ours.column_names:
        a, b = ours[column].to_numpy(), pinned[column].to_numpy()
        if pa_is_float(ours.schema.field(column).type):
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=0, equal_nan=True, err_msg=column)
        else:
            np.testing.assert_array_equal(a, b, err_msg=column)
    report = (out / "report.md").read_text()
    assert "Readings: literal (delay_mode = fifo" in report


def pa_is_float(t) -> bool:
    import pyarrow as pa

    return pa.types.is_floating(t)
