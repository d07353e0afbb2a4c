"""loopid: closed-loop system identification and model-based control (Ross & Bagnell 2012).

Commands:

\b
  loopid run SCENARIO    one scenario's methods on every seed (loopid run --help lists the
                         scenarios of every family)
  loopid reproduce       the paper's Figure 2, every panel and method, and the finite-MDP study
  loopid study           every reading of the paper's open details, one at a time
  loopid evaluate DIR    the run's saved controllers on fresh test episodes
  loopid animate DIR     an animated GIF of saved policies flying
  loopid plot DIR        figure.png and report.md again from DIR/results.parquet
  loopid round ...       a system you run yourself, one round at a time: init a round
                         directory, update it with logged transitions, export the controller

A run directory holds config.toml, results.parquet, figure.png, report.md and cells/ (one file
per finished cell: rerunning a command resumes it). Bad input exits with code 2 and one line
naming the bad value; nothing is written then.
"""

import os
import sys
import time
from pathlib import Path

import typer

import loopid
from loopid.experiments.commands import (
    EXECUTOR,
    MEMORY,
    QUIET,
    RAY_ADDRESS,
    WORKERS,
    execute_runs,
    method_list,
    workers_for,
)
from loopid.experiments.families import families
from loopid.paper.commands import COMMANDS as PAPER_COMMANDS
from loopid.rounds.commands import round_app

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help=__doc__,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain text: click wraps paragraphs, keeps blocks marked \b as they are
)
app.add_typer(round_app, name="round")


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


def scenario_from_options(
    name: str,
    config: Path | None,
    options: dict,
    assignments: list[str],
    readings: str | None = None,
):
    """The scenario ``loopid run NAME`` runs, and its methods (None: the family's default).

    Fields come from the family's named scenario, then the --config file, then the --readings
    preset, then --set FIELD=VALUE, then the common options (--seeds, --iterations, ...): later
    ones win. An option whose field the family does not have is refused with one line."""
    from loopid.experiments.families import family_named
    from loopid.settings.toml import parse_assignment

    family = family_named(name)
    fields, methods = family.read_file(config) if config is not None else ({}, None)
    allowed = family.field_names()
    if readings is not None:
        fields.update(_preset(readings, family, name))
    for text in assignments:
        key, value = parse_assignment(text)
        if key not in allowed:
            raise ValueError(
                f"--set {key}: {name} has no field {key!r}; fields: {', '.join(allowed)}"
            )
        fields[key] = value
    for key, value in options.items():
        if key not in allowed:
            flag = "--" + key.replace("_", "-")
            raise ValueError(f"{flag} does not apply to {name} (a {family.name} scenario)")
        fields[key] = value
    return family, family.build(name, fields), methods


def _preset(readings: str, family, name: str) -> dict:
    """The fields of ``family``'s preset ``readings``
    (:attr:`~loopid.experiments.families.base.Family.presets`); one line for an unknown preset
    or a family without presets."""
    if not family.presets:
        with_presets = ", ".join(f.name for f in families().values() if f.presets)
        raise ValueError(
            f"--readings: {name} ({family.name} family) has no presets; the scenarios of "
            f"{with_presets} have"
        )
    if readings not in family.presets:
        raise ValueError(
            f"--readings: unknown preset {readings!r}; presets: {', '.join(family.presets)}"
        )
    return dict(family.presets[readings])


READINGS = typer.Option(
    None,
    "--readings",
    help="A preset of the scenario's family: a named set of field values ("
    + "; ".join(f"{f.name}: {', '.join(f.presets)}" for f in families().values() if f.presets)
    + "). It overrides --config; --set overrides it.",
)


def _scenario_list() -> str:
    """The registered scenario names, by family (for the help text)."""
    return "; ".join(
        f"{name}: {', '.join(f.scenarios or [f.name])}"
        + ("" if f.scenarios else f" ({f.name} with --config FILE)")
        for name, f in families().items()
    )


@app.command()
def run(
    scenario: str = typer.Argument(..., help="A scenario of any family: " + _scenario_list()),
    methods: str = typer.Option(
        None, "--methods", help="Comma-separated methods (default: the scenario's own)."
    ),
    seeds: int = typer.Option(None, "--seeds", help="Number of seeds (default: the scenario's)."),
    iterations: int = typer.Option(None, "--iterations", help="Iterations N."),
    samples: int = typer.Option(None, "--samples", help="Samples per iteration m."),
    test_trajectories: int = typer.Option(
        None, "--test-trajectories", help="Test trajectories per evaluation."
    ),
    config: Path = typer.Option(
        None,
        "--config",
        help="TOML file of scenario fields (and methods); gym needs one "
        "(examples/pendulum.toml). Options on the command line win over it.",
    ),
    assignments: list[str] = typer.Option(
        [],
        "--set",
        help="FIELD=VALUE: set any scenario field (repeatable), e.g. --set delay_mode=fifo.",
    ),
    readings: str = READINGS,
    out: Path = typer.Option(None, "--out", help="Run directory (default: runs/SCENARIO)."),
    quiet: bool = QUIET,
    executor: str = EXECUTOR,
    ray_address: str = RAY_ADDRESS,
    workers: int = WORKERS,
    memory: float = MEMORY,
) -> None:
    """Run one scenario's methods on every seed into a run directory.

    Every scenario takes the same options. Its fields come from its defaults, then --config
    FILE, then --readings PRESET, then --set FIELD=VALUE, then --seeds, --iterations, --samples
    and --test-trajectories (later ones win).
    """
    from loopid.experiments.executors import check_executor

    t0 = time.perf_counter()
    out = Path("runs") / scenario if out is None else out
    options = dict(
        seeds=seeds, iterations=iterations, samples=samples, test_trajectories=test_trajectories
    )
    options = {k: v for k, v in options.items() if v is not None}
    check_executor(executor, ray_address)
    workers = workers_for(executor, workers)
    family, s, chosen = scenario_from_options(scenario, config, options, assignments, readings)
    if methods is not None:
        chosen = method_list(methods)
    elif chosen is None:
        chosen = list(family.default_methods(s))
    execute_runs(
        [(out, [s], chosen)], quiet=quiet, executor=executor, ray_address=ray_address,
        workers=workers, memory=memory, t0=t0,
    )  # fmt: skip


for _command in PAPER_COMMANDS:  # the paper's reproduction, then the commands families add
    app.command()(_command)
for _family in families().values():
    for _command in _family.commands:
        app.command()(_command)


@app.command()
def evaluate(
    run_dir: Path = typer.Argument(..., help="A run directory (loopid run or reproduce)."),
    scenario: str = typer.Option(None, "--scenario", help="Only this scenario."),
    method: str = typer.Option(None, "--method", help="Only this method."),
    seed: int = typer.Option(None, "--seed", help="Only this seed."),
    episodes: int = typer.Option(
        None, "--episodes", help="Fresh test episodes per seed (default: the run's count)."
    ),
    env: str = typer.Option(None, "--env", help="gym runs: fly on this Gymnasium id instead."),
) -> None:
    """Fly a run's saved final controllers on fresh test episodes; print mean +- s.e. cost and
    append the rows to RUN_DIR/evaluate.parquet."""
    from loopid.experiments.evaluate import evaluate_run

    rows = evaluate_run(
        run_dir, scenario=scenario, method=method, seed=seed, episodes=episodes, env=env
    ).to_pylist()
    for r in rows:
        typer.echo(
            f"{r['scenario']} / {r['method']} / seed {r['seed']}: {r['mean']:.6g} +- "
            f"{r['se']:.3g} over {r['episodes']} episodes{' on ' + r['env'] if r['env'] else ''} "
            f"(the run recorded {r['recorded']:.6g})"
        )
    typer.echo(f"appended {len(rows)} rows to {run_dir / 'evaluate.parquet'}", err=True)


@app.command()
def animate(
    run_dir: Path = typer.Argument(..., help="A run directory (loopid run or reproduce)."),
    method: str = typer.Option(
        ..., "--method", help="Method(s) to fly, comma-separated (e.g. dagger-e,batch-e)."
    ),
    seed: int = typer.Option(0, "--seed", help="Whose saved policy, and the test noise of it."),
    scenario: str = typer.Option(None, "--scenario", help="Default: the run's first."),
    out: Path = typer.Option(None, "--out", help="GIF file (default: RUN_DIR/animation.gif)."),
) -> None:
    """An animated GIF of saved final policies flying: the helicopter's funnel from above (or the
    hover's position error) on the seed's first test trajectory, or a Gymnasium env's own
    rgb_array frames, the methods side by side."""
    from loopid.experiments.execute import run_family

    if not (run_dir / "config.toml").is_file():
        raise ValueError(f"{str(run_dir)!r} is not a run directory (no config.toml)")
    family, configs = run_family(run_dir)
    if family.animate is None:
        with_animation = ", ".join(f.name for f in families().values() if f.animate is not None)
        raise ValueError(
            f"loopid animate draws runs of the {with_animation} families, not {family.name} runs"
        )
    name = scenario or next(iter(configs))
    if name not in configs:
        raise ValueError(f"{run_dir} has no scenario {name!r}; it has {', '.join(configs)}")
    path = out or run_dir / "animation.gif"
    family.animate(run_dir, configs[name], method_list(method), seed, path)
    typer.echo(f"wrote {path}", err=True)


@app.command()
def plot(
    run_dir: Path = typer.Argument(..., help="A run directory holding results.parquet."),
) -> None:
    """Remake DIR/figure.png and DIR/report.md from DIR/results.parquet (nothing is rerun)."""
    from loopid.experiments.execute import write_outputs
    from loopid.experiments.results import load_results
    from loopid.experiments.rundir import RunDir

    table = load_results(run_dir)
    RunDir(run_dir).check_artifacts()  # a damaged cell named before anything is drawn
    write_outputs(run_dir, table)
    typer.echo(f"wrote {run_dir / 'figure.png'} and {run_dir / 'report.md'}", err=True)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: user errors exit 2 with one line, never a traceback."""
    from loopid.experiments.executors import compile_cache
    from loopid.settings.checks import printable

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
        typer.echo(f"loopid: error: {printable(message, None)}", err=True)
        sys.exit(2)
    except Exception as e:  # a failure, not bad input: one line (LOOPID_DEBUG=1 shows it all)
        if os.environ.get("LOOPID_DEBUG"):
            raise
        message = printable(e, 500) or "no message"
        if "RESOURCE_EXHAUSTED" in message or "Out of memory" in message:
            message = "out of memory; lower --memory, --workers or --seeds"
        typer.echo(f"loopid: error: {type(e).__name__}: {message}", err=True)
        sys.exit(1)
    sys.exit(code if isinstance(code, int) else 0)
