"""Value checks with one-line errors, shared by every config dataclass (an experiment's
scenario, a round directory's config): each error is a ``ValueError`` whose one line names the
bad value and what is allowed (:func:`printable`: nothing a terminal would act on).
"""

import dataclasses
import math
from collections.abc import Sequence


def replaced(config, changes: dict, what: str = "scenario"):
    """A copy of the frozen dataclass ``config`` with ``changes`` (validated again by its
    ``__post_init__``); unknown field names raise ``ValueError`` naming them."""
    unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(config)})
    if unknown:
        raise ValueError(f"unknown {what} field(s): {', '.join(unknown)}")
    return dataclasses.replace(config, **changes)


def check_int(name: str, v, minimum: int = 1) -> None:
    """``ValueError`` unless ``v`` is an integer (not a bool) ``>= minimum``."""
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {v!r}")


def check_number(name: str, v, low: float, high: float = math.inf, *, open_low=False) -> None:
    """``ValueError`` unless ``v`` is a finite number in ``[low, high]`` (``(low, high]``)."""
    ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    ok = ok and (v > low if open_low else v >= low) and v <= high
    if not ok:
        bound = f"({low}, {high}]" if open_low else f"[{low}, {high}]"
        raise ValueError(f"{name} must be a number in {bound}, got {v!r}")


def check_choice(name: str, v, allowed: Sequence[str]) -> None:
    """``ValueError`` unless ``v`` is one of ``allowed``."""
    if not isinstance(v, str) or v not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(allowed)}, got {v!r}")


def printable(text, limit: int | None = 500) -> str:
    """``text`` as one line with nothing a terminal would act on: runs of whitespace become one
    space; control characters, the replacement character of undecodable bytes and every other
    unprintable character become ``?``; at most ``limit`` characters (None: no limit)."""
    text = " ".join(str(text).split())
    text = "".join(c if c.isprintable() and c != "\ufffd" else "?" for c in text)
    return text if limit is None or len(text) <= limit else text[: limit - 1] + "…"
