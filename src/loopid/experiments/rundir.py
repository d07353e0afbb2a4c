"""Run directories: the resolved configuration, one Parquet file per finished cell, the table.

Layout of ``DIR``::

    config.toml           the resolved configuration (scenarios, methods, seeds, version)
    cells/S__M.parquet    one file per finished cell (scenario S × method M), written atomically;
                          its metadata holds the cell's wall time
    results.parquet       all finished cells, in a fixed order (rewritten after every cell)
    figure.png, report.md drawn from results.parquet (:mod:`loopid.experiments.plots`,
                          :mod:`loopid.experiments.report`)

A cell file exists only once its cell has finished, so a killed run loses nothing finished, and
rerunning the same command skips the finished cells. A directory whose ``config.toml`` differs
from the new run's configuration is refused rather than mixed.
"""

import json
import tomllib
from pathlib import Path

import pyarrow as pa

from loopid.experiments.results import concat, metadata, read_table, write_atomic


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string for these ASCII names
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def to_toml(config: dict) -> str:
    """Write a two-level dict (tables of scalars and lists; one nested level of tables) as TOML.

    Hand-written because the configuration is flat and a writer is the only TOML dependency
    Python's standard library lacks (``tomllib`` reads).
    """
    lines: list[str] = []

    def table(prefix: str, d: dict) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        if scalars:
            lines.append(f"[{prefix}]")
            lines.extend(f"{k} = {_toml_value(v)}" for k, v in scalars.items())
            lines.append("")
        for k, v in d.items():
            if isinstance(v, dict):
                table(f"{prefix}.{json.dumps(k) if '-' in k else k}", v)

    for key, value in config.items():
        table(key, value)
    return "\n".join(lines)


class RunDir:
    """A run directory (see the module docstring)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.cells = self.path / "cells"

    def prepare(self, config: dict) -> None:
        """Create the directory for ``config``, or check an existing one has the same config."""
        cfg_file = self.path / "config.toml"
        if cfg_file.exists():
            old = tomllib.loads(cfg_file.read_text())
            new = tomllib.loads(to_toml(config))
            if old != new:
                raise ValueError(
                    f"{self.path} holds a run with a different configuration; "
                    "use another --out directory"
                )
            return
        self.cells.mkdir(parents=True, exist_ok=True)
        tmp = cfg_file.with_name(".config.toml.tmp")
        tmp.write_text(to_toml(config))
        tmp.replace(cfg_file)

    def cell_file(self, scenario: str, method: str) -> Path:
        return self.cells / f"{scenario}__{method}.parquet"

    def done(self, scenario: str, method: str) -> bool:
        return self.cell_file(scenario, method).exists()

    def save_cell(self, scenario: str, method: str, table: pa.Table) -> None:
        write_atomic(table, self.cell_file(scenario, method))

    def write_results(self, order: list[tuple[str, str]]) -> pa.Table:
        """Concatenate the finished cells in ``order`` into ``results.parquet``; return it."""
        table = concat([read_table(self.cell_file(s, m)) for s, m in order if self.done(s, m)])
        write_atomic(table, self.path / "results.parquet")
        return table

    def cell_metadata(self, scenario: str, method: str) -> dict[str, str]:
        """What a finished cell recorded besides its rows (``wall_s``, ``first_s``: seconds)."""
        return metadata(self.cell_file(scenario, method))
