"""Result tables: one row per scenario × method × seed × iteration, stored as Parquet (pyarrow).

Columns (types fixed by :data:`SCHEMA`): ``scenario, method, seed, iteration, samples`` (the
transitions collected before that iteration's policy was solved), ``test_cost`` (mean capped
total cost over the test trajectories), ``test_cost_median``, ``diverged`` (test trajectories
that hit the cap or a non-finite state), and the diagnostics of
:class:`loopid.algorithms.contracts.Row` (``loss_nu``, ``loss_policy``, ``online_loss``,
``policy_samples``, ``valid_samples``, ``solver_converged``, ``spectral_radius``), then any
system-specific diagnostics (:class:`loopid.algorithms.contracts.Diagnostics`, float64; +inf
allowed, e.g. c_ν^π where ν misses mass). Tables are written atomically
(:func:`loopid.files.write_atomic`), so a killed run never leaves a half-written table.
"""

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from loopid.algorithms.contracts import Row, Trace

SCHEMA = pa.schema(
    [
        ("scenario", pa.string()),
        ("method", pa.string()),
        ("seed", pa.int64()),
        ("iteration", pa.int64()),
        ("samples", pa.int64()),
        ("test_cost", pa.float64()),
        ("test_cost_median", pa.float64()),
        ("diverged", pa.int64()),
        ("loss_nu", pa.float64()),
        ("loss_policy", pa.float64()),
        ("online_loss", pa.float64()),
        ("policy_samples", pa.int64()),
        ("valid_samples", pa.int64()),
        ("solver_converged", pa.bool_()),
        ("spectral_radius", pa.float64()),
    ]
)


def trace_table(scenario: str, method: str, trace: Trace) -> pa.Table:
    """The rows of one cell, seed-major then iteration; raises if any value is NaN."""
    S, N = trace.rows.test_cost.shape
    cols: dict[str, np.ndarray] = {
        "scenario": np.full(S * N, scenario, dtype=object),
        "method": np.full(S * N, method, dtype=object),
        "seed": np.repeat(trace.seeds, N),
        "iteration": np.tile(trace.iteration, S),
        "samples": np.tile(trace.samples, S),
    }
    for name in Row._fields[:-1]:
        cols[name] = np.asarray(getattr(trace.rows, name)).reshape(S * N)
    extra = {name: np.asarray(v, np.float64).reshape(S * N) for name, v in trace.rows.extra.items()}
    for name, v in {**cols, **extra}.items():
        if v.dtype.kind == "f" and np.isnan(v).any():
            raise ValueError(f"column {name!r} of {scenario}/{method} holds NaN")
    schema = SCHEMA
    for name in extra:  # system-specific diagnostics (Row.extra) after the fixed columns
        schema = schema.append(pa.field(name, pa.float64()))
    data = {f.name: pa.array(cols[f.name], type=f.type) for f in SCHEMA}
    data.update({name: pa.array(v, type=pa.float64()) for name, v in extra.items()})
    return pa.table(data, schema=schema)


def read_table(path: Path) -> pa.Table:
    """Read a results table (one file, or a folder of cell files, concatenated in name order).

    The :data:`SCHEMA` columns come first with their types, then any extra (float64) diagnostic
    columns; cells without an extra column get nulls there. File metadata is dropped. A file
    without one of the :data:`SCHEMA` columns raises ``ValueError`` naming it.
    """
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.glob("*.parquet") if not p.name.startswith("."))
        if not files:
            return SCHEMA.empty_table()
        return concat([read_table(f) for f in files])
    table = pq.read_table(path)
    missing = [name for name in SCHEMA.names if name not in table.column_names]
    if missing:
        raise ValueError(f"{path} is not a loopid results table: no column(s) {', '.join(missing)}")
    extra = [name for name in table.column_names if name not in SCHEMA.names]
    schema = SCHEMA
    for name in extra:
        schema = schema.append(pa.field(name, pa.float64()))
    return table.select([*SCHEMA.names, *extra]).replace_schema_metadata(None).cast(schema)


def concat(tables: list[pa.Table]) -> pa.Table:
    """Concatenate result tables row-wise; extra columns missing from a table become nulls."""
    if not tables:
        return SCHEMA.empty_table()
    tables = [t.replace_schema_metadata(None) for t in tables]
    return pa.concat_tables(tables, promote_options="default")


def with_metadata(table: pa.Table, **values: float | str) -> pa.Table:
    """``table`` with ``values`` in its schema metadata (``loopid.NAME``), e.g. a cell's timings."""
    meta = dict(table.schema.metadata or {})
    meta.update({f"loopid.{k}".encode(): str(v).encode() for k, v in values.items()})
    return table.replace_schema_metadata(meta)


def metadata(path: Path) -> dict[str, str]:
    """The ``loopid.*`` schema metadata of a Parquet file, without the prefix."""
    meta = pq.read_schema(path).metadata or {}
    return {
        k.decode()[len("loopid.") :]: v.decode()
        for k, v in meta.items()
        if k.startswith(b"loopid.")
    }


def load_results(run_dir) -> pa.Table:
    """``run_dir/results.parquet``; a missing or unreadable table raises ValueError."""
    run_dir = Path(run_dir)
    results = run_dir / "results.parquet"
    if not results.is_file():
        raise ValueError(f"{str(run_dir)!r} holds no results.parquet")
    try:
        return read_table(results)
    except (pa.ArrowException, OSError) as e:
        raise ValueError(f"{str(results)!r} is not a readable Parquet table ({e})") from None
