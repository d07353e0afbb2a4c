"""What a kind of system gives the experiment pipeline: the :class:`Family` record.

A *family* is one kind of real system (the helicopter, finite MDPs, any Gymnasium env). The
pipeline above it (:mod:`loopid.experiments.execute`: cells, resume, atomic files, workers, Ray,
progress, ``report.md``, ``loopid plot``, the command line) knows nothing else about it. A family
module defines one frozen config dataclass and one :class:`Family`; the registry
(:mod:`loopid.experiments.families`) maps scenario names to families.

Every config dataclass has the fields ``name``, ``iterations``, ``samples`` and ``seeds`` (a
count, or for families that accept one, a tuple of seeds), validates itself when it is built
(``ValueError`` naming the bad field), and offers ``replace(**changes)`` and ``to_dict()`` (plain
TOML values; ``None`` left out). The helpers they share (checks, reading a ``--config`` file,
``--set key=value``) are in :mod:`loopid.experiments.config`.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import pyarrow as pa

from loopid.algorithms.loop import Row, Trace

#: ``progress(n, row)`` after iteration n of a cell.
Progress = Callable[[int, Row], None]


@dataclass(frozen=True)
class Family:
    """One kind of system, as the pipeline sees it.

    Attributes:
      name: the family's name (``helicopter``, ``mdp``, ``gym``), recorded in ``config.toml``.
      config: the frozen config dataclass of its scenarios.
      methods: every method it offers.
      scenarios: the named scenarios it ships (name -> config); may be empty (``gym`` is
        always built from a file).
      default_methods: ``default_methods(config) -> methods`` run when none are chosen.
      build: ``build(name, fields) -> config``: the named scenario (or, for a family without
        shipped scenarios, a new one) with ``fields`` set; ``ValueError`` on a bad field.
      read_file: ``read_file(path) -> (fields, methods or None)``: a ``--config`` TOML file.
      run: ``run(method, config, seeds, progress=None) -> Trace``: one cell, every seed at once
        (``seeds``: an integer array; ``progress`` is passed by keyword). Workers and Ray call
        it in other processes, so it must be importable there (a module-level function).
      figure: ``figure(table, path, configs)``: the run's ``figure.png``.
      report: ``report(table, configs) -> lines``: the family's sections of ``report.md``
        (Markdown lines), after the common header, configuration and wall time.
      check: ``check(config)``: checks that need the system itself (sizes against a Gymnasium
        env, say), run before anything is written; None when the config checks itself.
      shared: ``shared(config, method) -> {name: array}``: what a cell's seeds share and its
        artifacts keep beside their own arrays (the nominal model the learned offsets add to);
        None for nothing.
      load: ``load(config, method, arrays) -> (model, controller)``: one seed's saved final
        arrays (:mod:`loopid.experiments.artifacts`) rebuilt in the system's coordinates
        (:mod:`loopid.experiments.saved`); None when the family cannot.
      trajectories: ``trajectories(run_dir, configs, path)``: ``trajectories.png``, what each
        method's saved final policy flies; None when the family draws none.
      animate: ``animate(run_dir, config, methods, seed, path)``: an animated GIF of those
        policies flying; None when the family cannot.
      evaluate: ``evaluate(config, arrays, seeds, episodes, env) -> costs [S, episodes]``:
        saved policies on fresh test episodes (noise the run never saw; ``env``: another
        Gymnasium id, gym only); ``arrays``: the seeds' saved arrays (:mod:`.artifacts`),
        ``{name: [S, ...]}`` (the gains ``K``, and the model's parameters, which a saved MPC
        re-plans on) with the ``shared.*`` ones whole; None when the family cannot.
      memory: ``memory(config, method, seeds) -> bytes``: the peak memory of one cell's
        programs for that many seeds (:mod:`loopid.experiments.chunks` sizes chunks with it);
        None when the family's cells run unchunked (all seeds at once). A family with lane
        sets also takes a tuple of methods: the peak of their lane set.
      lane_sets: ``lane_sets(config, methods) -> [tuple of methods]``: the methods grouped as
        they can run together as one *lane set* (one compiled program over every (method,
        seed) pair: width an accelerator computes at the cost of one); None: each alone.
      run_lanes: ``run_lanes(methods, config, seeds, progress=None) -> {method: Trace}``: one
        group of ``lane_sets``, each method's trace the same numbers as ``run``'s;
        ``progress(n, row)`` with the row's leaves over the lanes. None without lane sets.
    """

    name: str
    config: type
    methods: tuple[str, ...]
    scenarios: Mapping[str, Any]
    default_methods: Callable[[Any], Sequence[str]]
    build: Callable[[str, dict], Any]
    read_file: Callable[[Path], tuple[dict, list[str] | None]]
    run: Callable[..., Trace]
    figure: Callable[[pa.Table, Path, Mapping[str, Any]], None]
    report: Callable[[pa.Table, Mapping[str, Any]], list[str]]
    check: Callable[[Any], None] | None = None
    shared: Callable[[Any, str], dict] | None = None
    load: Callable[[Any, str, dict], tuple[Any, Any]] | None = None
    evaluate: Callable[..., Any] | None = None
    trajectories: Callable[..., Any] | None = None
    animate: Callable[..., Any] | None = None
    memory: Callable[[Any, Any, int], int] | None = None
    lane_sets: Callable[[Any, Sequence[str]], list[tuple[str, ...]]] | None = None
    run_lanes: Callable[..., dict[str, Trace]] | None = None

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
