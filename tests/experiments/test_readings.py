"""The readings presets: the defaults, ``--readings``, its order against ``--config`` and
``--set``, and run directories made under other readings. (The literal preset end to end,
against the table pinned before the defaults changed, is in ``tests/test_cli.py``: it runs
after the study there, whose compiled programs it reuses.)
"""

import dataclasses
import re

import pytest

from loopid.cli import main, scenario_from_options
from loopid.experiments.execute import resolved_config
from loopid.experiments.families.helicopter.readings import (
    PRESETS,
    READING_FIELDS,
    continue_hint,
    preset,
    preset_of,
    readings_of,
)
from loopid.experiments.families.helicopter.scenario import SCENARIOS, Scenario
from loopid.experiments.rundir import RunDir

QUICK = {"iterations": 4, "test_trajectories": 10, "seeds": 2}


def test_presets_set_every_reading_field_and_differ_where_documented():
    for p in PRESETS.values():
        assert set(p) == set(READING_FIELDS)
    differ = {k for k in READING_FIELDS if PRESETS["probable"][k] != PRESETS["literal"][k]}
    assert differ == {"delay_mode", "funnel_nominal", "pg_samples", "pg_update", "nu_t_center"}
    assert PRESETS["literal"] == {
        "delay_mode": "fifo", "nu_pending": "hold", "funnel_nominal": "spec", "pads": True,
        "pg_samples": "transitions", "pg_update": "conservative", "nu_t_center": "target",
    }  # fmt: skip
    assert PRESETS["probable"]["pg_update"] == "descent"
    assert PRESETS["probable"]["nu_t_center"] == "nominal"


def test_the_packaged_scenarios_and_the_dataclass_carry_the_probable_readings():
    for s in SCENARIOS.values():
        assert {k: getattr(s, k) for k in READING_FIELDS} == PRESETS["probable"], s.name
        assert preset_of(s.to_dict()) == "probable"
    defaults = {f.name: f.default for f in dataclasses.fields(Scenario)}
    assert {k: defaults[k] for k in READING_FIELDS} == PRESETS["probable"]
    assert SCENARIOS["hover-delay"].delay_mode == "latency"
    assert SCENARIOS["funnel"].funnel_nominal == "heading"
    assert SCENARIOS["hover"].pg_samples == "rollouts"
    assert SCENARIOS["funnel"].nu_t_center == "nominal"


def test_unknown_preset_is_one_line_listing_the_presets():
    with pytest.raises(ValueError, match="presets: probable, literal") as e:
        preset("lit")
    assert "'lit'" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "args",
    [
        ["run", "hover", "--readings", "lit"],
        ["reproduce", "--readings", "paper"],
        ["reproduce", "--quick", "--readings", ""],
    ],
)
def test_unknown_preset_exits_2_with_one_line(args, tmp_path, capsys, monkeypatch):
    import loopid.experiments.executors as executors

    monkeypatch.setattr(executors, "compile_cache", lambda path=None: "")
    with pytest.raises(SystemExit) as e:
        main([*args, "--out", str(tmp_path / "out")])
    assert e.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "presets: probable, literal" in lines[0], lines
    assert not (tmp_path / "out").exists()


def test_readings_on_a_family_without_readings_is_refused():
    message = "mdp-trap (mdp family) has no presets; the scenarios of helicopter have"
    with pytest.raises(ValueError, match=re.escape(message)):
        scenario_from_options("mdp-trap", None, {}, [], "literal")


def test_preset_order_config_then_readings_then_set(tmp_path):
    """--readings overrides --config; --set overrides --readings; options override all."""
    _, s, _ = scenario_from_options("funnel", None, {}, [], "literal")
    assert {k: getattr(s, k) for k in READING_FIELDS} == PRESETS["literal"]
    _, s, _ = scenario_from_options("funnel", None, {}, ["delay_mode=latency"], "literal")
    assert (s.delay_mode, s.funnel_nominal, s.pg_samples) == ("latency", "spec", "transitions")
    config = tmp_path / "c.toml"
    config.write_text('funnel_nominal = "drift"\npg_samples = "transitions"\n')
    _, s, _ = scenario_from_options("funnel", config, {}, [], None)
    assert (s.delay_mode, s.funnel_nominal, s.pg_samples) == ("latency", "drift", "transitions")
    _, s, _ = scenario_from_options("funnel", config, {}, [], "probable")
    assert (s.funnel_nominal, s.pg_samples) == ("heading", "rollouts")
    _, s, _ = scenario_from_options("funnel", config, {"seeds": 3}, ["pads=false"], "literal")
    assert (s.funnel_nominal, s.pads, s.seeds) == ("spec", False, 3)


def _config(readings: dict | None, *, drop: tuple[str, ...] = (), names=tuple(SCENARIOS)) -> dict:
    scenarios = [SCENARIOS[n].replace(**{**QUICK, **(readings or {})}) for n in names]
    config = resolved_config(scenarios, ["expert"], range(2))
    for table in config["scenario"].values():
        for k in drop:
            del table[k]
    return config


def test_continue_hint_names_the_preset_or_the_fields():
    new = _config(None)
    assert continue_hint(_config(PRESETS["literal"]), new) == "--readings literal"
    assert continue_hint(_config(None), new) is None  # nothing differs in the readings
    odd = _config({"funnel_nominal": "drift"})
    assert continue_hint(odd, new) == "--set funnel_nominal=drift"
    assert continue_hint(_config({"iterations": 5}), new) is None  # not only the readings
    # a config.toml from before the readings were fields: they took the literal values
    old = _config(PRESETS["literal"], drop=READING_FIELDS)
    assert readings_of(old["scenario"]["hover"]) == PRESETS["literal"]
    assert continue_hint(old, new) == "--readings literal"


#: The preset ``probable`` before ν_t's centre and the policy gradient's step were among its
#: readings: a run directory made then recorded these values and no ``nu_t_center``.
OLD_PROBABLE = {**PRESETS["probable"], "pg_update": "conservative", "nu_t_center": "target"}


def test_a_run_made_under_the_older_probable_is_named_by_the_fields_that_continue_it():
    new = _config(None)
    old = _config(OLD_PROBABLE, drop=("nu_t_center",))
    assert readings_of(old["scenario"]["funnel"]) == OLD_PROBABLE
    hint = continue_hint(old, new)
    assert hint == "--set pg_update=conservative --set nu_t_center=target"


@pytest.mark.parametrize("drop", [(), READING_FIELDS])
def test_a_run_made_under_the_literal_readings_is_refused_with_the_flag(
    drop, tmp_path, capsys, monkeypatch
):
    """A run directory from before the defaults changed: exit 2, one line naming
    ``--readings literal``, nothing written; with the flag the same command is accepted."""
    import loopid.experiments.executors as executors

    monkeypatch.setattr(executors, "compile_cache", lambda path=None: "")
    out = tmp_path / "old"
    RunDir(out).prepare(_config(PRESETS["literal"], drop=drop, names=("hover",)))
    before = (out / "config.toml").read_bytes()
    args = ["run", "hover", "--methods", "expert", "--iterations", "4", "--seeds", "2"]
    args += ["--test-trajectories", "10", "--out", str(out), "--workers", "1", "--quiet"]
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "continue it with --readings literal" in lines[0], lines
    assert (out / "config.toml").read_bytes() == before
    assert not any((out / "cells").iterdir())
    # the preset the refusal names is accepted by the directory (prepare, no run)
    _, s, _ = scenario_from_options("hover", None, QUICK, [], "literal")
    RunDir(out).prepare(resolved_config([s], ["expert"], range(2)))


def test_an_older_run_directory_reads_back_with_the_readings_it_ran(tmp_path):
    """``loopid plot``, ``evaluate``, ``animate`` and ``loopid.load`` rebuild a run's scenarios
    from its ``config.toml``: one from before the readings were fields ran the literal ones,
    and one that records them keeps them."""
    from loopid.experiments.execute import run_family
    from loopid.experiments.rundir import to_toml

    old = _config(None, drop=READING_FIELDS, names=("hover-delay",))
    (tmp_path / "config.toml").write_text(to_toml(old))
    _, configs = run_family(tmp_path)
    assert preset_of(dataclasses.asdict(configs["hover-delay"])) == "literal"
    (tmp_path / "config.toml").write_text(to_toml(_config(None, names=("hover-delay",))))
    _, configs = run_family(tmp_path)
    assert preset_of(dataclasses.asdict(configs["hover-delay"])) == "probable"
