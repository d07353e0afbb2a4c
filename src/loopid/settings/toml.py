"""Settings in TOML: a ``--config`` file of flat keys or of tables, ``--set key=value``, and
TOML values made hashable (frozen) so that a config can key a cache.

Every error is a ``ValueError`` whose one line names the file, the table or the key.
"""

import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def read_toml(path, what: str = "--config") -> dict:
    """A TOML file as a dict; one-line ``ValueError`` for an unreadable file or bad TOML."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ValueError(f"{what} {str(path)!r}: cannot read it ({e.strerror})") from None
    except UnicodeDecodeError as e:  # binary, or another encoding: TOML is UTF-8
        raise ValueError(
            f"{what} {str(path)!r}: not UTF-8 text (byte {e.object[e.start]:#04x} at offset "
            f"{e.start}); a TOML file is UTF-8"
        ) from None
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


def read_tables(path, tables: dict, required: dict) -> tuple[dict, list[str] | None]:
    """A ``--config`` TOML of tables only, as ``(fields, methods or None)``.

    ``tables``: ``{table: {key: field}}``, each key read as that config field, or as the list
    of method names where its field is None (``[run] methods``); ``required``: ``{table:
    keys}``, the tables and keys the file must have. One-line ``ValueError`` naming an unknown
    or missing table or key (values are checked when the config is built)."""
    raw = read_toml(path)
    where = f"--config {str(path)!r}"
    out: dict = {}
    methods, methods_key = None, None
    for table, given in raw.items():
        if table not in tables:
            raise ValueError(f"{where}: unknown table [{table}]; allowed: {', '.join(tables)}")
        if not isinstance(given, dict):
            raise ValueError(f"{where}: {table} must be a table, got {given!r}")
        for key, value in given.items():
            if key not in tables[table]:
                raise ValueError(
                    f"{where}: unknown key {table}.{key}; allowed: {', '.join(tables[table])}"
                )
            if tables[table][key] is None:
                methods, methods_key = value, f"{table}.{key}"
            else:
                out[tables[table][key]] = value
    for table, keys in required.items():
        if table not in raw:
            raise ValueError(f"{where}: missing table [{table}]")
        for key in keys:
            if key not in raw[table]:
                raise ValueError(f"{where}: missing key {table}.{key}")
    if methods is not None and (
        not isinstance(methods, list) or not methods or not all(isinstance(m, str) for m in methods)
    ):
        raise ValueError(f"{where}: {methods_key} must be a non-empty list, got {methods!r}")
    return out, methods


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
