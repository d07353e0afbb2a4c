"""Algorithm 1 one round at a time, for a system that is not a Python env.

An engineer runs a controller on the real system, logs the transitions, and calls
:func:`update`; loopid learns from them, solves the new model and writes the next controller,
ready to deploy (:func:`export`: JSON, NumPy or a C header). ``round.md`` in the round directory
says what to collect next. The command line is ``loopid round init|update|export``.

- :func:`init`: start a round directory from a config (:mod:`loopid.rounds.config`).
- :func:`update`: one iteration on a Parquet or CSV file (:mod:`loopid.rounds.data`).
- :func:`export`: a controller as ``json``, ``npz`` or ``c``, or its identified model as
  ``model`` (:mod:`loopid.rounds.export`).
- :func:`controller`: a controller as a Python object.
"""

from loopid.rounds.api import Controller, Update, controller, init, update
from loopid.rounds.checks import RoundWarning
from loopid.rounds.config import RoundsConfig, read_config
from loopid.rounds.export import export

__all__ = [
    "Controller",
    "RoundWarning",
    "RoundsConfig",
    "Update",
    "controller",
    "export",
    "init",
    "read_config",
    "update",
]
