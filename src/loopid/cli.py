"""The ``loopid`` command line (typer).

- ``loopid run SCENARIO [--methods a,b] [--seeds N] [--iterations N] [--samples N]
  [--test-trajectories N] [--out DIR] [--quiet]``: one panel (or part of it) into a run directory.
- ``loopid reproduce [--out DIR] [--seeds N] [--quick] [--quiet]``: every panel of the paper's
  Figure 2 and every method, at protocol scale (``--quick``: 2 seeds, a few iterations).
- ``loopid --version``.

Bad input exits with code 2 and one line naming the bad value; nothing is written then.
"""

import sys
from pathlib import Path

import typer

import loopid

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help=__doc__, pretty_exceptions_enable=False
)

QUICK = {"iterations": 4, "test_trajectories": 10}


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


def _progress(quiet: bool):
    """(on_cell, log) callbacks: a rich bar per cell on a terminal, one line per cell otherwise."""
    if quiet:
        return None, None

    def log(line: str) -> None:
        typer.echo(line, err=True)

    if not sys.stderr.isatty():
        return None, log
    from rich.progress import (
        BarColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    def on_cell(scenario: str, method: str, iterations: int):
        bar = Progress(
            TextColumn(f"{scenario} / {method}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            transient=True,
        )
        task = bar.add_task("cell", total=iterations)
        bar.start()

        def advance(n, row):
            bar.update(task, completed=n)
            if n >= iterations:
                bar.stop()

        return advance

    return on_cell, log


def _methods(text: str) -> list[str]:
    from loopid.algorithms.methods import check_method

    names = [m.strip() for m in text.split(",") if m.strip()]
    if not names:
        raise ValueError("--methods is empty; give a comma-separated list")
    for m in names:
        check_method(m)
    return names


def _execute(out: Path, scenarios, methods, quiet: bool) -> None:
    from loopid.experiments.execute import run_cells

    on_cell, log = _progress(quiet)
    table = run_cells(out, scenarios, methods, on_cell=on_cell, log=log)
    if not quiet:
        typer.echo(f"wrote {table.num_rows} rows to {out / 'results.parquet'}", err=True)


@app.command()
def run(
    scenario: str = typer.Argument(..., help="hover, hover-delay or funnel."),
    methods: str = typer.Option(
        "dagger-t,dagger-e,dagger-en,batch-t,batch-e,batch-en,abbeel,expert,pg",
        "--methods",
        help="Comma-separated methods.",
    ),
    seeds: int = typer.Option(None, "--seeds", help="Number of seeds (default: the scenario's)."),
    iterations: int = typer.Option(None, "--iterations", help="Iterations N (default: SPEC's)."),
    samples: int = typer.Option(None, "--samples", help="Samples per iteration m."),
    test_trajectories: int = typer.Option(None, "--test-trajectories", help="Per evaluation."),
    out: Path = typer.Option(Path("runs/run"), "--out", help="Run directory."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
) -> None:
    """Run one scenario's methods on every seed; write config.toml and results.parquet."""
    from loopid.experiments.scenarios import scenario as make_scenario

    overrides = {
        k: v
        for k, v in dict(
            seeds=seeds, iterations=iterations, samples=samples, test_trajectories=test_trajectories
        ).items()
        if v is not None
    }
    s = make_scenario(scenario, **overrides)
    _execute(out, [s], _methods(methods), quiet)


@app.command()
def reproduce(
    out: Path = typer.Option(Path("runs/reproduce"), "--out", help="Run directory."),
    seeds: int = typer.Option(None, "--seeds", help="Number of seeds (default 20; --quick 2)."),
    quick: bool = typer.Option(False, "--quick", help="Smoke run: 2 seeds, 4 iterations."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
) -> None:
    """The paper's Figure 2: hover, hover with delay 1 and the nose-in funnel, every method."""
    from loopid.algorithms.methods import METHODS
    from loopid.experiments.scenarios import SCENARIOS

    changes = dict(QUICK, seeds=2) if quick else {}
    if seeds is not None:
        changes["seeds"] = seeds
    scenarios = [s.replace(**changes) for s in SCENARIOS.values()]
    _execute(out, scenarios, list(METHODS), quiet)


def _compile_cache() -> None:
    """Turn on JAX's persistent compilation cache (``LOOPID_JAX_CACHE``, default
    ``~/.cache/loopid/jax``): a second run of the same cells skips most compilation."""
    import os

    import jax

    path = os.environ.get("LOOPID_JAX_CACHE", str(Path.home() / ".cache" / "loopid" / "jax"))
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: user errors exit 2 with one line, never a traceback."""
    _compile_cache()
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
