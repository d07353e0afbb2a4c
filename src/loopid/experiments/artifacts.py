"""What a cell ends with, kept: the final policy and the learned model of every seed.

Each finished cell of a run directory has, beside its rows (``cells/S__M.parquet``)::

    cells/S__M.npz    the arrays of Trace.final (loopid.algorithms.contracts), each [S, ...]
                      with the seeds along the first axis (seeds [S]): K the last
                      policy's gains, the model's parameters (W for a linear offset model,
                      T_hat for a finite MDP's), best_K / history when the test
                      policy selects them; and, under shared.NAME, what every seed shares
                      (the nominal model shared.A, shared.B the offsets W add to)
    cells/S__M.json   what they are: format version, family, scenario, method, seeds, each
                      array's name, shape and dtype, and the scenario's configuration
                      (config: the coordinates the arrays are in, e.g. a Gymnasium run's
                      target, action_op, observe and horizon; the helicopter's task, pads,
                      delay and delay_mode)

Format: NumPy's ``.npz`` (uncompressed), which stores float64 exactly, needs no dependency
beyond NumPy and is read by any NumPy (``np.load``); safetensors would add a dependency and
gain nothing for a handful of dense arrays. A chunked cell's arrays are written from their
chunks' files one piece at a time (:class:`Stacked`), so that the cell's seeds are never all in
memory at once: the npz member is an ``.npy`` header (format 2.0) for the whole ``[S, ...]``
shape followed by each piece's bytes, the joined array's bytes in ``np.savez``'s layout. Both
files are written through a temporary name and a rename before the cell's Parquet file, so a
finished cell always has its artifacts and a killed run leaves no half-written one. A file
that is missing or cannot be read (truncated, a zip entry whose CRC-32 does not match, arrays
that do not match the ``.json``) raises :class:`Damaged` (:func:`read`), which names it and
says what to do: run the command that made the directory again, which finds it (:func:`check`),
moves the cell's files aside and computes the cell again.
"""

import json
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

from loopid.files import replace_atomically

#: The artifact format's version, in every ``.json``.
FORMAT = 1
#: Bytes read at a time when a file is checked (:func:`check`).
BLOCK = 1 << 24


class Damaged(ValueError):
    """A run directory's file that cannot be read: ``path``, ``why``, and what to do (one
    line; by default, for a cell's file, run the command again)."""

    def __init__(self, path, why: str, remedy: str = ""):
        self.path, self.why = Path(path), " ".join(str(why).split()) or "unreadable"
        remedy = remedy or (
            "run the command that made the run directory again: it moves the cell's files to "
            "cells/damaged/ and computes the cell again"
        )
        super().__init__(f"{str(path)!r} is damaged ({self.why}); {remedy}")


class Stacked(NamedTuple):
    """An ``[S, ...]`` array kept as its pieces along the first axis (a chunked cell's chunk
    files): ``shape`` and ``dtype`` of the whole, and ``pieces()`` yielding the pieces in order,
    each loaded only when it is written."""

    shape: tuple
    dtype: np.dtype
    pieces: Callable[[], Iterator[np.ndarray]]


def _write_member(f, array) -> None:
    """One ``.npy`` member: ``np.lib.format.write_array`` for an array; for a :class:`Stacked`,
    the whole shape's header, then each piece's C-order bytes (checked against the header)."""
    if not isinstance(array, Stacked):
        np.lib.format.write_array(f, np.asarray(array), allow_pickle=False)
        return
    header = {
        "descr": np.lib.format.dtype_to_descr(np.dtype(array.dtype)),
        "fortran_order": False,
        "shape": tuple(array.shape),
    }
    np.lib.format.write_array_header_2_0(f, header)
    rows = 0
    for piece in array.pieces():
        piece = np.ascontiguousarray(piece, dtype=array.dtype)
        if piece.shape[1:] != tuple(array.shape[1:]):
            raise ValueError(f"a piece of shape {piece.shape} does not stack into {array.shape}")
        f.write(piece.tobytes())
        rows += piece.shape[0]
    if rows != array.shape[0]:
        raise ValueError(f"the pieces hold {rows} rows, not the {array.shape[0]} of {array.shape}")


def save_npz(path, arrays: dict) -> None:
    """``np.savez(path, **arrays)`` (uncompressed, no pickles) where an array may be a
    :class:`Stacked`, written piece by piece (module docstring); ``np.load`` reads it back."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, array in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as f:
                _write_member(f, array)


def paths(cells: Path, scenario: str, method: str) -> tuple[Path, Path]:
    """``(npz, json)`` of one cell."""
    stem = Path(cells) / f"{scenario}__{method}"
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


def write(
    cells: Path,
    scenario: str,
    method: str,
    family: str,
    seeds,
    final: dict,
    config=None,
    shared: dict | None = None,
) -> None:
    """Write one cell's artifacts (module docstring); ``final``: ``{name: [S, ...] array}``;
    ``config``: the scenario's ``to_dict()``; ``shared``: ``{name: array}`` of every seed."""
    seeds = np.asarray(seeds, dtype=np.int64)
    arrays = {name: v if isinstance(v, Stacked) else np.asarray(v) for name, v in final.items()}
    for name, v in arrays.items():
        if v.shape[:1] != seeds.shape:
            raise ValueError(f"artifact {name!r} has shape {v.shape}, not [{seeds.size}, ...]")
    common = {f"shared.{name}": np.asarray(v) for name, v in (shared or {}).items()}
    arrays_and_common = {**arrays, **common}
    npz, meta = paths(cells, scenario, method)

    replace_atomically(npz, lambda tmp: save_npz(tmp, {"seeds": seeds, **arrays_and_common}))
    info = {
        "format": FORMAT,
        "family": family,
        "scenario": scenario,
        "method": method,
        "seeds": seeds.tolist(),
        "arrays": {
            n: {"shape": list(v.shape), "dtype": str(v.dtype)} for n, v in arrays_and_common.items()
        },
        "config": config or {},
    }
    replace_atomically(meta, lambda tmp: tmp.write_text(json.dumps(info, indent=1) + "\n"))


def read(cells: Path, scenario: str, method: str) -> tuple[dict, dict[str, np.ndarray]]:
    """``(info, arrays)`` of one cell; ``ValueError`` with one line naming a missing or
    unreadable file, or arrays that do not match their description."""
    npz, meta = paths(cells, scenario, method)
    info = _info(npz, meta)
    try:
        with open(npz, "rb") as f, np.load(f, allow_pickle=False) as data:  # a bad zip closed
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise Damaged(npz, str(e) or type(e).__name__) from None
    seeds = arrays.pop("seeds", None)
    expected = info.get("arrays", {})
    if seeds is None or seeds.tolist() != info.get("seeds") or set(arrays) != set(expected):
        raise Damaged(npz, f"it does not match {str(meta)!r}")
    for name, v in arrays.items():
        if list(v.shape) != expected[name]["shape"] or str(v.dtype) != expected[name]["dtype"]:
            raise Damaged(npz, f"array {name!r} does not match {str(meta)!r}")
    return info, {"seeds": seeds, **arrays}


def _info(npz: Path, meta: Path) -> dict:
    """The ``.json`` of a cell; :class:`Damaged` naming a missing file or one that is not this
    format's JSON object (a finished cell always has both)."""
    for f in (meta, npz):
        if not f.is_file():
            raise Damaged(f, "missing: the cell has no saved model and policy")
    try:
        info = json.loads(meta.read_bytes())
    except (OSError, ValueError) as e:
        raise Damaged(meta, str(e)) from None
    if not isinstance(info, dict) or info.get("format") != FORMAT:
        found = info.get("format") if isinstance(info, dict) else None
        raise Damaged(meta, f"format {found!r}, not {FORMAT}")
    return info


def check(cells: Path, scenario: str, method: str) -> None:
    """Raise :class:`Damaged` unless :func:`read` would
    read the cell: the ``.json`` parses, and the ``.npz`` holds the arrays it describes
    (:func:`check_npz`)."""
    npz, meta = paths(cells, scenario, method)
    info = _info(npz, meta)
    expected = {"seeds": {"shape": [len(info.get("seeds", []))], "dtype": "int64"}}
    check_npz(npz, expected | info.get("arrays", {}), f"its arrays do not match {str(meta)!r}")


def check_npz(npz: Path, expected: dict | None = None, mismatch: str = "") -> None:
    """Raise :class:`Damaged` unless every array of the ``.npz`` reads through to its end (where
    the zip checks its CRC-32), :data:`BLOCK` bytes at a time, so that a file of any size is
    checked in little memory; ``expected``: ``{name: {"shape": [...], "dtype": str}}`` the
    arrays must be (``mismatch``: what to say when they are not)."""
    try:
        with zipfile.ZipFile(npz) as zf:
            names = [n.removesuffix(".npy") for n in zf.namelist()]
            if expected is not None and sorted(names) != sorted(expected):
                raise ValueError(mismatch)
            for name in names:
                with zf.open(f"{name}.npy") as f:
                    header = {(1, 0): np.lib.format.read_array_header_1_0}.get(
                        np.lib.format.read_magic(f), np.lib.format.read_array_header_2_0
                    )
                    shape, _, dtype = header(f)
                    want = (expected or {}).get(name, {"shape": list(shape), "dtype": str(dtype)})
                    if list(shape) != want["shape"] or str(dtype) != want["dtype"]:
                        raise ValueError(f"array {name!r}: {mismatch}")
                    size, got = int(np.prod(shape)) * dtype.itemsize, 0
                    while block := f.read(BLOCK):  # the zip checks the CRC-32 at the end
                        got += len(block)
                    if got != size:
                        raise EOFError(f"array {name!r} holds {got} bytes, not {size}")
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise Damaged(npz, str(e) or type(e).__name__) from None


def for_seed(arrays: dict, seed, where: str) -> dict[str, np.ndarray]:
    """One seed's arrays of :func:`read`'s ``arrays``: each ``[S, ...]`` array at that seed, the
    ``shared.*`` ones whole; ``ValueError`` naming a seed the cell does not have."""
    seeds = arrays["seeds"].tolist()
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed not in seeds:
        raise ValueError(f"seed {seed!r} is not in {where}; its seeds: {seeds}")
    i = seeds.index(int(seed))
    return {k: v if k.startswith("shared.") else v[i] for k, v in arrays.items() if k != "seeds"}


def tested_gains(arrays: dict) -> np.ndarray:
    """The gains a cell tested, from its saved ``arrays`` (one seed's or ``[S, ...]``):
    ``best_K`` under ``test_policy = "best"``, else the last policy's ``K``."""
    return arrays["best_K"] if "best_K" in arrays else arrays["K"]
