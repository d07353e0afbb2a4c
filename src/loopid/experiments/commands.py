"""What every command that runs cells shares: its options (``--executor``, ``--workers``,
``--ray-address``, ``--quiet``, ``--memory``), its progress display (:class:`Output`) and running
a list of runs into their directories (:func:`execute_runs`: the cells, then each directory's
``figure.png`` and ``report.md``). ``loopid run`` and the commands a family adds
(:attr:`loopid.experiments.families.base.Family.commands`) are built from these.
"""

import sys
import time

import typer


class Output:
    """Progress and log lines for a run.

    On a terminal: one rich progress bar per running cell (seeds × iterations done over all its
    chunks, elapsed, ETA; cells running at once share one display) and a line per finished
    cell. Not a terminal (CI logs): the lines only. ``--quiet``: nothing but errors.
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

    def on_cell(self, scenario: str, method: str, total: int):
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
                TextColumn("seed-iterations"),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=self.console,
                transient=True,
            )
            self.bars.start()
        bars = self.bars
        task = bars.add_task(f"{scenario} / {method}", total=total)

        def advance(done: int) -> None:
            bars.update(task, completed=done)
            if done >= total:
                bars.remove_task(task)

        return advance

    def close(self) -> None:
        if self.bars is not None:
            self.bars.stop()
            self.bars = None


def method_list(text: str) -> list[str]:
    """A comma-separated method list (checked against the scenario's family by run_cells)."""
    names = [m.strip() for m in text.split(",") if m.strip()]
    if not names:
        raise ValueError("--methods is empty; give a comma-separated list")
    return names


def workers_for(executor: str, workers: int | None) -> int:
    """--workers: the local executor's workers (default: one process per CPU, at most 4; on
    several GPUs one process per device; on one GPU 4 threads sharing it)."""
    from loopid.experiments.executors import check_workers, default_workers

    if workers is None:
        return default_workers() if executor == "local" else 1
    if executor != "local":
        raise ValueError(f"--workers {workers} applies to --executor local, not {executor!r}")
    return check_workers(workers)


def execute_runs(runs, *, quiet, executor, ray_address, workers, memory, t0):
    """Run the cells of each run, ``(out, scenarios, methods)``, into its out (the runs' cells
    given to the same workers), then draw each one's figure.png and write its report.md."""
    from loopid.experiments.execute import run_all, write_outputs

    output = Output(quiet)
    try:
        tables = run_all(
            runs, executor_name=executor, ray_address=ray_address,
            workers=workers, memory=memory, on_cell=output.on_cell, log=output.log,
        )  # fmt: skip
    finally:
        output.close()
    for (out, _, _), table in zip(runs, tables, strict=True):
        write_outputs(out, table, time.perf_counter() - t0)
        output.log(f"wrote {table.num_rows} rows, figure.png and report.md to {out}/")


EXECUTOR = typer.Option("local", "--executor", help="local (this machine) or ray.")
WORKERS = typer.Option(
    None,
    "--workers",
    help="local: workers, one cell each at a time: processes (default: one per CPU, at most 4; "
    "on several GPUs one per device) or, on one GPU, threads sharing it (default 4); 1 = in "
    "this process, in order.",
)
RAY_ADDRESS = typer.Option(
    None, "--ray-address", help="Join this Ray cluster (default: start a local one)."
)
QUIET = typer.Option(False, "--quiet", help="No progress output (errors only).")
MEMORY = typer.Option(
    None,
    "--memory",
    help="Memory budget in GB of the processes computing at once; a cell that does not fit runs "
    "in seed chunks (default: 60% of the memory available, less 1.5 GB per process).",
)
