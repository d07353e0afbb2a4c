"""The learned model and controller of a run, reloaded: ``loopid.load(run_dir, scenario, method,
seed)``.

A run directory keeps, for every finished cell, the final policy and model of each seed
(:mod:`loopid.experiments.artifacts`). :func:`load` rebuilds them in the coordinates of the
system they were learned on (its family's ``load``, with the classes of
:mod:`loopid.experiments.learned`).

Every problem (no such run, scenario, method or seed; a missing or corrupt file) is a
``ValueError`` of one line naming it.
"""

from pathlib import Path
from typing import Any, NamedTuple

from loopid.experiments import artifacts


class Saved(NamedTuple):
    """A reloaded model and controller, with what they came from."""

    model: Any
    controller: Any
    scenario: Any
    method: str
    seed: int


def load(run_dir, scenario: str, method: str, seed: int) -> Saved:
    """The final model and controller of ``method`` at ``seed`` in ``run_dir``'s ``scenario``.

    ``model`` is None for methods without one (``expert``, ``pg``)."""
    from loopid.experiments.execute import run_family

    run_dir = Path(run_dir)
    if not (run_dir / "config.toml").is_file():
        raise ValueError(f"{str(run_dir)!r} is not a run directory (no config.toml)")
    family, configs = run_family(run_dir)
    if scenario not in configs:
        raise ValueError(f"{run_dir} has no scenario {scenario!r}; it has {', '.join(configs)}")
    if family.load is None:
        raise ValueError(f"the {family.name} family saves no models and controllers")
    _, arrays = artifacts.read(run_dir / "cells", scenario, method)
    one = artifacts.for_seed(arrays, seed, f"{scenario}/{method}")
    model, controller = family.load(configs[scenario], method, one)
    return Saved(model, controller, configs[scenario], method, int(seed))
