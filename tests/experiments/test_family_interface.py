"""The :class:`Family` interface: a subclass that lacks a required part cannot be made, and the
error names the part; optional parts have their defaults; the earlier record form still works,
with a warning, and gives the same family as :class:`FunctionFamily`."""

import pytest

from loopid.experiments.families import Family, FunctionFamily, families
from loopid.experiments.families.base import Family as BaseFamily
from loopid.experiments.families.helicopter.scenario import Scenario


def parts(**changes):
    """The required parts of a family given as functions (the record form)."""
    base = dict(
        name="toy", config=Scenario, methods=("a", "b"),
        build=lambda name, fields: ("built", name, fields),
        read_file=lambda path: ({}, None),
        run=lambda method, config, seeds, progress=None: ("ran", method, progress),
        figure=lambda table, path, configs: None,
        report=lambda table, configs: ["# toy"],
    )  # fmt: skip
    return base | changes


@pytest.mark.parametrize("missing", ["build", "read_file", "run", "figure", "report"])
def test_a_subclass_without_a_required_part_cannot_be_made(missing):
    body = {
        "name": "toy", "config": Scenario, "methods": ("a",),
        "build": lambda self, name, fields: None, "read_file": lambda self, path: ({}, None),
        "run": lambda self, method, config, seeds, progress=None: None,
        "figure": lambda self, table, path, configs: None, "report": lambda self, t, c: [],
    }  # fmt: skip
    del body[missing]
    Toy = type("Toy", (Family,), body)
    with pytest.raises(TypeError, match=missing):
        Toy()


def test_optional_parts_have_their_defaults():
    family = FunctionFamily(**parts())
    assert family.default_methods(None) == ("a", "b")
    assert family.check(None) is None and family.shared(None, "a") == {}
    assert family.lane_sets(None, ["a", "b"]) == [("a",), ("b",)]
    for capability in ("load", "evaluate", "trajectories", "animate", "memory", "run_lanes"):
        assert getattr(family, capability) is None
    assert family.run("a", None, [0], progress="p") == ("ran", "a", "p")
    assert family.build("x", {"k": 1}) == ("built", "x", {"k": 1})


def test_function_family_refuses_an_unknown_part():
    with pytest.raises(TypeError, match="plot"):
        FunctionFamily(**parts(plot=lambda: None))


def test_a_family_is_a_subclass_or_a_function_family_not_a_record():
    """``Family`` is the base class (abstract): parts as keywords make a
    :class:`FunctionFamily`, not a ``Family``."""
    with pytest.raises(TypeError, match="no arguments"):
        Family(**parts())
    with pytest.raises(TypeError, match="abstract"):
        Family()
    assert isinstance(FunctionFamily(**parts()), BaseFamily)


def test_the_shipped_families_are_subclasses_with_their_capabilities():
    offered = {
        name: {c for c in ("load", "evaluate", "trajectories", "animate", "memory", "run_lanes")
               if getattr(family, c) is not None}
        for name, family in families().items()
    }  # fmt: skip
    assert offered["helicopter"] == {
        "load", "evaluate", "trajectories", "animate", "memory", "run_lanes",
    }  # fmt: skip
    assert offered["mdp"] == {"load", "evaluate", "trajectories", "memory"}
    assert offered["gym"] == {"load", "evaluate", "trajectories", "animate"}
    assert all(type(f) is not FunctionFamily for f in families().values())
