"""The Gymnasium family: any Gymnasium env with Box spaces as the real system, from a TOML file.

``loopid run gym --config FILE`` (``examples/pendulum.toml`` is a complete file; the format is
in :mod:`.scenario`). The common options (``--seeds``, ``--iterations``, ``--samples``,
``--test-trajectories``, ``--methods``) and ``--set FIELD=VALUE`` override the file, as for every
family. Every problem (unknown or missing key, wrong size, Discrete space, unknown env id)
raises ``ValueError`` with one line naming the value, before anything is written
(:func:`check` builds the env once).

Methods: ``dagger`` (p_n = ``dagger_fraction``), ``batch`` (p_n = 0), ``abbeel`` (ν's data at
n = 2, then the policy's), run by :func:`loopid.algorithms.gym_loop.run_learning_host`. Figure:
mean test cost against samples, ± one standard error, per method; report: the final costs.

One module per part of the family interface, as in every family (:mod:`.scenario`,
:mod:`.run`, :mod:`.report`, :mod:`.saved`), and two of its own (:mod:`.env`, :mod:`.setup`):

- :mod:`.scenario`: :class:`GymScenario`, its checks and its TOML file (:func:`read_file`,
  :func:`build`);
- :mod:`.env`: the one place an env is built and closed (:func:`make_system`);
- :mod:`.setup`: the :class:`Setup` every entry point builds once (the env, ν, the test cost
  and the compiled agent of :mod:`loopid.algorithms.host_agent`), and :func:`check`;
- :mod:`.run`: :func:`run` (one method on every seed) and :func:`shared`;
- :mod:`.saved`: saved policies reloaded, evaluated and filmed (:func:`load`,
  :func:`evaluate`, :func:`animate`);
- :mod:`.report`: :func:`figure`, :func:`trajectories` and :func:`report`.
"""

from loopid.experiments.families.base import Family
from loopid.experiments.families.gym.env import EnvSpec, env_shape, make_system
from loopid.experiments.families.gym.report import figure, report, trajectories
from loopid.experiments.families.gym.run import run, shared
from loopid.experiments.families.gym.saved import animate, evaluate, load, saved_policy
from loopid.experiments.families.gym.scenario import (
    FIELDS,
    METHODS,
    TABLES,
    GymScenario,
    build,
    read_file,
    validate,
)
from loopid.experiments.families.gym.setup import Setup, check, gym_setup


class GymFamily(Family):
    """Any Gymnasium environment, from a ``--config`` file (:mod:`.scenario`)."""

    name = "gym"
    config = GymScenario
    methods = METHODS

    def default_methods(self, config):
        return ("dagger", "batch")

    build = staticmethod(build)
    read_file = staticmethod(read_file)
    run = staticmethod(run)
    figure = staticmethod(figure)
    report = staticmethod(report)
    check = staticmethod(check)
    shared = staticmethod(shared)
    load = staticmethod(load)
    evaluate = staticmethod(evaluate)
    trajectories = staticmethod(trajectories)
    animate = staticmethod(animate)


FAMILY = GymFamily()

__all__ = [
    "FAMILY",
    "FIELDS",
    "METHODS",
    "TABLES",
    "EnvSpec",
    "GymFamily",
    "GymScenario",
    "Setup",
    "animate",
    "build",
    "check",
    "env_shape",
    "evaluate",
    "figure",
    "gym_setup",
    "load",
    "make_system",
    "read_file",
    "report",
    "run",
    "saved_policy",
    "shared",
    "trajectories",
    "validate",
]
