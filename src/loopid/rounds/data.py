"""One round's logged transitions: reading, checking and hashing a Parquet or CSV file.

A round's file has one row per transition ``(o_t, a_t, o_{t+1})`` of the real system, in its own
units, and these columns (names from the config's ``[system]``):

- one per state coordinate (``states``), one per action coordinate (``actions``), one per
  next-state coordinate (``next_`` + the state's name), all finite numbers;
- ``source``: ``policy`` (the row comes from running the current controller from the start
  distribution) or ``nu`` (from the exploration distribution ν);
- ``t`` (the step within its episode, ``0 <= t < horizon``): required for a time-varying model,
  otherwise optional and unused. Other columns are kept in the saved copy and otherwise ignored.

The file holds exactly ``[rounds] samples`` rows. It is recognised by the SHA-256 of its bytes,
so the same file is never learned from twice. Every problem is one line of ``ValueError``
naming the file and the bad column, value or row, found before anything is written.
"""

import hashlib
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from loopid.algorithms.contracts import Transitions
from loopid.rounds.config import RoundsConfig

SOURCES = ("nu", "policy")


class RoundData(NamedTuple):
    """A checked round file.

    Attributes:
      x, u, x_next: states ``[b, n_obs]``, actions ``[b, m]`` and next states ``[b, n_obs]``,
        in the system's units.
      policy: ``[b]`` True for the rows of ``source = policy``.
      t: ``[b]`` the step of each row (zeros without a ``t`` column).
      digest: the SHA-256 of the file's bytes (hex).
      table: the file's table, as read (what the round directory keeps).
    """

    x: np.ndarray
    u: np.ndarray
    x_next: np.ndarray
    policy: np.ndarray
    t: np.ndarray
    digest: str
    table: pa.Table


def digest_of(path) -> str:
    """The SHA-256 (hex) of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _table(path: Path) -> pa.Table:
    suffix = path.suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            return pq.read_table(path)
        if suffix == ".csv":
            return pacsv.read_csv(path)
    except (OSError, pa.ArrowException) as err:
        raise ValueError(f"{str(path)!r}: cannot read it ({str(err).splitlines()[0]})") from None
    raise ValueError(f"{str(path)!r}: a round's file is .parquet or .csv, got {suffix or 'none'!r}")


def _numbers(table: pa.Table, names, where: str) -> np.ndarray:
    cols = []
    for name in names:
        col = table.column(name)
        if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type)):
            raise ValueError(f"{where}: column {name!r} must hold numbers, it holds {col.type}")
        if col.null_count:
            raise ValueError(f"{where}: column {name!r} has {col.null_count} empty value(s)")
        v = col.to_numpy().astype(np.float64)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise ValueError(f"{where}: column {name!r} holds {v[bad[0]]} at row {bad[0]}")
        cols.append(v)
    return np.stack(cols, axis=1)


def read_round(path, config: RoundsConfig) -> RoundData:
    """The checked transitions of ``path`` under ``config`` (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{str(path)!r}: no such file")
    table = _table(path)
    where = str(path)
    states, actions = list(config.states), list(config.actions)
    nexts = [f"next_{s}" for s in states]
    needed = [*states, *actions, *nexts, "source"] + (["t"] if config.time_varying else [])
    missing = [c for c in needed if c not in table.column_names]
    if missing:
        raise ValueError(f"{where}: missing column(s) {', '.join(missing)} (the config's names)")
    stray = [c for c in table.column_names if c.startswith("next_") and c not in nexts]
    if stray:
        raise ValueError(
            f"{where}: column(s) {', '.join(stray)} are not next states of the config's states "
            f"{', '.join(states)}: the config's sizes do not match the data"
        )
    if table.num_rows != config.samples:
        raise ValueError(
            f"{where}: {table.num_rows} transitions; a round takes [rounds] samples = "
            f"{config.samples}"
        )
    source = table.column("source")
    if not (pa.types.is_string(source.type) or pa.types.is_large_string(source.type)):
        raise ValueError(f"{where}: column 'source' must hold 'nu' or 'policy', got {source.type}")
    labels = np.asarray(source.to_pylist(), dtype=object)
    unknown = sorted({str(s) for s in labels if s not in SOURCES})
    if unknown:
        raise ValueError(f"{where}: unknown source label(s) {unknown}; allowed: nu, policy")
    t = np.zeros(table.num_rows, np.int64)
    if "t" in table.column_names:
        tt = _numbers(table, ["t"], where)[:, 0]
        if config.time_varying and (np.any(tt != np.round(tt)) or tt.min() < 0
                                    or tt.max() >= config.horizon):  # fmt: skip
            raise ValueError(f"{where}: column 't' must be steps 0..{config.horizon - 1}")
        t = tt.astype(np.int64) if config.time_varying else t
    return RoundData(
        _numbers(table, states, where), _numbers(table, actions, where),
        _numbers(table, nexts, where), labels == "policy", t, digest_of(path), table,
    )  # fmt: skip


def transitions(data: RoundData, config: RoundsConfig) -> Transitions:
    """The rows in the agent's coordinates (``Δx = [o − o*; 1]``, ``Δu = a − a_op``), all valid:
    the :class:`~loopid.algorithms.contracts.Transitions` a learner updates on."""
    target = np.asarray(config.target, np.float64)
    ones = np.ones((data.x.shape[0], 1))
    return Transitions(
        jnp.asarray(data.x), jnp.asarray(np.concatenate([data.x - target, ones], axis=1)),
        jnp.asarray(data.u - np.asarray(config.action_op, np.float64)),
        jnp.asarray(np.concatenate([data.x_next - target, ones], axis=1)),
        jnp.asarray(data.t, jnp.int32), jnp.ones(data.x.shape[0], bool),
    )  # fmt: skip
