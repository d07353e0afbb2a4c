"""What every family's config shares: value checks with one-line errors, reading a ``--config``
TOML file, ``--set key=value`` and hashable (frozen) TOML values.

Every error is a ``ValueError`` whose one line names the bad value and what is allowed.
"""

import dataclasses
import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def seed_list(config) -> np.ndarray:
    """A config's seeds as an integer array: ``range(seeds)`` for a count, else the tuple."""
    seeds = config.seeds
    if isinstance(seeds, int | np.integer) and not isinstance(seeds, bool):
        return np.arange(int(seeds))
    return np.asarray(seeds, dtype=np.int64)


def seeds_value(seeds) -> int | dict | list[int]:
    """The seeds as ``config.toml`` records them: a count ``n`` for 0..n−1, ``{start, count}``
    for another run of consecutive seeds, else the list (:func:`seeds_from_value` inverts it)."""
    seeds = np.asarray(seeds, dtype=np.int64)
    if seeds.size and np.array_equal(seeds, np.arange(seeds[0], seeds[0] + seeds.size)):
        if seeds[0] == 0:
            return int(seeds.size)
        return {"start": int(seeds[0]), "count": int(seeds.size)}
    return [int(s) for s in seeds]


def seeds_from_value(value) -> np.ndarray:
    """The seed array of a :func:`seeds_value` (or of an older ``config.toml``'s list)."""
    if isinstance(value, dict):
        return np.arange(value["start"], value["start"] + value["count"], dtype=np.int64)
    if isinstance(value, int):
        return np.arange(value, dtype=np.int64)
    return np.asarray(value, dtype=np.int64)


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


def read_toml(path, what: str = "--config") -> dict:
    """A TOML file as a dict; one-line ``ValueError`` for an unreadable file or bad TOML."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ValueError(f"{what} {str(path)!r}: cannot read it ({e.strerror})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{what} {str(path)!r}: not valid TOML ({e})") from None


def read_flat_file(
    path, allowed: Sequence[str], tables: dict | None = None
) -> tuple[dict, list[str] | None]:
    """A ``--config`` TOML of flat keys, each a config field in ``allowed`` or ``methods`` (a
    list of method names). ``tables``: ``{table: keys}`` whose keys are read as the fields
    ``table_key`` (``[model] kind`` -> ``model_kind``). Returns ``(fields, methods or None)``;
    the values are validated when the config is built."""
    cfg = read_toml(path)
    if tables:
        cfg = flatten_tables(cfg, tables, f"--config {str(path)!r}")
    unknown = sorted(set(cfg) - {*allowed, "methods"})
    if unknown:
        raise ValueError(
            f"--config {str(path)!r}: unknown key(s) {', '.join(unknown)}; "
            f"allowed: {', '.join((*allowed, 'methods'))}"
        )
    methods = cfg.pop("methods", None)
    if methods is not None and (
        not isinstance(methods, list) or not all(isinstance(m, str) for m in methods)
    ):
        raise ValueError(
            f"--config {str(path)!r}: methods must be a list of names, got {methods!r}"
        )
    return cfg, methods


def flatten_tables(raw: dict, tables: dict, where: str) -> dict:
    """``raw`` with each table of ``tables`` (``{table: keys}``) as flat fields ``table_key``;
    other keys pass through. One-line ``ValueError`` for an unknown key in such a table."""
    out = {k: v for k, v in raw.items() if k not in tables}
    for table, keys in tables.items():
        given = raw.get(table)
        if given is None:
            continue
        if not isinstance(given, dict):
            raise ValueError(f"{where}: {table} must be a table, got {given!r}")
        for key, value in given.items():
            if key not in keys:
                raise ValueError(f"{where}: unknown key {table}.{key}; allowed: {', '.join(keys)}")
            out[f"{table}_{key}"] = value
    return out


def parse_assignment(text: str) -> tuple[str, Any]:
    """``--set key=value``: the value is read as a TOML value (``3``, ``0.5``, ``true``,
    ``[1, 2]``, ``"text"``); anything that is not TOML is taken as a bare string
    (``--set delay_mode=latency``)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ValueError(f"--set takes key=value, got {text!r}")
    try:
        return key, tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return key, value.strip()


class Table(tuple):
    """A frozen TOML table: a tuple of ``(key, value)`` pairs (hashable, unlike a dict)."""


def freeze(v):
    """A TOML value made hashable: lists become tuples, tables :class:`Table` s."""
    if isinstance(v, dict):
        return Table((k, freeze(x)) for k, x in v.items())
    if isinstance(v, list | tuple) and not isinstance(v, Table):
        return tuple(freeze(x) for x in v)
    return v


def thaw(v):
    """The inverse of :func:`freeze`: tuples become lists, :class:`Table` s dicts."""
    if isinstance(v, Table):
        return {k: thaw(x) for k, x in v}
    if isinstance(v, tuple):
        return [thaw(x) for x in v]
    return v
