"""The helicopter family: the paper's Figure 2 (its hover and funnel tasks and nine methods)
through the one pipeline.

Config: :class:`loopid.experiments.scenarios.Scenario` (the packaged panels ``hover``,
``hover-delay`` and ``funnel``, every protocol setting a field). Methods: the paper's nine,
:data:`loopid.algorithms.methods.METHODS`.

For a scenario the family builds the plant (the JAX helicopter under the task:
:func:`loopid.algorithms.helicopter_plant.helicopter_plant`), the linearised expert L, the
initial model (:func:`loopid.algorithms.helicopter_plant.helicopter_nominal_model`), the
model-based agent (linear offset model, FTRL, LQR) and the exploration distributions, once per
compiled program (:mod:`loopid.experiments.families.helicopter.assembly`); then it runs a
method on all seeds at once, or the learning methods as one lane set, the default on an
accelerator (:mod:`loopid.experiments.families.helicopter.runs`, on
:mod:`loopid.algorithms.loop`). Figure: the paper's Figure 2 (:mod:`loopid.experiments.plots`);
report: the final costs with each panel's readings of the details the paper leaves open
(:mod:`loopid.experiments.readings`), and the paper's five findings
(:mod:`loopid.experiments.findings`); saved policies and models loaded, evaluated, flown and
animated (:mod:`loopid.experiments.families.helicopter.saved`).
"""

from loopid.algorithms import methods as M
from loopid.experiments.families.base import Family
from loopid.experiments.families.helicopter.assembly import (
    Setup,
    agent,
    loop_program,
    program_key,
    setup,
)
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
from loopid.experiments.scenarios import FIELDS, SCENARIOS, Scenario, scenario
from loopid.settings import model_planner
from loopid.settings.toml import read_flat_file


class HelicopterFamily(Family):
    """The paper's helicopter (Figure 2): ``hover``, ``hover-delay`` and ``funnel``; its
    learning methods run as one lane set (:func:`lane_sets`)."""

    name = "helicopter"
    config = Scenario
    methods = M.METHODS
    scenarios = SCENARIOS

    def build(self, name, fields):
        return scenario(name, **fields)

    def read_file(self, path):
        return read_flat_file(path, FIELDS, tables=model_planner.TABLES)

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
