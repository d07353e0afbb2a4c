"""One round's logged transitions: reading, checking and hashing a Parquet or CSV file.

A round's file has one row per transition ``(o_t, a_t, o_{t+1})`` of the real system, in its own
units, and these columns (names from the config's ``[system]``):

- one per state coordinate (``states``), one per action coordinate (``actions``), one per
  next-state coordinate (``next_`` + the state's name), all finite numbers;
- ``source``: ``policy`` (the row comes from running the current controller from the start
  distribution) or ``nu`` (from the exploration distribution ν);
- ``t`` (the step within its episode, ``0 <= t < horizon``): required for a time-varying model,
  otherwise optional and unused;
- ``episode`` (optional): which logged episode a row belongs to (any label: its rows are the
  episode's steps), for ``round.md``'s per-episode costs and lengths;
- ``terminated`` (optional, true/false or 1/0): the episode ended at this row before the horizon
  (a fall). Other columns are kept in the saved copy and otherwise ignored.

The file is Parquet (``.parquet``, ``.pq``, any compression) or CSV (``.csv``, or ``.csv.gz``,
``.csv.bz2``, ``.csv.zst`` compressed); its first bytes must be what its suffix says
(:func:`sniff`). In a CSV file only an empty field is an empty value; ``nan``, ``inf`` are
numbers, refused as not finite. The file holds exactly ``[rounds] samples`` rows. It is
recognised by the SHA-256 of its bytes, so the same file is never learned from twice (the same
rows in another file: :mod:`loopid.rounds.checks`). Every problem is one line of printable
``ValueError`` naming the file and the bad column and row (rows count from 0, the header
excluded), found before anything is written.
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
from loopid.settings.checks import printable

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
      episode: ``[b]`` the ``episode`` column's labels as text (None without the column).
      terminated: ``[b]`` the ``terminated`` column as booleans (None without the column).
    """

    x: np.ndarray
    u: np.ndarray
    x_next: np.ndarray
    policy: np.ndarray
    t: np.ndarray
    digest: str
    table: pa.Table
    episode: np.ndarray | None = None
    terminated: np.ndarray | None = None


def digest_of(path) -> str:
    """The SHA-256 (hex) of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


#: The first bytes of the formats a round's file may be mistaken for (a table of magic numbers,
#: as ``file(1)`` keeps, for the handful of formats an engineer's logger writes; a library such
#: as ``python-magic`` would add a system dependency for these few lines).
MAGIC = {
    b"PAR1": "Parquet", b"PK\x03\x04": "a ZIP archive (.npz, .xlsx)",
    b"\x1f\x8b": "gzip-compressed data", b"\x28\xb5\x2f\xfd": "zstd-compressed data",
    b"BZh": "bzip2-compressed data", b"\xfd7zXZ\x00": "xz-compressed data",
    b"\x04\x22\x4d\x18": "lz4-compressed data", b"ARROW1": "Arrow IPC (Feather)",
    b"\x89HDF\r\n\x1a\n": "HDF5", b"\x93NUMPY": "a NumPy .npy array",
}  # fmt: skip
#: What each accepted suffix must hold.
SUFFIXES = {
    ".parquet": "Parquet", ".pq": "Parquet", ".csv": "text",
    ".csv.gz": "gzip-compressed data", ".csv.bz2": "bzip2-compressed data",
    ".csv.zst": "zstd-compressed data",
}  # fmt: skip


def sniff(path: Path) -> str:
    """What the file holds, from its first bytes: a :data:`MAGIC` format, ``binary data`` (a NUL
    byte or bytes that are not UTF-8 in the first 8 KiB) or ``text``."""
    with open(path, "rb") as f:
        head = f.read(8192)
    for magic, what in MAGIC.items():
        if head.startswith(magic):
            return what
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as err:  # a multi-byte character cut at the 8 KiB boundary is text
        if err.start < len(head) - 4:
            return "binary data"
    return "binary data" if b"\x00" in head else "text"


def _suffix(path: Path) -> str:
    name = path.name.lower()
    return next((s for s in sorted(SUFFIXES, key=len, reverse=True) if name.endswith(s)), "")


def _table(path: Path) -> pa.Table:
    """The file's table; one printable line naming a suffix that is not a round file's, or a
    content that is not what the suffix says."""
    suffix = _suffix(path)
    if not suffix:
        raise ValueError(
            f"{str(path)!r}: a round's file is {', '.join(SUFFIXES)}, got "
            f"{printable(path.suffix.lower()) or 'no suffix'!r}"
        )
    found = sniff(path)
    if found != SUFFIXES[suffix]:
        hint = {"Parquet": " (rename it .parquet)", "text": " (a CSV file? rename it .csv)"}
        raise ValueError(
            f"{str(path)!r}: a {suffix} file holds {SUFFIXES[suffix]}, this one holds "
            f"{found}{hint.get(found, '')}"
        )
    try:
        if SUFFIXES[suffix] == "Parquet":
            return pq.read_table(path)
        # only an empty field is empty: "NaN" is a number (refused as not finite, by its row)
        return pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(null_values=[""]))
    except (OSError, pa.ArrowException) as err:
        raise ValueError(f"{str(path)!r}: cannot read it ({printable(err)})") from None


def _first(bad: np.ndarray) -> str:
    """``row R`` of the first True of ``bad`` (and how many more)."""
    rows = np.flatnonzero(bad)
    more = f" (and {rows.size - 1} more)" if rows.size > 1 else ""
    return f"row {rows[0]}{more}"


def _numbers(table: pa.Table, names, where: str) -> np.ndarray:
    cols = []
    for name in names:
        col = table.column(name)
        if col.null_count:
            empty = np.asarray(col.is_null().to_numpy(zero_copy_only=False))
            raise ValueError(f"{where}: column {name!r} has an empty value at {_first(empty)}")
        if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type)):
            values = col.to_pylist()
            bad = np.array([not _is_number(v) for v in values])
            at = _first(bad) if bad.any() else "row 0"
            shown = printable(repr(values[int(np.argmax(bad))]), 40) if bad.any() else ""
            raise ValueError(
                f"{where}: column {name!r} must hold numbers; it holds {shown or col.type} at {at}"
            )
        v = col.to_numpy().astype(np.float64)
        bad = ~np.isfinite(v)
        if bad.any():
            raise ValueError(f"{where}: column {name!r} holds {v[bad][0]} at {_first(bad)}")
        cols.append(v)
    return np.stack(cols, axis=1)


def _is_number(v) -> bool:
    try:
        float(v)
    except (TypeError, ValueError):
        return False
    return not isinstance(v, bool)


def _episodes(table: pa.Table, where: str) -> tuple:
    """The optional ``episode`` labels and ``terminated`` flags (module docstring)."""
    episode = terminated = None
    if "episode" in table.column_names:
        col = table.column("episode")
        if col.null_count:
            raise ValueError(f"{where}: column 'episode' has {col.null_count} empty value(s)")
        episode = np.asarray([str(v) for v in col.to_pylist()])
    if "terminated" in table.column_names:
        col = table.column("terminated")
        flags = np.asarray(col.to_pylist(), dtype=object)
        if col.null_count or not all(v in (0, 1) for v in flags):  # True == 1, False == 0
            raise ValueError(f"{where}: column 'terminated' must hold true/false or 1/0")
        terminated = flags.astype(bool)
    return episode, terminated


def read_round(path, config: RoundsConfig, *, episodes: bool = True) -> RoundData:
    """The checked transitions of ``path`` under ``config`` (module docstring). ``episodes``:
    read the optional ``episode`` and ``terminated`` columns (off for a round directory's
    committed copies, which a version that ignored those columns may have accepted)."""
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
    bad = np.array([s not in SOURCES for s in labels])
    if bad.any():
        unknown = sorted({printable(s, 40) for s in labels[bad]})
        raise ValueError(
            f"{where}: unknown source label(s) {unknown} (first at {_first(bad)}); "
            "allowed: nu, policy"
        )
    t = np.zeros(table.num_rows, np.int64)
    if "t" in table.column_names:
        tt = _numbers(table, ["t"], where)[:, 0]
        bad = (tt != np.round(tt)) | (tt < 0) | (tt >= config.horizon)
        if config.time_varying and bad.any():
            raise ValueError(
                f"{where}: column 't' must be steps 0..{config.horizon - 1}; it holds "
                f"{tt[bad][0]:g} at {_first(bad)}"
            )
        t = tt.astype(np.int64) if config.time_varying else t
    return RoundData(
        _numbers(table, states, where), _numbers(table, actions, where),
        _numbers(table, nexts, where), labels == "policy", t, digest_of(path), table,
        *(_episodes(table, where) if episodes else (None, None)),
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
