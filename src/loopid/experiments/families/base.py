"""What a kind of system gives the experiment pipeline: the :class:`Family` record.

A *family* is one kind of real system (the helicopter, finite MDPs, any Gymnasium env). The
pipeline above it (:mod:`loopid.experiments.execute`: cells, resume, atomic files, workers, Ray,
progress, ``report.md``, ``loopid plot``, the command line) knows nothing else about it. A family
module defines one frozen config dataclass and one subclass of :class:`Family`, an interface
that says which parts a family must give and which it may; the registry
(:mod:`loopid.experiments.families`, Python entry points) maps scenario names to families.

Every config dataclass has the fields ``name``, ``iterations``, ``samples`` and ``seeds`` (a
count, or for families that accept one, a tuple of seeds), validates itself when it is built
(``ValueError`` naming the bad field), and offers ``replace(**changes)`` and ``to_dict()`` (plain
TOML values; ``None`` left out). The helpers they share (checks, reading a ``--config`` file,
``--set key=value``) are in :mod:`loopid.settings.checks` and :mod:`loopid.settings.toml`.
"""

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any, ClassVar

import pyarrow as pa

from loopid.algorithms.contracts import Row, Trace

#: ``progress(n, row)`` after iteration n of a cell.
Progress = Callable[[int, Row], None]


class Family(ABC):
    """One kind of system, as the pipeline sees it: subclass it and give its parts.

    **Required.** A subclass that lacks one cannot be instantiated (``TypeError`` naming it):

    - ``name`` (class attribute): the family's name (``helicopter``, ``mdp``, ``gym``), recorded
      in ``config.toml``; ``config``: the frozen config dataclass of its scenarios;
      ``methods``: every method it offers.
    - :meth:`build`, :meth:`read_file`, :meth:`run`, :meth:`figure` and :meth:`report`.

    **Optional, with a default.** ``scenarios`` (the named scenarios it ships; default none:
    every scenario is built from a file, as ``gym``'s), :meth:`default_methods` (every
    method), :meth:`check` (nothing to check), :meth:`shared` (nothing shared),
    :meth:`lane_sets` (each method alone), :meth:`normalize` (an older ``config.toml``'s
    scenario table as it is), :meth:`continue_hint` (no hint), ``presets`` (none: ``loopid run
    --readings`` refuses its scenarios) and ``commands`` (none).

    **Optional capabilities.** ``None`` on this class; a family that offers one defines it as a
    method, and the pipeline says in one line what a family without it cannot do:

    - ``load(config, method, arrays) -> (model, controller)``: one seed's saved final arrays
      (:mod:`loopid.experiments.artifacts`) rebuilt in the system's coordinates
      (:mod:`loopid.experiments.saved`).
    - ``evaluate(config, arrays, seeds, episodes, env) -> costs [S, episodes]``: saved policies
      on fresh test episodes (noise the run never saw; ``env``: another Gymnasium id, gym only);
      ``arrays``: the seeds' saved arrays, ``{name: [S, ...]}`` (the gains ``K``, and the
      model's parameters, which a saved MPC re-plans on) with the ``shared.*`` ones whole.
    - ``trajectories(run_dir, configs, path)``: ``trajectories.png``, what each method's saved
      final policy flies; ``animate(run_dir, config, methods, seed, path)``: an animated GIF of
      them.
    - ``memory(config, method, seeds) -> bytes``: the peak memory of one cell's programs for that
      many seeds (:mod:`loopid.experiments.chunks` sizes chunks with it; without it a cell runs
      all its seeds at once). A family with :attr:`run_lanes` also takes a tuple of methods: the
      peak of their lane set.
    - ``run_lanes(methods, config, seeds, progress=None) -> {method: Trace}``: one group of
      :meth:`lane_sets` as one compiled program over every (method, seed) pair (width an
      accelerator computes at the cost of one), each method's trace the same numbers as
      :meth:`run`'s; ``progress(n, row)`` with the row's leaves over the lanes.
    """

    name: ClassVar[str]
    config: ClassVar[type]
    methods: ClassVar[tuple[str, ...]]
    scenarios: ClassVar[Mapping[str, Any]] = {}
    #: ``loopid run --readings NAME``: named sets of field values (``{name: {field: value}}``).
    presets: ClassVar[Mapping[str, Mapping[str, Any]]] = {}
    #: Commands the family adds to ``loopid`` (Typer command functions, named by their function
    #: name with ``_`` as ``-``), after ``loopid run``.
    commands: ClassVar[Sequence[Callable[..., None]]] = ()

    load: Callable[[Any, str, dict], tuple[Any, Any]] | None = None
    evaluate: Callable[..., Any] | None = None
    trajectories: Callable[..., Any] | None = None
    animate: Callable[..., Any] | None = None
    memory: Callable[[Any, Any, int], int] | None = None
    run_lanes: Callable[..., dict[str, Trace]] | None = None

    @abstractmethod
    def build(self, name: str, fields: dict) -> Any:
        """The named scenario (or, for a family without shipped scenarios, a new one) with
        ``fields`` set; ``ValueError`` naming a bad field."""

    @abstractmethod
    def read_file(self, path: Path) -> tuple[dict, list[str] | None]:
        """A ``--config`` TOML file: ``(fields, methods or None)``."""

    @abstractmethod
    def run(self, method: str, config, seeds, progress: Progress | None = None) -> Trace:
        """One cell, every seed at once (``seeds``: an integer array). Workers and Ray call it
        in other processes, which find the family by its config's type, so the family must be
        registered by a module they import."""

    @abstractmethod
    def figure(self, table: pa.Table, path: Path, configs: Mapping[str, Any]) -> None:
        """The run's ``figure.png``."""

    @abstractmethod
    def report(self, table: pa.Table, configs: Mapping[str, Any]) -> list[str]:
        """The family's sections of ``report.md`` (Markdown lines), after the common header,
        configuration and wall time."""

    def default_methods(self, config) -> Sequence[str]:
        """The methods run when none are chosen: every one."""
        return self.methods

    def check(self, config) -> None:  # noqa: B027  (optional: nothing to check by default)
        """Checks that need the system itself (sizes against a Gymnasium env, say), run before
        anything is written; ``ValueError`` naming the bad value."""

    def shared(self, config, method: str) -> dict:
        """What a cell's seeds share and its artifacts keep beside their own arrays (the
        nominal model the learned offsets add to): ``{name: array}``."""
        return {}

    def lane_sets(self, config, methods: Sequence[str]) -> list[tuple[str, ...]]:
        """``methods`` grouped by the compiled program they share (default: each alone). A family
        with :attr:`run_lanes` runs each group as one lane set; run one at a time, a group's
        cells still share their program, and an executor starts the group's later cells once
        its first has compiled it (:mod:`loopid.experiments.pool`)."""
        return [(m,) for m in methods]

    def normalize(self, fields: dict) -> dict:
        """A scenario table of a ``config.toml`` (plain TOML values) in today's form, so that a
        run directory written before a field existed compares equal to today's config of the
        same run (default: as it is)."""
        return fields

    def continue_hint(self, old: dict, new: dict) -> str | None:
        """When a run directory's ``config.toml`` (``old``, normalised) differs from the new
        run's (``new``): the command-line options that would continue the old run, or None
        (the default) when there are none."""
        return None

    def field_names(self) -> tuple[str, ...]:
        """The config dataclass's field names."""
        return tuple(f.name for f in fields(self.config))

    def check_methods(self, config, methods: Sequence[str]) -> None:
        """``ValueError`` naming the first method this family does not offer."""
        for m in methods:
            if m not in self.methods:
                raise ValueError(
                    f"unknown method {m!r} for {config.name}; choose from {', '.join(self.methods)}"
                )


class FunctionFamily(Family):
    """A family given as functions, one keyword per part of :class:`Family` (the required
    ``name``, ``config``, ``methods``, ``build``, ``read_file``, ``run``, ``figure`` and
    ``report``; any optional one), for a family written as a few functions in a script.
    ``default_methods(config)`` is a function here too."""

    def __init__(self, *, name, config, methods, build, read_file, run, figure, report, **parts):
        optional = {"scenarios", "default_methods", "check", "shared", "lane_sets", "presets"}
        optional |= {"commands", "normalize", "continue_hint"}
        optional |= {"load", "evaluate", "trajectories", "animate", "memory", "run_lanes"}
        unknown = sorted(set(parts) - optional)
        if unknown:
            raise TypeError(f"unknown part(s) of a family: {', '.join(unknown)}")
        self.name, self.config, self.methods = name, config, tuple(methods)
        self._required = {
            "build": build, "read_file": read_file, "run": run, "figure": figure,
            "report": report,
        }  # fmt: skip
        for part, value in parts.items():
            if value is not None:
                setattr(self, part, value)

    def build(self, name, fields):
        return self._required["build"](name, fields)

    def read_file(self, path):
        return self._required["read_file"](path)

    def run(self, method, config, seeds, progress=None):
        return self._required["run"](method, config, seeds, progress=progress)

    def figure(self, table, path, configs):
        return self._required["figure"](table, path, configs)

    def report(self, table, configs):
        return self._required["report"](table, configs)
