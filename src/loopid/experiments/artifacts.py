"""What a cell ends with, kept: the final policy and the learned model of every seed.

Each finished cell of a run directory has, beside its rows (``cells/S__M.parquet``)::

    cells/S__M.npz    the arrays of :attr:`loopid.algorithms.loop.Trace.final`, each [S, ...]
                      with the seeds along the first axis (``seeds`` [S]): ``K`` the last
                      policy's gains, the model's parameters (``W`` for a linear offset model,
                      ``T_hat`` for a finite MDP's), ``best_K`` / ``history`` when the test
                      policy selects them; and, under ``shared.NAME``, what every seed shares
                      (the nominal model ``shared.A``, ``shared.B`` the offsets ``W`` add to)
    cells/S__M.json   what they are: format version, family, scenario, method, seeds, each
                      array's name, shape and dtype, and the scenario's configuration
                      (``config``: the coordinates the arrays are in, e.g. a Gymnasium run's
                      target, action_op, observe and horizon; the helicopter's task, pads,
                      delay and delay_mode)

Format: NumPy's ``.npz`` (uncompressed), which stores float64 exactly, needs no dependency
beyond NumPy and is read by any NumPy (``np.load``); safetensors would add a dependency and
gain nothing for a handful of dense arrays. Both files are written through a temporary name and
a rename before the cell's Parquet file, so a finished cell always has its artifacts and a
killed run leaves no half-written one. A file that is missing or unreadable raises one line
naming it (:func:`read`).
"""

import json
import os
from pathlib import Path

import numpy as np

#: The artifact format's version, in every ``.json``.
FORMAT = 1


def paths(cells: Path, scenario: str, method: str) -> tuple[Path, Path]:
    """``(npz, json)`` of one cell."""
    stem = Path(cells) / f"{scenario}__{method}"
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


def _replace(write, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    write(tmp)
    os.replace(tmp, path)


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
    arrays = {name: np.asarray(v) for name, v in final.items()}
    for name, v in arrays.items():
        if v.shape[:1] != seeds.shape:
            raise ValueError(f"artifact {name!r} has shape {v.shape}, not [{seeds.size}, ...]")
    common = {f"shared.{name}": np.asarray(v) for name, v in (shared or {}).items()}
    arrays_and_common = {**arrays, **common}
    npz, meta = paths(cells, scenario, method)

    def save_npz(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, seeds=seeds, **arrays_and_common)

    _replace(save_npz, npz)
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
    _replace(lambda tmp: tmp.write_text(json.dumps(info, indent=1) + "\n"), meta)


def read(cells: Path, scenario: str, method: str) -> tuple[dict, dict[str, np.ndarray]]:
    """``(info, arrays)`` of one cell; ``ValueError`` with one line naming a missing or
    unreadable file, or arrays that do not match their description."""
    npz, meta = paths(cells, scenario, method)
    for f in (meta, npz):
        if not f.is_file():
            raise ValueError(f"{str(f)!r} is missing: the cell has no saved model and policy")
    try:
        info = json.loads(meta.read_text())
        if info.get("format") != FORMAT:
            raise ValueError(f"format {info.get('format')!r}, not {FORMAT}")
        with np.load(npz, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, KeyError, EOFError) as e:
        bad = meta if isinstance(e, json.JSONDecodeError) else npz
        what = " ".join(str(e).split()) or type(e).__name__
        raise ValueError(f"{str(bad)!r} is not a readable loopid artifact ({what})") from None
    seeds = arrays.pop("seeds", None)
    expected = info.get("arrays", {})
    if seeds is None or seeds.tolist() != info.get("seeds") or set(arrays) != set(expected):
        raise ValueError(f"{str(npz)!r} does not match {str(meta)!r}")
    for name, v in arrays.items():
        if list(v.shape) != expected[name]["shape"] or str(v.dtype) != expected[name]["dtype"]:
            raise ValueError(f"{str(npz)!r}: array {name!r} does not match {str(meta)!r}")
    return info, {"seeds": seeds, **arrays}


def for_seed(arrays: dict, seed, where: str) -> dict[str, np.ndarray]:
    """One seed's arrays of :func:`read`'s ``arrays``: each ``[S, ...]`` array at that seed, the
    ``shared.*`` ones whole; ``ValueError`` naming a seed the cell does not have."""
    seeds = arrays["seeds"].tolist()
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed not in seeds:
        raise ValueError(f"seed {seed!r} is not in {where}; its seeds: {seeds}")
    i = seeds.index(int(seed))
    return {k: v if k.startswith("shared.") else v[i] for k, v in arrays.items() if k != "seeds"}
