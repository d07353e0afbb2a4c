"""The ``loopid`` command line, as a user runs it: files, schema, resume, Ray, one-line errors.

The slow tests share one JAX compilation cache (``cache``), so only the first compiles.
"""

import re
import tomllib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import loopid
from conftest import cell_mtimes, cli
from loopid.cli import main
from loopid.experiments.families.helicopter.methods import METHODS
from loopid.experiments.families.helicopter.scenario import SCENARIOS
from loopid.experiments.results import SCHEMA
from pinned import assert_matches_pin, keys

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
def quick_cache(tmp_path_factory) -> Path:
    """The compilation cache :func:`quick` alone fills (what --quick compiled)."""
    return tmp_path_factory.mktemp("quick-cache")


@pytest.fixture(scope="session")
def quick(tmp_path_factory, quick_cache) -> Path:
    """``loopid reproduce --quick`` into a fresh directory (fills the shared cache).

    The end-to-end runs of this file use one worker process: they are compile-bound, and on
    two cores two workers each start JAX and compile what they meet (neither has stored it in
    the cache yet) for no gain in wall time
    (``reproduce --quick`` cold, measured: 76 s and 108 CPU-s with one worker, 85 s and 149
    CPU-s with two). Worker processes have their own tests (``test_cli_executors.py``)."""
    out = tmp_path_factory.mktemp("quick") / "run"
    r = cli("reproduce", "--quick", "--workers", "1", "--out", out, cache=quick_cache)
    assert r.returncode == 0, r.stderr
    return out


def step_programs(cache: Path) -> set[str]:
    """The ``step`` programs (one iteration of the loop) in the compilation cache ``cache``."""
    return {p.name for p in cache.iterdir() if p.name.startswith("jit_step-")}


@pytest.mark.slow
def test_a_run_after_quick_compiles_no_new_step_program(quick, quick_cache, tmp_path):
    """Programs do not depend on the seed or iteration count a command asks for: after
    ``reproduce --quick`` (2 seeds, 4 iterations), ``loopid run hover --seeds 5 --iterations
    6`` at --quick's 10 test trajectories runs the same padded lane width and finds its
    ``step`` program in the cache --quick left (before a fixed lane width it compiled one for 5
    seeds)."""
    before = step_programs(quick_cache)
    assert before  # --quick compiled its panels' programs into this cache
    r = cli("run", "hover", "--seeds", "5", "--iterations", "6", "--test-trajectories", "10",
            "--workers", "1", "--quiet", "--out", tmp_path / "run", cache=quick_cache)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert step_programs(quick_cache) == before
    rows = pq.read_table(tmp_path / "run" / "results.parquet").to_pydict()
    assert len(rows["seed"]) == 9 * 5 * 6  # every method, seed and iteration ran


@pytest.mark.slow
def test_the_funnel_still_flies_the_policy_gradient_one_flag_away(tmp_path, quick_cache):
    """``loopid reproduce`` leaves the policy gradient out of the funnel's panel; ``loopid run
    funnel --methods pg`` still runs it, every seed and iteration, with finite losses."""
    out = tmp_path / "pg"
    r = cli("run", "funnel", "--methods", "pg", "--seeds", "2", "--iterations", "2",
            "--workers", "1", "--quiet", "--out", out, cache=quick_cache)  # fmt: skip
    assert r.returncode == 0, r.stderr
    cols = pq.read_table(out / "results.parquet").to_pydict()
    assert set(zip(cols["scenario"], cols["method"], strict=True)) == {("funnel", "pg")}
    assert sorted(zip(cols["seed"], cols["iteration"], strict=True)) == [
        (0, 1), (0, 2), (1, 1), (1, 2)
    ]  # fmt: skip
    assert all(c > 0 for c in cols["test_cost"])


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
    # every method of Figure 2 on every panel; the policy gradient on the hover panels only
    assert cells == {(s, m) for s in SCENARIOS for m in METHODS if m != "pg" or s != "funnel"}
    assert ("hover", "pg") in cells and ("hover-delay", "pg") in cells
    methods = tomllib.loads((quick / "config.toml").read_text())["run"]["methods"]
    assert "pg" not in methods["funnel"]
    assert "pg" in methods["hover"] and "pg" in methods["hover-delay"]
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


@pytest.mark.science
def test_study_quick_writes_every_file_and_covers_every_reading(tmp_path, cache, quick):
    """``loopid study --quick``, sharing the default reading's cells with a reproduce run."""
    from loopid.paper.study import FIGURES, READING_FIELDS, READINGS

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
    assert sum(text.count(f"**{v}**") for v in ("holds", "holds with ties", "does not hold", "tie",
               "too few seeds")) >= 5 * len(READINGS) - 2 * sum(  # 3 and 5 in hover only
                   rd.panels == ("funnel",) for rd in READINGS)  # fmt: skip
    assert not re.search(r"\bnan\b", text, re.IGNORECASE)
    for f in FIGURES:
        assert (out / f"study_{f}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_reproduce_quick_literal_equals_the_table_before_the_defaults_changed(tmp_path, cache):
    """``reproduce --quick --readings literal`` gives ``tests/fixtures/
    reproduce_quick_literal.parquet``, the table computed before the default readings changed,
    when the literal readings were the defaults, to the last bits that another CPU reproduces.

    The rule (:func:`pinned.assert_matches_pin`, whose module gives the measurements):

    - every row in the pinned order; its ``scenario, method, seed, iteration, samples`` exactly;
    - *settled* rows (test cost at most 10 × L, L the expert's on that scenario and seed, and no
      diverged test trajectory, here and in the pin alike): every float to 1e-10 relative, every
      int and bool exactly. Converged policies sit at 1-4 × L (the experts, and one DAgger-ν_e
      row at 3.7 × L); the one row without a diverged trajectory that moved across instruction
      sets is at 1.8e6, 2.9e4 × L: a policy that has not settled, where chaos amplifies rounding;
    - other rows: ``diverged`` within ±1; ``test_cost`` and ``test_cost_median`` not compared
      (rounding moves a diverging trajectory's cost by up to 14 %, and the median by 16 %,
      between instruction sets); the training side (losses, spectral radius) to 1e-6, since
      the models are fit to batches flown by diverging policies too, and moved by up to 1.9e-9;
      ``policy_samples``, ``valid_samples`` and ``solver_converged`` exactly (never moved);
    - columns that results gained after the pin are not compared; the pinned ones keep types.

    The rule is the same on every architecture (``platform.machine()``: x86_64 with AVX-512,
    AVX2 or fewer instructions, arm64/aarch64): settled rows to 1e-10, only unsettled ones move.
    On the CPU that pinned the table it was bit for bit but for 1e-12 in the hover panels'
    policy gradient; the ``probable`` readings move 220 losses by 7e-5 to order one and 61
    ``diverged`` counts by two or more. The same table bit for bit, on one machine, across
    executors and chunkings, is checked in ``test_cli_executors.py`` and
    ``tests/experiments/test_chunks.py``. The pin lost its funnel policy-gradient rows (8 of
    216) when ``loopid reproduce`` stopped flying the policy gradient on the funnel; every other
    row is as it was computed."""
    out = tmp_path / "literal"
    r = cli(
        "reproduce", "--quick", "--readings", "literal", "--quiet", "--workers", "1",
        "--out", out, cache=cache,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    pinned = pq.read_table(PINNED)
    assert pinned.num_rows == 208  # 216 before the policy gradient left the funnel's panel
    assert_matches_pin(pq.read_table(out / "results.parquet"), pinned, rtol=1e-10)
    report = (out / "report.md").read_text()
    assert "Readings: literal (delay_mode = fifo" in report


def _set(table: pa.Table, column: str, row: int, value) -> pa.Table:
    """``table`` with ``column`` at ``row`` set to ``value``."""
    j = table.column_names.index(column)
    values = table[column].to_pylist()
    values[row] = value
    return table.set_column(j, table.schema.field(j), pa.array(values, table.schema.field(j).type))


def _row(table: pa.Table, scenario: str, method: str, seed: int, iteration: int) -> int:
    """The index of the row with that identity."""
    rows = keys(table, ("scenario", "method", "seed", "iteration"))
    return rows.index((scenario, method, seed, iteration))


def _scaled(column: str, factor: float, *row):
    return lambda t: _set(t, column, _row(t, *row), t[column][_row(t, *row)].as_py() * factor)


def _shifted(column: str, by: int, *row):
    return lambda t: _set(t, column, _row(t, *row), t[column][_row(t, *row)].as_py() + by)


def _both(*changes):
    def change(t):
        for c in changes:
            t = c(t)
        return t

    return change


SETTLED = ("hover", "dagger-e", 1, 4)  # 183, 3.7 × L, no diverged trajectory
EXPERT = ("hover-delay", "expert", 1, 2)  # L itself
DIVERGING = ("hover", "batch-en", 0, 2)  # 2 diverged; 3 on another instruction set
UNSETTLED = ("hover-delay", "dagger-en", 1, 3)  # 1.8e6, none diverged; moved by 2.5e-8

#: Changes that another CPU's rounding makes, or that are not the pin's business: they pass.
ROUNDING = {
    "itself": lambda t: t,
    "a diverging row's cost by 14 pct, median by 16 pct, count by one": _both(
        _scaled("test_cost", 1.14, *DIVERGING),
        _scaled("test_cost_median", 1.16, *DIVERGING),
        _shifted("diverged", 1, *DIVERGING),
    ),
    "a count one fewer": _shifted("diverged", -1, *DIVERGING),
    "an unsettled row's cost by 3e-8": _scaled("test_cost", 1 + 3e-8, *UNSETTLED),
    "an unsettled row's loss by 2e-9": _scaled("loss_policy", 1 + 2e-9, *DIVERGING),
    "a settled row's cost by 1e-11": _scaled("test_cost", 1 + 1e-11, *SETTLED),
    "a column added": lambda t: t.append_column("new", pa.array([1.0] * t.num_rows)),
}

#: Changes that no rounding makes: they fail, naming what moved.
CHANGES = {
    "a settled row's cost by 1e-8": (_scaled("test_cost", 1 + 1e-8, *SETTLED), "test_cost"),
    "an expert's cost by 1e-8": (_scaled("test_cost", 1 + 1e-8, *EXPERT), "test_cost"),
    "a settled row's loss by 1e-8": (_scaled("loss_nu", 1 + 1e-8, *SETTLED), "loss_nu"),
    "a settled row's spectral radius by 1e-8": (
        _scaled("spectral_radius", 1 + 1e-8, *SETTLED),
        "spectral_radius",
    ),
    "a settled row diverging": (_shifted("diverged", 1, *SETTLED), ": settled in the pin"),
    "a settled row at 112 times L": (_scaled("test_cost", 30.0, *SETTLED), ": settled in the pin"),
    "an unsettled row settling": (
        lambda t: _set(t, "test_cost", _row(t, *UNSETTLED), 60.0),
        ": unsettled in the pin",
    ),
    "a count two more": (_shifted("diverged", 2, *DIVERGING), "diverged"),
    "a count two fewer": (_shifted("diverged", -2, *DIVERGING), "diverged"),
    "an unsettled row's loss by 1e-5": (_scaled("online_loss", 1 + 1e-5, *DIVERGING), "online"),
    "an unsettled row's policy draws": (_shifted("policy_samples", 1, *DIVERGING), "policy_s"),
    "a solver verdict": (
        lambda t: _set(t, "solver_converged", _row(t, *DIVERGING), False),
        "solver_converged",
    ),
    "a row missing": (lambda t: t.slice(1), "missing"),
    "rows in another order": (lambda t: pa.concat_tables([t.slice(1), t.slice(0, 1)]), "differs"),
    "a pinned column missing": (lambda t: t.drop_columns(["valid_samples"]), "valid_samples"),
    "a pinned column of another type": (
        lambda t: t.set_column(7, "diverged", t["diverged"].cast(pa.int32())),
        "another type",
    ),
}


@pytest.mark.parametrize("change", ROUNDING.values(), ids=ROUNDING.keys())
def test_the_pin_holds_through_rounding(change):
    """:func:`pinned.assert_matches_pin` passes what another CPU's rounding moves (no JAX run)."""
    pinned = pq.read_table(PINNED)
    assert_matches_pin(change(pinned), pinned)


@pytest.mark.parametrize(("change", "needle"), CHANGES.values(), ids=CHANGES.keys())
def test_the_pin_catches_what_rounding_does_not_move(change, needle):
    """:func:`pinned.assert_matches_pin` fails, naming the column or row, on what no rounding
    moves: a settled row by 1e-8, an unsettled row's count by two, a row or a column missing."""
    pinned = pq.read_table(PINNED)
    with pytest.raises(AssertionError, match=needle):
        assert_matches_pin(change(pinned), pinned)


def pa_is_float(t) -> bool:
    import pyarrow as pa

    return pa.types.is_floating(t)
