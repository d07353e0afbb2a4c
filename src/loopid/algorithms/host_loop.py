"""The old name of :mod:`loopid.algorithms.gym_loop` (the Gymnasium loop, stepped from the host),
kept for one release: every name read from here warns ``DeprecationWarning`` and is the one of
:mod:`~loopid.algorithms.gym_loop` (``nominal_model`` is now
:func:`~loopid.algorithms.gym_loop.gym_nominal_model`)."""

import warnings

from loopid.algorithms import gym_loop

_RENAMED = {"nominal_model": "gym_nominal_model"}


def __getattr__(name: str):
    new = _RENAMED.get(name, name)
    if not hasattr(gym_loop, new):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    warnings.warn(
        f"loopid.algorithms.host_loop.{name} is now loopid.algorithms.gym_loop.{new}; the old "
        "module goes in the next release",
        DeprecationWarning,
        stacklevel=2,
    )
    return getattr(gym_loop, new)
