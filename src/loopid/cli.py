"""The ``loopid`` command line (typer).

- ``loopid reproduce [--out DIR] [--seeds N] [--quick] [--quiet] [--executor local|ray]
  [--ray-address ADDR] [--workers N]``: every panel of the paper's Figure 2 and every method,
  at protocol scale (``--quick``: every panel and method at 2 seeds and 4 iterations, a smoke run).
- ``loopid run SCENARIO [--methods a,b] [--seeds N] [--iterations N] [--samples N]
  [--test-trajectories N] [--config FILE] [--out DIR] [--quiet] [--executor local|ray]
  [--ray-address ADDR] [--workers N]``: one panel (or part of it). ``--config`` is a TOML
  file of scenario fields (and ``methods``); options given on the command line win over it.
  ``loopid run gym --config FILE``: any Gymnasium environment
  (:mod:`loopid.experiments.gym_config`).
- ``loopid study [--out DIR] [--seeds N] [--quick] [--reproduce RUN_DIR] [--workers N]
  [--executor local|ray]``: every reading of SPEC §5, one factor at a time
  (:mod:`loopid.experiments.study`).
- ``loopid plot DIR``: remake ``figure.png`` and ``report.md`` from ``DIR/results.parquet``.
- ``loopid --version``.

A run directory holds ``config.toml``, ``results.parquet``, ``figure.png`` and ``report.md``
(and ``cells/``, one file per finished cell: rerunning a command resumes it). Bad input exits
with code 2 and one line naming the bad value; nothing is written then.
"""

import sys
import time
from pathlib import Path

import typer

import loopid

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help=__doc__, pretty_exceptions_enable=False
)

#: ``--quick``: every panel and method, 2 seeds, 4 iterations, 10 test trajectories.
QUICK = {"iterations": 4, "test_trajectories": 10, "seeds": 2}
ALL_METHODS = "dagger-t,dagger-e,dagger-en,batch-t,batch-e,batch-en,abbeel,expert,pg"


def _version(value: bool) -> None:
    if value:
        typer.echo(f"loopid {loopid.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """loopid: closed-loop system identification and model-based control."""


class _Output:
    """Progress and log lines for a run.

    On a terminal: one rich progress bar per running cell (iterations, elapsed, ETA; cells
    running at once share one display) and a line per finished cell. Not a terminal
    (CI logs): the lines only. ``--quiet``: nothing but errors.
    """

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.bars = None
        self.console = None
        if not quiet and sys.stderr.isatty():
            from rich.console import Console

            self.console = Console(stderr=True)

    def log(self, line: str) -> None:
        if self.quiet:
            return
        if self.console is not None:
            self.console.print(line, markup=False, highlight=False)
        else:
            typer.echo(line, err=True)

    def on_cell(self, scenario: str, method: str, iterations: int):
        if self.console is None:
            return None
        if self.bars is None:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.bars = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("iterations"),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=self.console,
                transient=True,
            )
            self.bars.start()
        bars = self.bars
        task = bars.add_task(f"{scenario} / {method}", total=iterations)

        def advance(n, row):
            bars.update(task, completed=n)
            if n >= iterations:
                bars.remove_task(task)

        return advance

    def close(self) -> None:
        if self.bars is not None:
            self.bars.stop()
            self.bars = None


def _methods(text: str, s=None) -> list[str]:
    """Parse a comma-separated method list; check it against scenario ``s`` (default: the
    helicopter's nine methods)."""
    from loopid.algorithms.methods import check_method
    from loopid.experiments.runner import check_methods

    names = [m.strip() for m in text.split(",") if m.strip()]
    if not names:
        raise ValueError("--methods is empty; give a comma-separated list")
    if s is not None:
        check_methods(s, names)
    else:
        for m in names:
            check_method(m)
    return names


def _write_outputs(out: Path, table, command_s: float | None = None) -> None:
    """``figure.png`` and ``report.md`` of a run directory: the paper's Figure 2 and findings,
    or the finite-MDP figure and report when the table holds only MDP scenarios."""
    import numpy as np

    from loopid.experiments.mdp import MDP_SCENARIOS, mdp_figure, mdp_report
    from loopid.experiments.plots import figure
    from loopid.experiments.report import write_report
    from loopid.experiments.results import write_atomic_bytes

    names = set(np.asarray(table.column("scenario").to_numpy(zero_copy_only=False)).tolist())
    if names and names <= set(MDP_SCENARIOS):
        mdp_figure(table, out / "figure.png")
        write_atomic_bytes(mdp_report(table).encode(), out / "report.md")
    else:
        figure(table, out / "figure.png")
        write_report(out, table, command_s=command_s)


def _finish(out: Path, table, t0: float, output: _Output) -> None:
    """Draw ``figure.png`` and write ``report.md`` from the table just written."""
    _write_outputs(out, table, time.perf_counter() - t0)
    output.log(f"wrote {table.num_rows} rows, figure.png and report.md to {out}/")


def _workers(executor: str, workers: int | None) -> int:
    """``--workers``: the local executor's worker processes (default: one per CPU, at most 4)."""
    from loopid.experiments.executors import check_workers, default_workers

    if workers is None:
        return default_workers() if executor == "local" else 1
    if executor != "local":
        raise ValueError(f"--workers {workers} applies to --executor local, not {executor!r}")
    return check_workers(workers)


def _execute(out, scenarios, methods, *, quiet, executor, ray_address, workers, t0) -> None:
    from loopid.experiments.execute import run_cells

    output = _Output(quiet)
    try:
        table = run_cells(
            out,
            scenarios,
            methods,
            executor_name=executor,
            ray_address=ray_address,
            workers=workers,
            on_cell=output.on_cell,
            log=output.log,
        )
    finally:
        output.close()
    _finish(out, table, t0, output)


EXECUTOR = typer.Option("local", "--executor", help="local (this machine) or ray.")
WORKERS = typer.Option(
    None,
    "--workers",
    help="local: worker processes, one cell each at a time (default: one per CPU, at most 4; "
    "1 = in this process).",
)
RAY_ADDRESS = typer.Option(
    None, "--ray-address", help="Join this Ray cluster (default: start a local one)."
)
QUIET = typer.Option(False, "--quiet", help="No progress output (errors only).")
SEEDS = typer.Option(None, "--seeds", help="Number of seeds (default 20; --quick 2).")


def _protocol_changes(quick: bool, seeds: int | None) -> dict:
    """The scenario fields ``--quick`` and ``--seeds`` change on the paper's panels."""
    changes = dict(QUICK) if quick else {}
    if seeds is not None:
        changes["seeds"] = seeds
    return changes


@app.command()
def run(
    scenario: str = typer.Argument(..., help="hover, hover-delay, funnel, or gym (--config)."),
    methods: str = typer.Option(
        None, "--methods", help=f"Comma-separated methods (default: all, {ALL_METHODS})."
    ),
    seeds: int = typer.Option(None, "--seeds", help="Number of seeds (default: the scenario's)."),
    iterations: int = typer.Option(None, "--iterations", help="Iterations N (default: SPEC's)."),
    samples: int = typer.Option(None, "--samples", help="Samples per iteration m."),
    test_trajectories: int = typer.Option(None, "--test-trajectories", help="Per evaluation."),
    config: Path = typer.Option(
        None, "--config", help="TOML file of scenario fields (and methods) to override."
    ),
    out: Path = typer.Option(None, "--out", help="Run directory (default: runs/SCENARIO)."),
    quiet: bool = QUIET,
    executor: str = EXECUTOR,
    ray_address: str = RAY_ADDRESS,
    workers: int = WORKERS,
) -> None:
    """Run one scenario's methods on every seed into a run directory."""
    t0 = time.perf_counter()
    out = Path("runs") / scenario if out is None else out
    options = dict(
        seeds=seeds, iterations=iterations, samples=samples, test_trajectories=test_trajectories
    )
    options = {k: v for k, v in options.items() if v is not None}
    if scenario == "gym":
        given = [f"--{k.replace('_', '-')}" for k in options] + (["--methods"] if methods else [])
        given += ["--executor"] if executor != "local" or ray_address else []
        given += ["--workers"] if workers is not None else []
        if given:
            raise ValueError(
                f"loopid run gym takes its settings from --config; remove {', '.join(given)}"
            )
        if config is None:
            raise ValueError("loopid run gym needs --config FILE (see examples/pendulum.toml)")
        _run_gym(config, out, quiet)
        return

    from loopid.experiments.executors import check_executor
    from loopid.experiments.mdp import MDP_SCENARIOS
    from loopid.experiments.runner import scenario_methods
    from loopid.experiments.scenarios import read_config
    from loopid.experiments.scenarios import scenario as make_scenario

    check_executor(executor, ray_address)
    workers = _workers(executor, workers)
    fields = read_config(config) if config is not None else {}
    chosen = fields.pop("methods", None)
    if scenario in MDP_SCENARIOS:
        if "test_trajectories" in options:
            raise ValueError("--test-trajectories does not apply to MDP scenarios (J is exact)")
        s = MDP_SCENARIOS[scenario].replace(**(fields | options))
    else:
        s = make_scenario(scenario, **(fields | options))
    if methods is not None:
        chosen = _methods(methods, s)
    elif chosen is not None:
        chosen = _methods(",".join(chosen), s)
    else:
        chosen = list(scenario_methods(s))
    _execute(
        out,
        [s],
        chosen,
        quiet=quiet,
        executor=executor,
        ray_address=ray_address,
        workers=workers,
        t0=t0,
    )


def _run_gym(config: Path, out: Path, quiet: bool) -> None:
    try:
        from loopid.experiments.gym_config import run_gym_config
    except ImportError:
        raise ValueError("the gym scenario needs loopid.experiments.gym_config") from None
    output = _Output(quiet)
    table = run_gym_config(config, out, quiet=quiet, log=output.log)
    output.log(f"wrote {table.num_rows} rows to {out}/")


@app.command()
def reproduce(
    out: Path = typer.Option(Path("runs/reproduce"), "--out", help="Run directory."),
    seeds: int = SEEDS,
    quick: bool = typer.Option(
        False, "--quick", help="Smoke run: every panel and method, 2 seeds, 4 iterations."
    ),
    quiet: bool = QUIET,
    executor: str = EXECUTOR,
    ray_address: str = RAY_ADDRESS,
    workers: int = WORKERS,
) -> None:
    """The paper's Figure 2: hover, hover with delay 1 and the nose-in funnel, every method."""
    from loopid.experiments.executors import check_executor
    from loopid.experiments.scenarios import SCENARIOS

    t0 = time.perf_counter()
    check_executor(executor, ray_address)
    workers = _workers(executor, workers)
    changes = _protocol_changes(quick, seeds)
    scenarios = [s.replace(**changes) for s in SCENARIOS.values()]
    _execute(
        out,
        scenarios,
        _methods(ALL_METHODS),
        quiet=quiet,
        executor=executor,
        ray_address=ray_address,
        workers=workers,
        t0=t0,
    )
    # the extra figure: the finite-MDP study, where the paper's bounds are exact
    from loopid.experiments.mdp import MDP_METHODS, MDP_SCENARIOS

    mdp_changes = {k: v for k, v in changes.items() if k in ("iterations", "seeds")}
    mdp = [MDP_SCENARIOS[name].replace(**mdp_changes) for name in ("mdp-random", "mdp-trap")]
    _execute(
        out / "mdp",
        mdp,
        list(MDP_METHODS),
        quiet=quiet,
        executor=executor,
        ray_address=ray_address,
        workers=workers,
        t0=t0,
    )


@app.command()
def study(
    out: Path = typer.Option(Path("runs/study"), "--out", help="Study directory."),
    seeds: int = SEEDS,
    quick: bool = typer.Option(
        False, "--quick", help="Smoke run: every reading, 2 seeds, 4 iterations."
    ),
    reproduce_dir: Path = typer.Option(
        None,
        "--reproduce",
        help="A loopid reproduce run directory (e.g. runs): its finished cells of the same "
        "configuration and seeds are copied, not recomputed.",
    ),
    quiet: bool = QUIET,
    executor: str = EXECUTOR,
    ray_address: str = RAY_ADDRESS,
    workers: int = WORKERS,
) -> None:
    """Every reading of the paper's open details (SPEC 5), one factor at a time: study.md,
    study.parquet and one figure per reading family."""
    from loopid.experiments.execute import check_cells, resolved_config, run_cells
    from loopid.experiments.executors import check_executor
    from loopid.experiments.results import write_atomic
    from loopid.experiments.rundir import RunDir
    from loopid.experiments.scenarios import SCENARIOS
    from loopid.experiments.study import (
        funnel_prediction_lines,
        share_cells,
        study_cells,
        study_table,
        write_outputs,
    )

    t0 = time.perf_counter()
    check_executor(executor, ray_address)
    workers = _workers(executor, workers)
    changes = _protocol_changes(quick, seeds)
    base = {name: s.replace(**changes) for name, s in SCENARIOS.items()}
    scenarios, methods = study_cells(base)
    seed_list = check_cells(scenarios, methods, None)
    if reproduce_dir is not None and not (reproduce_dir / "config.toml").is_file():
        raise ValueError(f"--reproduce {str(reproduce_dir)!r} holds no config.toml")
    output = _Output(quiet)
    RunDir(out).prepare(resolved_config(scenarios, methods, seed_list))
    if reproduce_dir is not None:
        shared = share_cells(out, reproduce_dir, scenarios, seed_list)
        output.log(f"{len(shared)} cells shared with {reproduce_dir}")
    try:
        table = run_cells(
            out, scenarios, methods, executor_name=executor, ray_address=ray_address,
            workers=workers, on_cell=output.on_cell, log=output.log,
        )  # fmt: skip
    finally:
        output.close()
    readings = study_table(table, base)
    write_atomic(readings, out / "study.parquet")
    prediction = funnel_prediction_lines(base["funnel"])
    write_outputs(out, readings, base, command_s=time.perf_counter() - t0, prediction=prediction)
    output.log(f"wrote study.parquet ({readings.num_rows} rows), study.md and figures to {out}/")


@app.command()
def plot(
    run_dir: Path = typer.Argument(..., help="A run directory holding results.parquet."),
) -> None:
    """Remake DIR/figure.png and DIR/report.md from DIR/results.parquet (nothing is rerun)."""
    from loopid.experiments.plots import load_results

    _write_outputs(run_dir, load_results(run_dir))
    typer.echo(f"wrote {run_dir / 'figure.png'} and {run_dir / 'report.md'}", err=True)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: user errors exit 2 with one line, never a traceback."""
    from loopid.experiments.executors import compile_cache

    compile_cache()
    try:
        code = app(args=argv, standalone_mode=False)
    except typer.Abort:
        typer.echo("loopid: aborted", err=True)
        sys.exit(130)
    except (typer.TyperException, ValueError) as e:
        message = e.format_message() if hasattr(e, "format_message") else str(e)
        if not message.strip():  # no arguments: the help was printed
            sys.exit(2)
        typer.echo(f"loopid: error: {' '.join(message.split())}", err=True)
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)
