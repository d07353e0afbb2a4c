"""Old public names kept for one release: a module's ``__getattr__`` that finds a renamed or
moved name at its new place and warns ``DeprecationWarning`` saying where."""

import importlib
import warnings
from collections.abc import Callable
from typing import Any


def renamed(module: str, names: dict[str, tuple[str, str]]) -> Callable[[str], Any]:
    """``__getattr__`` for the module named ``module``: ``names`` maps each old name to its
    ``(new module, new name)``; any other name is an ``AttributeError``, as usual."""

    def __getattr__(name: str) -> Any:
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        where, new = names[name]
        warnings.warn(
            f"{module}.{name} is now {where}.{new}; the old name goes in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(where), new)

    return __getattr__


def renamed_argument(function: str, old: str, new: str, old_value, new_value):
    """The value of keyword ``new`` of ``function`` where a caller still passed it as ``old``
    (warns); ``TypeError`` when both are given."""
    if old_value is None:
        return new_value
    if new_value is not None:
        raise TypeError(f"{function}() got both {new}= and its old name {old}=")
    warnings.warn(
        f"{function}({old}=...) is now {function}({new}=...); the old name goes in the next "
        "release",
        DeprecationWarning,
        stacklevel=3,
    )
    return old_value
