"""One gym method run on every seed (:func:`run`), and the nominal model its seeds share
(:func:`shared`).

Methods: ``dagger`` (p_n = ``dagger_fraction``), ``batch`` (p_n = 0), ``abbeel`` (ν's data at
n = 2, then the policy's), run by :func:`loopid.algorithms.gym_loop.run_learning_host` on the
:class:`~.setup.Setup` that :func:`~.setup.gym_setup` builds.
"""

import numpy as np

from loopid.algorithms.contracts import Trace
from loopid.algorithms.gym_loop import run_learning_host
from loopid.algorithms.host_agent import nominal_model
from loopid.algorithms.schedules import policy_fractions
from loopid.experiments.families.base import Progress
from loopid.experiments.families.gym.scenario import METHODS, GymScenario
from loopid.experiments.families.gym.setup import gym_setup
from loopid.experiments.seeds import seed_list


def run(method: str, s: GymScenario, seeds=None, progress: Progress | None = None) -> Trace:
    """Run ``method`` (:data:`~.scenario.METHODS`) on every seed (default
    :func:`~loopid.experiments.seeds.seed_list`): ``N = iterations`` rows per seed."""
    if method not in METHODS:
        raise ValueError(f"unknown gym method {method!r}; choose from {', '.join(METHODS)}")
    with gym_setup(s) as setup:
        seeds = seed_list(s) if seeds is None else np.asarray(seeds)
        fractions = policy_fractions(method, s.iterations, dagger_fraction=s.dagger_fraction)
        return run_learning_host(
            setup.system, setup.compiled.agent, setup.exploration, fractions,
            [int(x) for x in seeds], samples=s.samples, n_test=s.test_trajectories,
            cost=setup.test_cost, termination_cost=s.termination, cost_cap=s.cost_cap,
            progress=progress, program=setup.compiled.program, controller=setup.compiled.controller,
            test_policy=s.test_policy,
        )  # fmt: skip


def shared(s: GymScenario, method: str) -> dict:
    """The nominal model ``A``, ``B`` every seed's learned offsets add to."""
    with gym_setup(s) as setup:
        model = nominal_model(s.spec, setup.shape)
    return {"A": np.asarray(model.A), "B": np.asarray(model.B)}
