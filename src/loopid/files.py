"""Atomic file writes: a file is written to a temporary name beside it and renamed, so a reader
(or a run resumed after a kill) sees the old file or the whole new one, never a part.

The run directories of the experiment pipeline and the round directories of
:mod:`loopid.rounds` write every file this way.
"""

import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq


def replace_atomically(path, write) -> None:
    """``write(tmp)`` to a temporary file beside ``path``, then rename it to ``path``: readers see
    the old file or the whole new one, never a part. When writing fails (a full disk, an
    interrupt) the temporary file is removed and the error raised: nothing is left behind."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(table: pa.Table, path: Path) -> None:
    """Write ``table`` to ``path`` as Parquet, atomically (:func:`replace_atomically`)."""
    replace_atomically(path, lambda tmp: pq.write_table(table, tmp))


def write_atomic_bytes(data: bytes, path: Path) -> None:
    """Write ``data`` to ``path`` atomically (:func:`replace_atomically`)."""
    replace_atomically(path, lambda tmp: tmp.write_bytes(data))
