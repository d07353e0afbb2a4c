"""Deprecated name of :mod:`loopid.systems.as_gymnasium` (loopid's helicopter tasks as
Gymnasium envs), kept so that code written against loopid 0.x keeps importing; use the new name."""

from loopid.systems.as_gymnasium import *  # noqa: F403
from loopid.systems.as_gymnasium import __all__  # noqa: F401
