"""Seed chunks: a cell's seeds run in equal chunks that fit a memory budget.

A cell runs all its seeds as one vmapped program, so its memory grows with the seed count
(the helicopter's hover: about 5.8 MB per seed, mostly the 100 test trajectories' noise,
``[400 steps, 6, 100]`` float64, while it is drawn). Above a budget the seeds are split:

- **Estimate.** A family's ``memory(config, method, seeds) -> bytes`` gives the peak bytes of
  the cell's compiled programs for that many seeds, from XLA's own buffer assignment
  (:func:`loopid.algorithms.loop.program_memory`): arguments + outputs + temporaries − donated
  buffers, the largest over the programs a cell runs one after another. Each task computes it
  for its own seeds, in the process that runs it, before it runs
  (:func:`loopid.experiments.cell.run_chunk`): the compilation it needs is the one the task
  then runs (JAX reuses it), so it costs nothing extra.
- **Budget** (:func:`budget`): ``--memory GB`` for all the processes computing at once, else
  :data:`DEFAULT_FRACTION` of the memory this machine has available (``MemAvailable``, within a
  cgroup's limit) less :data:`PROCESS_BYTES` per process; each process gets an equal share. On
  an accelerator the default is most of one device's memory, per process (one per device), or
  shared equally by the threads of one process sharing the device.
- **Chunks** (:func:`chunk_size`, :func:`split`): the programs' memory is affine in the seed count,
  ``a + b·S`` with ``a ≥ 0``, so ``b ≤ M(S)/S`` and ``c = ⌊S · budget / M(S)⌋`` seeds fit
  (S: the seed count, at most :data:`LANE_WIDTH`, the estimate is made at). The
  seeds are split into ``k = ⌈S / c⌉`` chunks of ``⌈S / k⌉``; the last is padded with copies
  of its last seed (dropped afterwards), so every chunk runs one compiled program.
- **Lane width** (:data:`LANE_WIDTH`, on a CPU; :func:`lane_width`): every chunk holds exactly
  this many lanes, padding its unused ones with copies of its last seed, so a panel's programs
  have one shape whatever the seed count a command asks for: ``--quick``'s 2 seeds,
  ``loopid run --seeds 5`` and ``loopid reproduce``'s 20 (two chunks) all run, and share in the
  persistent compilation cache, the same compiled programs. A chunk holds no more, even when more
  fit the budget, because the cost per seed grows with the chunk
  once a chunk's working set outgrows the core's cache. The test rollouts, most of a cell's
  arithmetic, advance every trajectory of the chunk one step at a time: per trajectory column
  the state, its error coordinates, the change and that step's noise, ~600 B, so ~60 kB per seed
  at 100 test trajectories, and a chunk of 10 seeds (~0.6 MB) stays inside this machine's 2 MB
  L2 where one of 40 (~2.4 MB) does not. Measured on the hover DAgger cell (100 test
  trajectories, one step after compilation, sizes interleaved in one process, best of 6-8,
  2-core machine): per seed 0.86x at 10 seeds, 0.90x at 15, 1.00 at 20 and 30, 1.04x at 40,
  1.10x at 80 and 1.25x at 200 seeds. A constant, not derived from the family: the working set
  per seed is the same for the funnel (same state, same test count), and the finite-MDP cells'
  per-seed data (MB) is out of cache at any chunk size. The cost of more chunks is a Python call
  per chunk and iteration (~1 ms against ~100 ms of work) and their files. The memory estimate
  is made at the chunk's width, so its compilation is the one the run reuses.
- **Same numbers.** Each seed's computation is its own under ``vmap`` (its keys come from its
  seed alone), but XLA's CPU backend picks a reduction's loop from the whole shape, so a sum's
  order, and its last bit, can change with the number of seeds beside it. Every reduction whose
  lowering was measured to do so is written in a fixed order: the model's squared error over a
  state's components (:func:`loopid.models.linear_offset.sum_last`); the test cost's sums over
  the 21 error coordinates of the ``[21, S·n_test]`` column batch (``jnp.sum`` gave 9 of 120
  hover test costs 1 ulp apart between chunks of 14 and one of 40), the mean over the test
  trajectories and the masked loss mean (``jnp.mean``/``jnp.sum`` over 100 entries changed from
  S = 41 seeds on), all by :func:`loopid.algorithms.plant.ordered_sum`. Batches of one or two
  seeds are lowered differently again (measured: a seed's rows then differ in the last bits,
  which a diverging test trajectory amplifies), so every program runs at least
  :data:`MIN_CHUNK` seeds, padding if it must (:func:`loopid.algorithms.loop.pad_seeds`, so a
  direct ``family.run`` of two seeds gives the same numbers as a run directory's cell). Checked
  bit for bit, every Row field and final array: hover DAgger 14 against 40 and 64 seeds
  (100 test trajectories), hover-delay 3 against 50 (also ``delay_mode="latency"``), the funnel
  3 against 45, the ``best`` and ``mixture`` test policies, the expert; and the issue's
  ``--memory 0.1`` against ``--memory 16`` (``tests/experiments/test_chunks.py``); the
  policy-gradient baseline (``pg``), whose per-coordinate RMS over a rollout and ‖g‖ are
  fixed-order sums too (funnel 10 against 20 seeds, hover 12 against 48, 100 test trajectories;
  before, 548 of a seed's 840 funnel gains changed in the last bits between 10 and 20 seeds).

Chunk files: ``cells/S__M.chunks/I-J.parquet`` (rows of the seeds at positions I..J−1 of the
run's seed list) and ``I-J.npz`` (their final arrays), written atomically, arrays first. A killed
run resumes at the first missing chunk; when every chunk is in, they are merged into the cell's
usual files and the folder is removed. A cell that fits runs as one chunk, with no chunk files.
"""

import math
import os
import re
import shutil
import zipfile
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from loopid.algorithms.loop import MIN_SEEDS
from loopid.experiments import backend
from loopid.experiments.artifacts import Stacked
from loopid.experiments.results import concat, metadata, read_table, with_metadata
from loopid.files import replace_atomically, write_atomic

#: The default budget: this fraction of the machine's available memory (the rest is headroom for
#: the estimate's error, compilation, Python and other programs).
DEFAULT_FRACTION = 0.6
#: What one XLA CPU process holds besides its cells' buffers (the Python interpreter, JAX, the
#: compiled programs, compilation's own peak): measured 0.6-1.0 GB for a helicopter process, and
#: 1.5 GB leaves room for larger programs.
PROCESS_BYTES = 1.5e9

GB = 1e9
#: The lanes every chunk holds on a CPU (module docstring: one program shape for every seed
#: count; the per-seed cost is lowest at 10-15 seeds and grows above, 1.25x at 200).
LANE_WIDTH = 10
#: The fewest seeds a chunk holds (:data:`loopid.algorithms.loop.MIN_SEEDS`: smaller batches are
#: lowered differently).
MIN_CHUNK = MIN_SEEDS


def available_bytes() -> int:
    """The memory this machine can give without swapping: ``MemAvailable`` of /proc/meminfo,
    within the cgroup's limit (``memory.max`` less ``memory.current``) when there is one; on
    systems without /proc, the physical memory."""
    found = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found = int(line.split()[1]) * 1024
    except OSError:
        pass
    if found is None:
        found = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = int(Path("/sys/fs/cgroup/memory.current").read_text())
        if limit != "max":
            found = min(found, int(limit) - used)
    except (OSError, ValueError):
        pass
    return max(int(found), 0)


def check_memory(gb) -> float | None:
    """``--memory GB`` as a positive finite number (None: the default budget)."""
    if gb is None:
        return None
    if isinstance(gb, bool) or not isinstance(gb, int | float) or not math.isfinite(gb) or gb <= 0:
        raise ValueError(f"--memory must be a positive number of GB, got {gb!r}")
    return float(gb)


def budget(gb: float | None, processes: int = 1, *, threads: bool = False) -> int:
    """Bytes one process's chunk may use: ``gb`` (all processes together) or the default
    (module docstring), shared equally by ``processes``; on an accelerator the default is
    :data:`~loopid.experiments.backend.DEVICE_FRACTION` of one device's memory, which each
    process owns, or which ``processes`` workers share as ``threads`` of one process."""
    gb = check_memory(gb)
    if gb is not None:
        return int(gb * GB / processes)
    device = backend.device_bytes()
    if device is not None:  # an accelerator: its memory, shared by the threads computing on it
        return int(backend.DEVICE_FRACTION * device / (processes if threads else 1))
    return int(max(DEFAULT_FRACTION * available_bytes() - processes * PROCESS_BYTES, 0) / processes)


def lane_width(seeds: int) -> int:
    """The lanes a chunk of a run of ``seeds`` seeds holds: :data:`LANE_WIDTH` on a CPU, the
    unused ones padded; on an accelerator, where width is nearly free, all ``seeds`` (the memory
    budget alone splits them)."""
    return max(seeds, MIN_CHUNK) if backend.accelerator() else LANE_WIDTH


def check_processes(processes: int, what: str = "--workers") -> None:
    """Refuse more worker processes than this machine has CPUs, or memory for
    (:data:`PROCESS_BYTES` each), in one line naming the most it can take."""
    cpus = os.cpu_count() or 1
    if processes > cpus:
        raise ValueError(f"{what} {processes}: this machine has {cpus} CPUs; use at most {cpus}")
    room = available_bytes()
    most = int(room // PROCESS_BYTES)
    if processes > max(most, 1):
        raise ValueError(
            f"{what} {processes}: each worker process needs about {PROCESS_BYTES / GB:.1f} GB and "
            f"{room / GB:.1f} GB is available; use at most {max(most, 1)}"
        )


def size_text(nbytes: float) -> str:
    """``nbytes`` in words, e.g. ``7.05 MB``."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{nbytes:.0f} B"


def chunk_size(estimate: int, seeds: int, limit: int, where: str) -> int:
    """The most seeds of a cell whose program estimate is ``estimate`` bytes at ``seeds`` seeds
    that fit in ``limit`` bytes (at most ``seeds``); ``ValueError`` in one line, naming the
    estimate and the budget, when not even one does."""
    if estimate <= limit:
        return seeds
    c = int(seeds * limit // max(estimate, 1))
    if c < MIN_CHUNK:
        raise ValueError(
            f"{where}: a chunk of {MIN_CHUNK} seeds needs about "
            f"{size_text(MIN_CHUNK * estimate / seeds)} (estimated for {seeds} seeds: "
            f"{size_text(estimate)}), more than the memory budget of {size_text(limit)} per "
            "worker; raise --memory or use fewer --workers"
        )
    return c


class Chunk(NamedTuple):
    """Positions ``start..stop−1`` of the run's seed list, run as ``seeds`` (padded to the chunk
    size with copies of the last seed)."""

    start: int
    stop: int
    seeds: np.ndarray

    @property
    def count(self) -> int:
        return self.stop - self.start


def split(
    seeds: np.ndarray, positions: list[int], size: int, minimum: int = MIN_CHUNK
) -> list[Chunk]:
    """Chunks of at most ``size`` of the seeds at ``positions`` (ascending), as equal as they can
    be (``k = ⌈P / size⌉`` chunks of ``⌈P / k⌉``, at least ``minimum``), each within one run of
    consecutive positions and padded to that one size."""
    if not positions:
        return []
    k = -(-len(positions) // size)
    size = max(-(-len(positions) // k), minimum)
    runs, first = [], positions[0]
    for a, b in zip(positions, [*positions[1:], None], strict=True):
        if b != a + 1:
            runs.append((first, a + 1))
            first = b
    chunks = []
    for lo, hi in runs:
        for start in range(lo, hi, size):
            stop = min(start + size, hi)
            part = seeds[start:stop]
            padded = np.concatenate([part, np.full(size - part.size, part[-1], part.dtype)])
            chunks.append(Chunk(start, stop, padded))
    return chunks


_NAME = re.compile(r"^(\d+)-(\d+)\.parquet$")


class ChunkFiles:
    """The chunk files of one cell (module docstring)."""

    def __init__(self, cells: Path, scenario: str, method: str):
        self.path = Path(cells) / f"{scenario}__{method}.chunks"

    def stem(self, start: int, stop: int) -> Path:
        """The path, without its suffix, of the chunk of positions ``start..stop − 1``."""
        return self.path / f"{start:09d}-{stop:09d}"

    def finished(self) -> list[tuple[int, int]]:
        """The ``(start, stop)`` position ranges already saved, in order."""
        if not self.path.is_dir():
            return []
        found = (_NAME.match(p.name) for p in self.path.iterdir())
        return sorted((int(m[1]), int(m[2])) for m in found if m)

    def missing(self, n: int) -> list[int]:
        """The positions ``0..n−1`` not in a saved chunk."""
        done = np.zeros(n, bool)
        for start, stop in self.finished():
            done[start:stop] = True
        return np.flatnonzero(~done).tolist()

    def save(self, chunk: Chunk, table: pa.Table, final: dict) -> None:
        """One finished chunk: its arrays, then its rows (so a chunk with rows has its arrays)."""
        self.path.mkdir(parents=True, exist_ok=True)
        stem = self.stem(chunk.start, chunk.stop)
        arrays = {k: np.asarray(v) for k, v in final.items()}

        def save_arrays(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)

        replace_atomically(stem.with_suffix(".npz"), save_arrays)
        write_atomic(table, stem.with_suffix(".parquet"))

    def merged(self) -> tuple[pa.Table, dict[str, Stacked]]:
        """Every chunk's rows in seed-list order (the one-chunk table, row for row), with the
        summed wall time and programs built, the chunk count (and the first chunk's
        ``lane_set``) in the metadata, and their final arrays as
        :class:`loopid.experiments.artifacts.Stacked`: read from the chunk files one chunk at a
        time when they are written, so the merge holds no
        more than one chunk's arrays (the final gains alone are 0.27 MB a hover seed, 0.54 GB
        at 2,000 seeds)."""
        tables, wall, stems = [], 0.0, [self.stem(*part) for part in self.finished()]
        built = {"compiled": 0, "loaded": 0}
        for stem in stems:
            tables.append(read_table(stem.with_suffix(".parquet")))
            meta = metadata(stem.with_suffix(".parquet"))
            wall += float(meta.get("wall_s", 0.0))
            for k in built:
                built[k] += int(meta.get(k, 0))
        first = metadata(stems[0].with_suffix(".parquet"))
        kept = {k: first[k] for k in ("lane_set",) if k in first}  # ran as one lane set's
        table = with_metadata(
            concat(tables), wall_s=f"{wall:.3f}", first_s=first.get("first_s", "0"),
            chunks=str(len(tables)), compiled=str(built["compiled"]), loaded=str(built["loaded"]),
            **kept,
        )  # fmt: skip
        return table, {name: _stacked(stems, name) for name in _array_names(stems[0])}

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


def _array_names(stem: Path) -> list[str]:
    with np.load(stem.with_suffix(".npz"), allow_pickle=False) as data:
        return list(data.files)


def _stacked(stems: list[Path], name: str) -> Stacked:
    """The chunks' ``name`` arrays as one ``[S, ...]`` array, from their ``.npy`` headers alone."""
    shapes, dtype = [], None
    for stem in stems:
        with zipfile.ZipFile(stem.with_suffix(".npz")) as zf, zf.open(f"{name}.npy") as f:
            read = {(1, 0): np.lib.format.read_array_header_1_0}.get(
                np.lib.format.read_magic(f), np.lib.format.read_array_header_2_0
            )
            shape, _, dtype = read(f)
            shapes.append(shape)

    def pieces():
        for stem in stems:
            with np.load(stem.with_suffix(".npz"), allow_pickle=False) as data:
                yield data[name]

    return Stacked((sum(s[0] for s in shapes), *shapes[0][1:]), dtype, pieces)
