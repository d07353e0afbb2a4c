"""The paper's commands: ``loopid reproduce`` (the paper's Figure 2, with the finite-MDP study
beside it) and ``loopid study`` (every reading of the details the paper leaves open, one at a
time).
"""

import time
from pathlib import Path

import typer

from loopid.experiments.commands import (
    EXECUTOR,
    MEMORY,
    QUIET,
    RAY_ADDRESS,
    WORKERS,
    Output,
    execute_runs,
    workers_for,
)

#: --quick: every panel and every method of Figure 2, 2 seeds, 4 iterations, 10 test
#: trajectories.
QUICK = {"iterations": 4, "test_trajectories": 10, "seeds": 2}


def figure2_methods(scenario) -> list[str]:
    """The methods ``loopid reproduce`` runs on a panel of Figure 2: every method on the hover
    panels; on the funnel every method but the policy gradient. Figure 2's caption names D_t,
    D_e, D_en, B_t, B_e, B_en, A and L; the paper's two sentences on the policy gradient stand in
    its hover paragraph, and finding 5 is judged on the hover panels. ``loopid run funnel
    --methods pg`` and ``loopid study`` still fly it on the funnel."""
    from loopid.experiments.families.helicopter.methods import METHODS
    from loopid.systems.helicopter.tasks import is_hover

    return [m for m in METHODS if m != "pg" or is_hover(scenario.task)]


SEEDS = typer.Option(None, "--seeds", help="Number of seeds (default 20; --quick 2).")


READINGS = typer.Option(
    None,
    "--readings",
    help="Preset of the readings of the details the paper leaves open: probable (the default: "
    "delay_mode=latency, funnel_nominal=heading, pg_samples=rollouts, pg_update=descent, "
    "nu_t_center=nominal) or literal (fifo, spec, transitions, conservative, target). It "
    "overrides --config; --set overrides it.",
)


def _protocol_changes(quick: bool, seeds: int | None) -> dict:
    """The scenario fields --quick and --seeds change on the paper's panels."""
    changes = dict(QUICK) if quick else {}
    if seeds is not None:
        changes["seeds"] = seeds
    return changes


def reproduce(
    out: Path = typer.Option(Path("runs/reproduce"), "--out", help="Run directory."),
    seeds: int = SEEDS,
    quick: bool = typer.Option(
        False, "--quick", help="Smoke run: every panel and method, 2 seeds, 4 iterations."
    ),
    readings: str = READINGS,
    quiet: bool = QUIET,
    executor: str = EXECUTOR,
    ray_address: str = RAY_ADDRESS,
    workers: int = WORKERS,
    memory: float = MEMORY,
) -> None:
    """The paper's Figure 2 (hover, hover with delay 1, the nose-in funnel; every method, the
    policy gradient on the hover panels) in OUT, and the finite-MDP study in OUT/mdp.
    --readings literal: under the literal readings of the paper's text instead of the probable
    ones."""
    from loopid.experiments.executors import check_executor
    from loopid.experiments.families import family_called
    from loopid.experiments.families.helicopter.readings import preset
    from loopid.experiments.families.helicopter.scenario import SCENARIOS

    t0 = time.perf_counter()
    check_executor(executor, ray_address)
    workers = workers_for(executor, workers)
    changes = _protocol_changes(quick, seeds)
    if readings is not None:
        changes.update(preset(readings))
    scenarios = [s.replace(**changes) for s in SCENARIOS.values()]
    # the extra figure: the finite-MDP study, where the paper's bounds are exact; its cells
    # run on the same workers, after the helicopter's
    mdp_changes = {k: v for k, v in changes.items() if k in ("iterations", "seeds")}
    mdp = family_called("mdp")
    mdps = [mdp.scenarios[n].replace(**mdp_changes) for n in ("mdp-random", "mdp-trap")]
    execute_runs(
        [(out, scenarios, {s.name: figure2_methods(s) for s in scenarios}),
         (out / "mdp", mdps, list(mdp.methods))],
        quiet=quiet, executor=executor, ray_address=ray_address, workers=workers,
        memory=memory, t0=t0,
    )  # fmt: skip


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
    memory: float = MEMORY,
) -> None:
    """Every reading of the paper's open details, one factor at a time from the probable
    readings, and the literal preset: study.md, study.parquet and one figure per group of
    readings."""
    from loopid.experiments.executors import check_executor
    from loopid.paper.study import run_study

    t0 = time.perf_counter()
    check_executor(executor, ray_address)
    workers = workers_for(executor, workers)
    output = Output(quiet)
    try:
        readings = run_study(
            out, _protocol_changes(quick, seeds), reproduce=reproduce_dir, executor=executor,
            ray_address=ray_address, workers=workers, memory=memory, on_cell=output.on_cell,
            log=output.log, started=t0,
        )  # fmt: skip
    finally:
        output.close()
    output.log(f"wrote study.parquet ({readings.num_rows} rows), study.md and figures to {out}/")


#: The paper's commands, in the order ``loopid --help`` lists them.
COMMANDS = (reproduce, study)
