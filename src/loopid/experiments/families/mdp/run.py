"""One finite-MDP method run on every seed (:func:`run_mdp`), over the compiled loop program
each scenario builds once (:func:`mdp_setup`).
"""

from collections.abc import Callable
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from loopid.algorithms.contracts import LoopProgram, LoopSpec, Row, Trace
from loopid.algorithms.loop import at_least, run_learning
from loopid.algorithms.loop_program import make_loop_program
from loopid.algorithms.schedules import policy_fractions
from loopid.experiments.families.mdp.agent import mdp_agent, mdp_diagnostics, mdp_plant
from loopid.experiments.families.mdp.scenario import (
    MDP_METHODS,
    MDPScenario,
    as_scenario,
    scenario_mdp,
    scenario_model,
    scenario_nu,
)
from loopid.systems.mdp import FiniteMDP


class MDPSetup(NamedTuple):
    """Everything a scenario's methods share: the MDP, ν's distribution, the plant, the agent,
    ν, the learning loop (``loop``: geometric draws, one exact test) and its compiled
    program."""

    mdp: FiniteMDP
    nu_dist: np.ndarray
    plant: object
    agent: object
    nu: Callable
    program: LoopProgram
    loop: LoopSpec


@lru_cache(maxsize=8)
def mdp_setup(s: MDPScenario) -> MDPSetup:
    """Build (and cache) the scenario's MDP, ν, agent, diagnostics and compiled loop program."""
    mdp = scenario_mdp(s)
    dist, nu = scenario_nu(s, mdp)
    model = scenario_model(s, mdp)
    plant = mdp_plant(mdp, s.horizon)
    agent = mdp_agent(mdp, model)
    diag = mdp_diagnostics(mdp, dist, model)
    loop = LoopSpec(plant, agent, nu, samples=s.samples, n_test=1, mode="geometric", gamma=s.gamma)
    program = make_loop_program(loop, s.iterations, diagnostics=diag)
    return MDPSetup(mdp, dist, plant, agent, nu, program, loop)


def run_mdp(
    method: str,
    scenario,
    seeds=None,
    progress: Callable[[int, Row], None] | None = None,
) -> Trace:
    """Run ``method`` (:data:`MDP_METHODS`) on a finite-MDP scenario (a name in
    :data:`MDP_SCENARIOS` or an :class:`MDPScenario`) for every seed (default
    ``range(scenario.seeds)``). The Trace's ``rows.extra`` holds the exact diagnostics."""
    s = as_scenario(scenario)
    if method not in MDP_METHODS:
        raise ValueError(f"unknown MDP method {method!r}; choose from {', '.join(MDP_METHODS)}")
    seeds = list(range(s.seeds)) if seeds is None else list(seeds)
    setup = mdp_setup(s)
    fractions = policy_fractions(method, s.iterations)
    return at_least(
        lambda padded: run_learning(
            setup.loop, fractions, padded, program=setup.program, progress=progress
        ),
        np.asarray(seeds),
    )  # fmt: skip
