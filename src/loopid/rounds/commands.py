"""``loopid round init|update|export``: the command line of :mod:`loopid.rounds`.

Bad input (a config or a file that does not fit, a file or rows already given, a split far
from the plan) is a ``ValueError`` of one line: the ``loopid`` command prints it and exits with
code 2, and the round directory is left as it was. A warning about a file that was learned
from (:class:`~loopid.rounds.checks.RoundWarning`) is one line on stderr, ``loopid: warning:``.

What each command prints (a script reads stdout; stderr is for the person):

- ``init``: nothing on stdout; ``wrote DIR/controllers/round-001.npz and DIR/round.md`` on stderr.
- ``update``: one line on stdout, ``controller N: loss before the update … on nu rows, … on
  policy rows; … on all data after it``; ``wrote DIR/round.md`` on stderr.
- ``export``: the path written, alone on one line of stdout; nothing on stderr.
- a warning: ``loopid: warning: …``, one line on stderr (the update is learned).
- an error: ``loopid: error: …``, one line on stderr, exit code 2.
"""

import warnings
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
        ...,
        metavar="FILE",
        help="This round's transitions (.parquet, .pq, .csv, .csv.gz, .csv.bz2 or .csv.zst).",
    ),
    accept_split: bool = typer.Option(
        False,
        "--accept-split",
        help="Learn from FILE even if its split of policy and nu rows "
        "is far from round.md's plan (outside the 99.9 % binomial interval).",
    ),
) -> None:
    """One iteration: learn from FILE's transitions, solve the new model, write the next
    controller and DIR/round.md. A file already given, or one whose rows were all learned
    already, is refused; so is a split far from the plan, unless --accept-split."""
    from loopid import rounds
    from loopid.rounds.checks import RoundWarning
    from loopid.settings.checks import printable

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", RoundWarning)
        done = rounds.update(root, file, accept_split=accept_split)
    for w in said:
        if issubclass(w.category, RoundWarning):
            typer.echo(f"loopid: warning: {printable(w.message, None)}", err=True)
        else:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
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
    fmt: str = typer.Option(
        "c",
        "--format",
        help="json, npz or c (a C99 header) for the controller; model (JSON for a small "
        "system, else npz), model-json or model-npz for its identified A and B.",
    ),
    out: Path = typer.Option(
        None, "--out", help="Output file (default: DIR/controller-NNN.* or DIR/model-NNN.*)."
    ),
) -> None:
    """Write a controller, ready to deploy: its gains, operating point and, as C, a function
    loopid_action(x, t, u) (with the model's loopid_A, loopid_B and loopid_predict), or its
    identified model A, B in the log's units. A controller that plans online (MPC) is not
    written as C. Prints the path written on stdout."""
    from loopid import rounds

    typer.echo(str(rounds.export(root, fmt, n, out)))
