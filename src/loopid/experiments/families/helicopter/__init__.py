"""The helicopter family: the paper's Figure 2 (its hover and funnel tasks and nine methods)
through the one pipeline.

Config: :class:`loopid.experiments.families.helicopter.scenario.Scenario` (the packaged panels
``hover``, ``hover-delay`` and ``funnel``, every protocol setting a field). Methods: the paper's
nine, :data:`loopid.experiments.families.helicopter.methods.METHODS`.

The helicopter itself (its dynamics, tasks, expert L, plant and nominal models) is the system
package :mod:`loopid.systems.helicopter`; this package holds the experiment, one module per part
of the :class:`~loopid.experiments.families.base.Family` interface, as in every family:

- :mod:`.scenario`: the config and its checks; :mod:`.readings`, the readings of the details
  the paper leaves open; :mod:`.methods`, the nine methods;
- :mod:`.run`: ``run`` (a method on all seeds at once, or the learning methods as one lane set,
  on :mod:`loopid.algorithms.loop`), over the plant, expert, initial model, agent and
  exploration distributions that :mod:`.assembly` builds once per compiled program;
- :mod:`.report`: ``report`` (the final costs with each panel's readings, and the paper's five
  findings, :mod:`.findings`) and ``figure`` (the paper's Figure 2);
- :mod:`.saved`: ``load`` and ``evaluate`` (saved policies and models reloaded and flown on
  fresh noise), ``trajectories`` and ``animate`` (drawn by :mod:`.flights`).

The paper's whole reproduction, which spans this family and the finite MDP, is
:mod:`loopid.paper`.
"""

from loopid.experiments.families.base import Family
from loopid.experiments.families.helicopter import methods as M
from loopid.experiments.families.helicopter import readings
from loopid.experiments.families.helicopter.assembly import (
    Setup,
    agent,
    loop_program,
    program_key,
    setup,
)
from loopid.experiments.families.helicopter.report import figure, report
from loopid.experiments.families.helicopter.run import (
    NOT_LANES,
    lane_sets,
    memory,
    run,
    run_lanes,
    shared,
)
from loopid.experiments.families.helicopter.saved import animate, evaluate, load, trajectories
from loopid.experiments.families.helicopter.scenario import FIELDS, SCENARIOS, Scenario, scenario
from loopid.settings import model_planner
from loopid.settings.toml import read_flat_file


class HelicopterFamily(Family):
    """The paper's helicopter (Figure 2): ``hover``, ``hover-delay`` and ``funnel``; its
    learning methods run as one lane set (:func:`lane_sets`)."""

    name = "helicopter"
    config = Scenario
    methods = M.METHODS
    scenarios = SCENARIOS
    presets = readings.PRESETS

    def build(self, name, fields):
        return scenario(name, **fields)

    def read_file(self, path):
        return read_flat_file(path, FIELDS, tables=model_planner.TABLES)

    def normalize(self, fields):
        """A scenario table with every reading field spelled out: a ``config.toml`` written
        before a reading became a field ran its literal reading
        (:func:`~loopid.experiments.families.helicopter.readings.readings_of`)."""
        return {**fields, **readings.readings_of(fields)}

    def continue_hint(self, old, new):
        return readings.continue_hint(old, new)

    run = staticmethod(run)
    figure = staticmethod(figure)
    report = staticmethod(report)
    shared = staticmethod(shared)
    lane_sets = staticmethod(lane_sets)
    load = staticmethod(load)
    evaluate = staticmethod(evaluate)
    trajectories = staticmethod(trajectories)
    animate = staticmethod(animate)
    memory = staticmethod(memory)
    run_lanes = staticmethod(run_lanes)


FAMILY = HelicopterFamily()


__all__ = [
    "FAMILY", "NOT_LANES", "HelicopterFamily", "Setup", "agent", "animate", "evaluate",
    "figure", "lane_sets", "load", "loop_program", "memory", "program_key", "report", "run",
    "run_lanes", "setup", "shared", "trajectories",
]  # fmt: skip
