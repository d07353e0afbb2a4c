"""The "Add a new kind of system" guide's example runs, and does what the guide says it does.

The first ``python`` block under that heading is executed as a script (``__name__ ==
"__main__"``, in a temporary directory), exactly as a reader would run ``python mylinear.py``: it
defines a family for the linear-Gaussian system, registers it, runs DAgger and Batch into
``runs/linear`` and writes ``figure.png`` and ``report.md``. The checks: the family is in the
registry and the command line's option layer builds its configs; the run directory is complete
and records the family; running the same cells again resumes to the same table; and, since the
system is inside the model class, DAgger and Batch end at the optimal LQR policy's test cost.
"""

import os
import re
import tomllib
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop_program import noise_program
from loopid.experiments.execute import run_cells
from loopid.experiments.families import families, family_named, family_of
from loopid.experiments.results import read_table

pytestmark = pytest.mark.slow  # about 40 s on 2 cores, nearly all compiling the guide's cell

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "new-system.md"
HEADING = "# Add a new kind of system"


def guide_block() -> str:
    """The first ```python block after the heading (and before the next ``## `` heading)."""
    text = GUIDE.read_text(encoding="utf-8")
    assert text.count(HEADING + "\n") == 1, f"the guide has no single {HEADING!r} section"
    section = text.split(HEADING + "\n", 1)[1]
    section = re.split(r"^## ", section, maxsplit=1, flags=re.MULTILINE)[0]
    match = re.search(r"^```python\n(.*?)^```$", section, flags=re.MULTILINE | re.DOTALL)
    assert match, f"no python block under {HEADING!r}"
    return match.group(1)


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """The guide's block run as a script in a fresh directory: ``(namespace, its directory)``.
    The family it registers is taken out of the registry afterwards."""
    home = tmp_path_factory.mktemp("guide")
    code = compile(guide_block(), str(GUIDE), "exec")
    namespace = {"__name__": "__main__"}
    before = dict(families())
    cwd = Path.cwd()
    try:
        os.chdir(home)
        exec(code, namespace)
    finally:
        os.chdir(cwd)
    yield namespace, home
    for name in set(families()) - set(before):
        families().pop(name)


def column(table, name) -> np.ndarray:
    return np.asarray(table.column(name).to_pylist())


def test_family_is_registered_and_the_cli_builds_its_configs(example):
    ns, _ = example
    family = ns["FAMILY"]
    assert families()["linear"] is family and family_named("linear") is family
    config = ns["LinearConfig"]()
    assert family_of(config) is family
    # the command line's option layer: defaults < --set < options; TOML lists become tuples
    from loopid.cli import scenario_from_options

    fam, built, methods = scenario_from_options(
        "linear",
        None,
        {"seeds": 2, "iterations": 3},
        ["noise_std=0.2", "A=[[1.0, 0.1], [0.0, 0.9]]"],
    )
    assert fam is family and methods is None
    assert built == config.replace(seeds=2, iterations=3, noise_std=0.2, A=((1.0, 0.1), (0.0, 0.9)))
    assert hash(built) == hash(built.replace())  # usable as a cache key
    # the config checks itself: a bad value is a ValueError naming the field
    for field, bad in [("horizon", 0), ("seeds", 2.5), ("noise_std", -1.0), ("B", ((0.0,),))]:
        with pytest.raises(ValueError, match=field if field != "B" else "A must be"):
            config.replace(**{field: bad})
    # to_dict is plain TOML values that rebuild the same config (what run_family reads back)
    assert ns["LinearConfig"](**config.to_dict()) == config
    assert config.to_dict()["A"] == [[1.0, 0.1], [0.0, 1.0]]


def test_run_directory_is_complete_and_resumes(example):
    ns, home = example
    out = home / "runs" / "linear"
    for name in ("config.toml", "results.parquet", "figure.png", "report.md"):
        assert (out / name).is_file(), name
    assert sorted(p.name for p in (out / "cells").iterdir()) == [  # rows and saved policies
        f"linear__{m}.{ext}" for m in ("batch", "dagger") for ext in ("json", "npz", "parquet")
    ]
    config = ns["LinearConfig"]()
    recorded = tomllib.loads((out / "config.toml").read_text())
    assert recorded["run"]["family"] == "linear"
    assert recorded["run"]["seeds"] == config.seeds  # 0..seeds-1, recorded as the count
    assert recorded["scenario"]["linear"] == config.to_dict()
    table = read_table(out / "results.parquet")
    assert table.num_rows == 2 * config.seeds * config.iterations
    report = (out / "report.md").read_text()
    assert "## Final test cost per scenario and method" in report
    assert "| dagger |" in report and "| batch |" in report
    # the same call again: every cell is already finished, nothing is recomputed
    logged = []
    again = run_cells(out, [config], ["dagger", "batch"], log=logged.append)
    assert again.equals(table)
    assert logged == [
        "linear / dagger: already finished, skipped",
        "linear / batch: already finished, skipped",
    ]
    # another configuration in the same directory is refused, not mixed
    with pytest.raises(ValueError, match="different configuration"):
        run_cells(out, [config.replace(noise_std=0.2)], ["dagger"])


def test_learners_reach_the_optimal_lqr_cost(example):
    """Realisable system: the learned models converge to (A, B), so the LQR policies converge to
    the LQR policy of the true system. Both are tested on the same test noise (the loop's common
    random numbers: ``fold_in(key(seed), 2)``), so the ratio measures the policy alone.

    Tolerance: measured on 8 seeds with the guide's settings (10 iterations of 200 samples),
    the final cost is within -0.2% .. +1.6% of the optimum for DAgger and -0.3% .. +1.3% for
    Batch (a learned policy can land a hair below: the stationary LQR gain is not exactly optimal
    over a 50-step horizon). 5% is three times the worst seed, while the first policy (the
    nominal model, B = 0, which cannot act) costs 16-28 times the optimum, so a loop that does
    not learn, learns the wrong B, or solves the wrong LQR fails.
    """
    ns, home = example
    config = ns["LinearConfig"]()
    plant = ns["setup"](config)[0].plant
    A, B = np.asarray(config.A), np.asarray(config.B)
    Q, R = np.eye(A.shape[0]), 0.1 * np.eye(B.shape[1])  # the guide task's cost
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    K = np.concatenate([K, np.zeros((B.shape[1], 1))], axis=1)  # [x; 1]: no feedforward at 0
    seeds = np.arange(config.seeds)
    noise = noise_program(plant, config.test_trajectories, "last")(seed_keys(seeds))
    gains = jnp.broadcast_to(jnp.asarray(K), (seeds.size, config.horizon, *K.shape))
    optimal = np.asarray(plant.eval_seeds(gains, noise.test)[0]).mean(axis=1)  # [S]
    table = read_table(home / "runs" / "linear" / "results.parquet")
    method, seed, it, cost = (
        column(table, c) for c in ("method", "seed", "iteration", "test_cost")
    )
    for m in ("dagger", "batch"):
        first = np.array([cost[(method == m) & (seed == s) & (it == 1)][0] for s in seeds])
        final = np.array(
            [cost[(method == m) & (seed == s) & (it == config.iterations)][0] for s in seeds]
        )
        assert np.all(first > 10 * optimal), (m, first / optimal)
        np.testing.assert_allclose(final, optimal, rtol=0.05, err_msg=m)
    assert np.all(column(table, "diverged") == 0)
