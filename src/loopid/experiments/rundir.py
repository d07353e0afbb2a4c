"""Run directories: the resolved configuration, one Parquet file per finished cell, the table.

Layout of ``DIR``::

    config.toml           the resolved configuration (scenarios, methods, seeds, version); the
                          seeds as a count, a {start, count} range or, when given so, a list
    cells/S__M.parquet    one file per finished cell (scenario S × method M), written atomically;
                          its metadata holds the cell's wall time (its model and policy beside
                          it: loopid.experiments.artifacts)
    cells/damaged/        the files of cells found damaged on a rerun, moved aside
    results.parquet       all finished cells, in a fixed order (rewritten after every cell)
    figure.png, report.md drawn from results.parquet (the family's figure, and
                          loopid.experiments.report)

A cell file exists only once its cell has finished, so a killed run loses nothing finished, and
rerunning the same command skips the finished cells. A finished cell with a file that cannot be
read (:meth:`RunDir.finished`: truncated, a bad checksum) counts as unfinished: its files are
moved to ``cells/damaged/``, one line on stderr names the file, and the cell is computed again
(its table is the same: a cell's rows depend on its configuration and seeds alone). A
directory whose ``config.toml`` differs
from the new run's configuration is refused rather than mixed; where only the readings differ
(a run made under another preset), the refusal says which ``--readings`` continues it.
"""

import os
import sys
import tomllib
from functools import partial
from pathlib import Path

import pyarrow as pa
import tomli_w

from loopid.experiments import artifacts
from loopid.experiments.chunks import ChunkFiles
from loopid.experiments.families import Family, family_called, scenario_names
from loopid.experiments.results import concat, metadata, read_table
from loopid.experiments.seeds import seeds_from_value, seeds_value
from loopid.files import replace_atomically, write_atomic


def to_toml(config: dict) -> str:
    """``config`` (tables of TOML values) as TOML text (tomli-w)."""
    return tomli_w.dumps(config)


def config_family(config: dict) -> Family:
    """The family of a ``config.toml`` (its ``[run] family``; a file without one: the family
    whose packaged scenarios its scenario tables name). ``ValueError`` naming an unknown one."""
    name = config.get("run", {}).get("family")
    if name is not None:
        return family_called(name)
    names = scenario_names()
    found = {names[s].name: names[s] for s in config.get("scenario", {}) if s in names}
    if len(found) != 1:
        raise ValueError(
            "config.toml names no family ([run] family) and its scenarios are not one family's"
        )
    return next(iter(found.values()))


def normalized(config: dict) -> dict:
    """``config`` in today's form: its seeds as :func:`seeds_value` writes them (older
    ``config.toml`` files list them all), and each scenario table as its family normalises it
    (:meth:`~loopid.experiments.families.base.Family.normalize`: fields an older file lacks
    spelled out with the values it ran)."""
    run = dict(config.get("run", {}))
    if "seeds" in run:
        run["seeds"] = seeds_value(seeds_from_value(run["seeds"]))
    scenarios = config.get("scenario", {})
    if scenarios:
        family = config_family(config)
        scenarios = {name: family.normalize(dict(s)) for name, s in scenarios.items()}
    return {**config, "run": run, "scenario": scenarios}


class RunDir:
    """A run directory (see the module docstring)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.cells = self.path / "cells"

    def prepare(self, config: dict, create: bool = True) -> None:
        """Check that an existing directory holds a run of the same ``config`` (``ValueError``
        otherwise); ``create``: also create the directory and its ``config.toml`` now (else
        :meth:`ensure` does when the first result is saved)."""
        cfg_file = self.path / "config.toml"
        if cfg_file.exists():
            old = tomllib.loads(cfg_file.read_text())
            new = tomllib.loads(to_toml(config))
            old, new = normalized(old), normalized(new)
            if old != new:
                hint = config_family(new).continue_hint(old, new)
                if hint is not None:
                    raise ValueError(
                        f"{self.path} holds a run made under other readings; continue it with "
                        f"{hint}, or use another --out directory"
                    )
                raise ValueError(
                    f"{self.path} holds a run with a different configuration; "
                    "use another --out directory"
                )
            return
        if create:
            self.ensure(config)

    def exists(self) -> bool:
        return (self.path / "config.toml").is_file()

    def ensure(self, config: dict) -> None:
        """Create the directory, ``cells/`` and ``config.toml`` if they are not there yet."""
        cfg_file = self.path / "config.toml"
        if cfg_file.exists():
            return
        self.cells.mkdir(parents=True, exist_ok=True)
        replace_atomically(cfg_file, lambda tmp: tmp.write_text(to_toml(config)))

    def cell_file(self, scenario: str, method: str) -> Path:
        return self.cells / f"{scenario}__{method}.parquet"

    def done(self, scenario: str, method: str) -> bool:
        return self.cell_file(scenario, method).exists()

    def finished(self, scenario: str, method: str) -> bool:
        """Whether the cell is finished with every file readable (its rows read whole,
        :func:`loopid.experiments.artifacts.check`). A finished cell with a damaged file is
        not: its files go to ``cells/damaged/`` (its rows first, so that a rerun killed
        midway finds the cell unfinished), and one line on stderr names the file. An
        unfinished cell's saved chunks are checked alike, a damaged one moved aside."""
        if not self.done(scenario, method):
            files = ChunkFiles(self.cells, scenario, method)
            for part in files.finished():
                stem = files.stem(*part)
                rows, npz = stem.with_suffix(".parquet"), stem.with_suffix(".npz")
                check = partial(artifacts.check_npz, npz)
                self._set_aside(check, rows, npz, prefix=files.path.name)
            return False
        rows = self.cell_file(scenario, method)
        npz, meta = artifacts.paths(self.cells, scenario, method)
        check = partial(artifacts.check, self.cells, scenario, method)
        return not self._set_aside(check, rows, npz, meta)

    def _set_aside(self, check, rows: Path, *others: Path, prefix: str = "") -> bool:
        """Read ``rows`` whole and run ``check()``; when either finds a file damaged, move
        ``rows`` then ``others`` to ``cells/damaged/`` (names prefixed ``prefix.``), say so on
        stderr and return True."""
        try:
            try:
                read_table(rows)
            except (OSError, ValueError, pa.ArrowException) as e:
                raise artifacts.Damaged(rows, str(e)) from None
            check()
        except artifacts.Damaged as e:
            if not rows.exists():  # another run into the directory merged or moved it meanwhile
                return True
            aside = self.cells / "damaged"
            aside.mkdir(exist_ok=True)
            # a file damaged before keeps its copy there: the later one is numbered
            names = [f"{prefix}.{f.name}" if prefix else f.name for f in (rows, *others)]
            k = 1
            while any((aside / _numbered(name, k)).exists() for name in names):
                k += 1
            for f, name in zip((rows, *others), names, strict=True):
                try:
                    os.replace(f, aside / _numbered(name, k))
                except FileNotFoundError:
                    pass
            print(
                f"loopid: warning: {str(e.path)!r} is damaged ({e.why}); moved it to "
                f"{str(aside)!r} with the files that go with it, to be computed again",
                file=sys.stderr,
            )
            return True
        return False

    def check_artifacts(self) -> None:
        """Raise :class:`~loopid.experiments.artifacts.Damaged` naming the first finished cell
        file that cannot be read (what ``loopid plot`` checks before it draws anything)."""
        for rows in sorted(self.cells.glob("*__*.parquet")):
            scenario, method = rows.stem.split("__", 1)
            artifacts.check(self.cells, scenario, method)

    def save_cell(self, scenario: str, method: str, table: pa.Table) -> None:
        write_atomic(table, self.cell_file(scenario, method))

    def write_results(self, order: list[tuple[str, str]], save: bool = True) -> pa.Table:
        """Concatenate the finished cells in ``order`` into ``results.parquet`` (``save``);
        return it."""
        table = concat([read_table(self.cell_file(s, m)) for s, m in order if self.done(s, m)])
        if save:
            write_atomic(table, self.path / "results.parquet")
        return table

    def cell_metadata(self, scenario: str, method: str) -> dict[str, str]:
        """What a finished cell recorded besides its rows (``wall_s``, ``first_s``: seconds)."""
        return metadata(self.cell_file(scenario, method))


def _numbered(name: str, k: int) -> str:
    """``name`` the first time a file of that name is set aside, then ``name.k`` (``k`` ≥ 2)."""
    return name if k == 1 else f"{name}.{k}"
