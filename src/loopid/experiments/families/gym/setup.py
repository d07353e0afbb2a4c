"""What every entry point of the gym family builds first, once: the :class:`Setup`.

:func:`gym_setup` opens the scenario's env (:mod:`.env`) and builds everything a cell or a saved
policy needs from it: the env's sizes and coordinates, the compiled agent
(:func:`loopid.algorithms.host_agent.compiled_agent`, cached across calls), ν and the test cost.
``run`` and ``shared`` (:mod:`loopid.experiments.families.gym.run`), ``check``, ``load``,
``evaluate``, ``trajectories`` and ``animate`` all take that one object; the env is closed when
the ``with`` block ends. Every problem found while building it (a size that does not fit the
env, a ``module:function`` that does not import) is one line of ``ValueError``.
"""

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, NamedTuple

import numpy as np

from loopid.algorithms.gym_loop import Exploration
from loopid.algorithms.host_agent import (
    CompiledAgent,
    EnvShape,
    checked,
    compiled_agent,
    design_cost,
    import_callable,
)
from loopid.experiments.families.gym.env import env_shape, opened_system
from loopid.experiments.families.gym.scenario import GymScenario
from loopid.systems.from_gymnasium import GymSystem
from loopid.systems.gym_policies import CallablePolicy, OpenLoopPolicy


class Setup(NamedTuple):
    """A gym scenario built against its env.

    Attributes:
      scenario: the :class:`GymScenario`; values: its fields as plain values
        (:attr:`~.scenario.GymScenario.plain`).
      system: the open env (:class:`~loopid.systems.from_gymnasium.GymSystem`), the loop's plant.
      shape: its sizes and coordinates (:class:`~loopid.algorithms.host_agent.EnvShape`).
      compiled: the agent, its compiled host loop program and controller
        (:class:`~loopid.algorithms.host_agent.CompiledAgent`).
      exploration: ν (:class:`~loopid.algorithms.gym_loop.Exploration`).
      test_cost: an :class:`~loopid.systems.gym_cost.ObservationCost`, ``"reward"`` or a
        callable ``cost(obs, action)``.
    """

    scenario: GymScenario
    values: dict
    system: GymSystem
    shape: EnvShape
    compiled: CompiledAgent
    exploration: Exploration
    test_cost: Any


@contextmanager
def gym_setup(s: GymScenario) -> Iterator[Setup]:
    """The :class:`Setup` of ``s``; its env is closed when the ``with`` block ends."""
    with opened_system(s) as system:
        try:
            v = s.plain
            shape = env_shape(system)
            # ν: the [exploration] table's gain, policy or open-loop actions, with its noise
            if v["gain"] is not None:
                nu = checked("exploration.gain", system.linear_policy, v["gain"])
            elif v["policy"] is not None:
                nu = CallablePolicy(import_callable(v["policy"], "exploration.policy"), system.m)
            else:
                U = np.asarray(v["nominal"], dtype=np.float64)
                if U.ndim != 2 or U.shape[1] != system.m or U.shape[0] < 1:
                    raise ValueError(
                        f"[exploration] nominal must be [T, {system.m}], got shape {U.shape}"
                    )
                nu = OpenLoopPolicy(U)
            exploration = Exploration(nu, float(v["action_std"]))
            # the test cost: the [cost] table's quadratic, the env's own reward, or a callable
            if v["test_cost"] == "quadratic":
                test_cost = design_cost(s.spec, shape)
            elif v["test_cost"] == "reward":
                test_cost = "reward"
            else:
                test_cost = import_callable(v["test_cost"], "cost.test")
            compiled = compiled_agent(s.spec, shape)
        except (ValueError, TypeError) as err:
            raise ValueError(str(err).splitlines()[0]) from None
        yield Setup(s, v, system, shape, compiled, exploration, test_cost)


def check(s: GymScenario) -> None:
    """Build the env and every part once, so that a size that does not fit the env is refused
    before anything is written."""
    with gym_setup(s):
        pass
