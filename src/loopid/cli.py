"""The ``loopid`` command line (typer)."""

from pathlib import Path

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


@app.command()
def reproduce(
    out: Path = typer.Option(Path("runs"), "--out", help="Directory for the run's summary."),
    seeds: int = typer.Option(4, "--seeds", min=1, help="Number of seeds (vmapped)."),
) -> None:
    """Reproduce the paper's figure (placeholder: for now an open-loop noisy hover rollout).

    What exists so far is the simulator, so this runs it honestly: 400 steps from hover trim
    with Δu = 0 and process noise std 1, one trajectory per seed (noise key = seed), and reports
    the mean total cost (SPEC §4.1). It will be replaced by the real reproduction.
    """
    import jax

    from loopid.systems import helicopter, tasks

    task = tasks.make_task("hover")
    keys = jax.vmap(jax.random.key)(jax.numpy.arange(seeds))
    noise = jax.vmap(lambda k: helicopter.noise_sequence(k, task.horizon, task.noise_std))(keys)
    dU = jax.numpy.zeros((seeds, task.horizon, helicopter.N_ACTION))
    X = helicopter.rollout(jax.numpy.tile(task.x0, (seeds, 1)), dU, noise, delay=task.delay)
    dX = jax.vmap(jax.vmap(helicopter.to_error), in_axes=(0, None))(X, task.target)
    costs = jax.vmap(tasks.trajectory_cost, in_axes=(0, 0, None, None))(dX, dU, task.Q, task.R)
    lines = [
        "loopid reproduce: placeholder (the DAgger reproduction is not wired in yet)",
        f"open-loop hover at trim, dU = 0, noise std {task.noise_std}, {task.horizon} steps, "
        f"seeds 0..{seeds - 1}",
        f"mean total cost {float(costs.mean()):.6g} (min {float(costs.min()):.6g}, "
        f"max {float(costs.max()):.6g})",
    ]
    out.mkdir(parents=True, exist_ok=True)
    (out / "hover_open_loop.txt").write_text("\n".join(lines) + "\n")
    for line in lines:
        typer.echo(line)
    typer.echo(f"written: {out / 'hover_open_loop.txt'}")


def main() -> None:
    """Console-script entry point."""
    app()
