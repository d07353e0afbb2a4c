"""Scenarios as TOML files shipped in the package; a user's --config is validated."""

import dataclasses
import re
import tomllib
from importlib import resources

import pytest

from loopid.experiments.families.helicopter.scenario import (
    FIELDS,
    SCENARIOS,
    Scenario,
    from_dict,
    read_config,
    scenario,
)
from loopid.settings import model_planner


def packaged(name: str) -> dict:
    folder = resources.files("loopid.experiments.families.helicopter") / "scenarios"
    return tomllib.loads((folder / f"{name}.toml").read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", ["hover", "hover-delay", "funnel"])
def test_packaged_files_spell_out_every_choice(name):
    d = packaged(name)
    # None: the task's own (TOML has no null); the model and planner: the paper's when unset
    optional = {"noise_std", "delay", *model_planner.FIELDS}
    assert set(d) == set(FIELDS) - optional
    assert SCENARIOS[name] == from_dict(d)
    assert SCENARIOS[name].to_dict() == d  # what config.toml records


def test_protocol_of_spec_4_4():
    got = {n: (s.task, s.iterations, s.samples, s.seeds) for n, s in SCENARIOS.items()}
    assert got == {
        "hover": ("hover", 50, 100, 20),
        "hover-delay": ("hover-delay", 100, 100, 20),
        "funnel": ("funnel", 100, 500, 20),
    }
    for s in SCENARIOS.values():
        assert (s.stop_norm, s.nu_state_var, s.nu_action_var, s.expert_action_var) == (
            5.0, 0.0025, 0.0001, 0.0001,
        )  # fmt: skip
        assert (s.ftrl_lambda, s.cost_cap, s.test_trajectories) == (1e-3, 1e8, 100)


def test_dataclass_defaults_agree_with_the_files():
    """Scenario(...) built in Python gets the same choices as the shipped files."""
    for s in SCENARIOS.values():
        assert Scenario(s.name, s.task, s.iterations, s.samples) == s


def test_read_config(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('iterations = 7\nnu_state_var = 0.01\nmethods = ["dagger-t", "expert"]\n')
    fields, methods = read_config(f)
    assert fields == {"iterations": 7, "nu_state_var": 0.01}
    assert methods == ["dagger-t", "expert"]
    s = scenario("hover", **fields)
    assert (s.iterations, s.nu_state_var, s.samples) == (7, 0.01, 100)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("iteratons = 3\n", "unknown key(s) iteratons"),
        ("[scenario]\niterations = 3\n", "unknown key(s) scenario"),
        ("methods = 3\n", "methods must be a list"),
        ("iterations = \n", "not valid TOML"),
    ],
)
def test_read_config_rejects(tmp_path, text, needle):
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(ValueError, match=r"c\.toml") as e:
        read_config(f)
    assert needle in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"iterations": "ten"}, "iterations must be an integer"),
        ({"iterations": 2.5}, "iterations must be an integer"),
        ({"seeds": -1}, "seeds must be an integer >= 1, got -1"),
        ({"pads": 1}, "pads must be true or false"),
        ({"name": "Hover Two"}, "name must be"),
        ({"task": "loop"}, "task must be one of"),
        ({"gamma": 1.0}, "gamma must be"),
        ({"sampling": "first"}, "sampling must be one of"),
        ({"nu_pending": "drop"}, "nu_pending must be one of hold, zero, rollout, got 'drop'"),
        ({"delay_mode": "lag"}, "delay_mode must be one of fifo, latency, got 'lag'"),
        (
            {"delay_mode": "latency", "nu_pending": "zero"},
            "nu_pending applies to delay_mode 'fifo' only",
        ),
        (
            {"funnel_nominal": "exact"},
            "funnel_nominal must be one of spec, no-increment, drift, heading, got 'exact'",
        ),
        ({"pg_samples": "episodes"}, "pg_samples must be one of transitions, rollouts"),
        ({"pg_update": "bold"}, "pg_update must be one of conservative, descent, got 'bold'"),
        ({"cost_cap": float("nan")}, "cost_cap must be"),
        ({"colour": "red"}, "unknown scenario field"),
    ],
)
def test_bad_values_name_the_field(change, needle):
    with pytest.raises(ValueError, match=re.escape(needle)):
        scenario("hover", **change)


def test_scenario_is_frozen_and_hashable():
    s = SCENARIOS["hover"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.iterations = 3  # type: ignore[misc]
    assert hash(s) == hash(s.replace())
