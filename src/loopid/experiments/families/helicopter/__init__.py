"""The helicopter family: the paper's Figure 2 (its hover and funnel tasks and nine methods)
through the one pipeline.

Config: :class:`loopid.experiments.families.helicopter.scenario.Scenario` (the packaged panels
``hover``, ``hover-delay`` and ``funnel``, every protocol setting a field). Methods: the paper's
nine, :data:`loopid.experiments.families.helicopter.methods.METHODS`.

For a scenario the family builds the plant (the JAX helicopter under the task:
:func:`loopid.experiments.families.helicopter.plant.helicopter_plant`), the linearised expert L, the
initial model (:func:`loopid.experiments.families.helicopter.plant.helicopter_nominal_model`), the
model-based agent (linear offset model, FTRL, LQR) and the exploration distributions, once per
compiled program (:mod:`loopid.experiments.families.helicopter.assembly`); then it runs a
method on all seeds at once, or the learning methods as one lane set, the default on an
accelerator (:mod:`loopid.experiments.families.helicopter.runs`, on
:mod:`loopid.algorithms.loop`). Figure: the paper's Figure 2
(:mod:`loopid.experiments.families.helicopter.figure2`);
report: the final costs with each panel's readings of the details the paper leaves open
(:mod:`loopid.experiments.families.helicopter.readings`), and the paper's five findings
(:mod:`loopid.experiments.families.helicopter.findings`); saved policies and models loaded,
evaluated, flown and animated (:mod:`loopid.experiments.families.helicopter.saved`).
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
from loopid.experiments.families.helicopter.commands import COMMANDS
from loopid.experiments.families.helicopter.runs import (
    NOT_LANES,
    lane_sets,
    memory,
    run,
    run_lanes,
    shared,
)
from loopid.experiments.families.helicopter.saved import (
    animate,
    evaluate,
    figure,
    load,
    report,
    trajectories,
)
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
    commands = COMMANDS

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
