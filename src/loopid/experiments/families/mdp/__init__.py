r"""The finite-MDP family: the paper's theory made visible, through the same loop and results.

Scenarios (:data:`MDP_SCENARIOS`):

- ``mdp-random``: a random MDP (S = 10, A = 3, Dirichlet(0.3) rows, costs U[0, 1], γ = 0.9),
  ν uniform over the state-action pairs (the best ν for Batch), count-estimator model: the
  realisable case, where DAgger and Batch both become optimal.
- ``mdp-trap``: :func:`loopid.systems.mdp.trap_mdp` with ν = D_{μ,π_ε} of "walk, but act at
  random with probability ε = 10⁻³" (a base policy's distribution with action noise): Batch's
  policy jumps into the region ν rarely sees (huge c_ν^π̂), DAgger's does not.
- ``mdp-trap-hinge``: the same with the deterministic classifier model (online hinge): a
  misspecified class on a stochastic system (the walk slips), i.e. the agnostic case.

Methods (:data:`MDP_METHODS`): ``dagger`` (p_n = ½), ``batch`` (p_n = 0), ``abbeel`` (ν at
n = 2, then the policy only); the fractions come from
:func:`loopid.algorithms.schedules.policy_fractions`. Policy draws are ``geometric`` (exact
draws from D_{μ,π}, the paper's analysis). Every method of a scenario shares one compiled loop
program.

Extra result columns (:func:`loopid.experiments.families.mdp.agent.mdp_diagnostics`): ``j_policy``,
``j_best``, ``j_mixture``, ``j_optimal``, ``bound`` (Theorem 3.1 while all data came from ν,
Lemma 4.1 once the policies contribute), ``eps_prd_l1``, ``eps_prd_kl``, ``eps_mdl_l1``,
``eps_oc``, ``c_nu``, ``c_nu_policy``. ``test_cost`` is the exact J of the iteration's policy.

One module per part of the family interface, as in every family: :mod:`.scenario` (the
scenarios and their checks, their MDP, ν and model), :mod:`.run` (the compiled loop program and
:func:`run_mdp`), :mod:`.report` (the figure, the report section and ``trajectories.png``) and
:mod:`.saved` (saved policies reloaded and evaluated exactly); beside them :mod:`.agent` (the
MDP's plant, models and agent, and the exact diagnostics, from the bounds of
:mod:`loopid.systems.mdp_bounds`).
"""

from dataclasses import fields

from loopid.algorithms.loop import program_memory
from loopid.experiments.families.base import Family
from loopid.experiments.families.mdp.report import mdp_figure, report, trajectories
from loopid.experiments.families.mdp.run import MDPSetup, mdp_setup, run_mdp
from loopid.experiments.families.mdp.saved import evaluate, load
from loopid.experiments.families.mdp.scenario import (
    MDP_METHODS,
    MDP_SCENARIOS,
    MDPScenario,
    build,
    scenario_mdp,
    scenario_model,
    scenario_nu,
)
from loopid.settings.toml import read_flat_file


class MDPFamily(Family):
    """Finite MDPs, where the paper's guarantees can be computed exactly: ``mdp-random``,
    ``mdp-trap`` and ``mdp-trap-hinge``."""

    name = "mdp"
    config = MDPScenario
    methods = MDP_METHODS
    scenarios = MDP_SCENARIOS

    build = staticmethod(build)
    report = staticmethod(report)
    load = staticmethod(load)
    evaluate = staticmethod(evaluate)
    trajectories = staticmethod(trajectories)

    def read_file(self, path):
        return read_flat_file(path, [f.name for f in fields(MDPScenario)])

    def run(self, method, config, seeds=None, progress=None):
        return run_mdp(method, config, seeds, progress)

    def figure(self, table, path, configs):
        mdp_figure(table, path)

    def memory(self, config, method, seeds):
        return program_memory(mdp_setup(config).program, seeds)

    def lane_sets(self, config, methods):
        """Every method of a scenario runs the scenario's one compiled loop program
        (:func:`mdp_setup`), with its own policy fractions: one group."""
        return [tuple(methods)] if methods else []


FAMILY = MDPFamily()

__all__ = [
    "FAMILY",
    "MDP_METHODS",
    "MDP_SCENARIOS",
    "MDPFamily",
    "MDPScenario",
    "MDPSetup",
    "build",
    "evaluate",
    "load",
    "mdp_figure",
    "mdp_setup",
    "report",
    "run_mdp",
    "scenario_mdp",
    "scenario_model",
    "scenario_nu",
    "trajectories",
]
