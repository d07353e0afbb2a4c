"""Deprecated name of :mod:`loopid.systems.from_gymnasium` (a Gymnasium env as loopid's real
system), kept so that code written against loopid 0.x keeps importing; use the new name."""

from loopid.systems.from_gymnasium import *  # noqa: F403
from loopid.systems.from_gymnasium import __all__  # noqa: F401
