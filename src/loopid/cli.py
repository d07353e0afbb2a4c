"""The ``loopid`` command line (typer)."""

import typer

import loopid

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__)


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


def main() -> None:
    """Console-script entry point."""
    app()
