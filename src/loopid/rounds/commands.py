"""``loopid round init|update|export``: the command line of :mod:`loopid.rounds`.

Bad input (a config or a file that does not fit, a file already given) is a ``ValueError`` of
one line: the ``loopid`` command prints it and exits with code 2, and the round directory is
left as it was.
"""

from pathlib import Path

import typer

round_app = typer.Typer(
    no_args_is_help=True,
    rich_markup_mode=None,
    help="Algorithm 1 one round at a time, for a system you run yourself: init a round "
    "directory, update it with each round's logged transitions, export the controller.",
)


@round_app.command("init")
def init(
    root: Path = typer.Argument(..., metavar="DIR", help="The round directory to start."),
    config: Path = typer.Option(
        ..., "--config", help="TOML file: [system], [cost], [model], [planner], [rounds]."
    ),
) -> None:
    """Solve the initial model, write controller 1 and DIR/round.md (what to collect next)."""
    from loopid import rounds

    path = rounds.init(root, config)
    typer.echo(f"wrote {path} and {root / 'round.md'}", err=True)


@round_app.command("update")
def update(
    root: Path = typer.Argument(..., metavar="DIR", help="The round directory."),
    file: Path = typer.Argument(
        ..., metavar="FILE", help="This round's transitions (.parquet or .csv)."
    ),
) -> None:
    """One iteration: learn from FILE's transitions, solve the new model, write the next
    controller and DIR/round.md. A file already given is refused."""
    from loopid import rounds

    done = rounds.update(root, file)
    r = done.row
    before = [f"{r[k]:.4g} on {w} rows" for k, w in (("loss_nu", "nu"), ("loss_policy", "policy"))
              if r[k] is not None]  # fmt: skip
    typer.echo(
        f"controller {done.round}: loss before the update {', '.join(before)}; "
        f"{r['loss_all']:.4g} on all data after it"
    )
    typer.echo(f"wrote {root / 'round.md'}", err=True)


@round_app.command("export")
def export(
    root: Path = typer.Argument(..., metavar="DIR", help="The round directory."),
    n: int = typer.Option(None, "--round", help="Which controller (default: the latest)."),
    fmt: str = typer.Option("c", "--format", help="json, npz or c (a C99 header)."),
    out: Path = typer.Option(None, "--out", help="Output file (default: DIR/controller-NNN.*)."),
) -> None:
    """Write a controller, ready to deploy: its gains, operating point and, as C, a function
    loopid_action(x, t, u). A controller that plans online (MPC) is not written as C."""
    from loopid import rounds

    typer.echo(str(rounds.export(root, fmt, n, out)))
