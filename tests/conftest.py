"""Strict numerics for every test: float64, strict dtype promotion, warnings as errors."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

import loopid  # noqa: F401  (turns on float64, registers the Gymnasium ids)

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


def tree_allclose(a, b, *, rtol=1e-10, atol=1e-12) -> bool:
    """True when two pytrees have the same structure, leaves of the same shapes and all leaves
    close (``|x − y| <= atol + rtol |y|``; NaN equal to NaN). ``rtol = atol = 0``: bit for bit,
    as ``numpy.testing.assert_array_equal``."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    if ta != tb:
        return False
    pairs = [(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb, strict=True)]
    return all(
        x.shape == y.shape and np.allclose(x, y, rtol=rtol, atol=atol, equal_nan=True)
        for x, y in pairs
    )


#: The test files that take longest (measured, most first): collected first, so that a parallel
#: run (``make test``: pytest-xdist, a whole file per worker, in collection order) starts them at
#: once instead of ending on one of them while the other workers idle.
SLOWEST_FILES = (
    "test_cli.py",  # reproduce --quick, study --quick and reproduce --quick --readings literal
    "test_cli_executors.py",  # a killed run, worker processes, Ray
    "test_chunks.py",
    "test_nonlinear.py",
    "test_family_gym.py",
    "test_saved.py",
    "test_family_package.py",  # a family installed with its entry point: workers and Ray
)


def pytest_collection_modifyitems(items):
    """Put the files of :data:`SLOWEST_FILES` first, in that order (a stable sort: every file's
    own tests, and every other file, keep their order)."""
    rank = {name: i for i, name in enumerate(SLOWEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture
def rng():
    """A NumPy generator with a fixed seed, for test data."""
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def cache(tmp_path_factory) -> Path:
    """One JAX compilation cache for the session's command-line runs (only the first compiles)."""
    return tmp_path_factory.mktemp("jax-cache")


def cli(*args, cache: Path, **popen):
    """``python -m loopid ARGS`` with ``cache`` as its compilation cache: the finished process
    (output captured), or with ``popen`` keywords the running one."""
    env = dict(os.environ, LOOPID_JAX_CACHE=str(cache))
    command = [sys.executable, "-m", "loopid", *map(str, args)]
    if popen:
        return subprocess.Popen(command, env=env, **popen)
    return subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)


def cell_mtimes(out: Path) -> dict[str, int]:
    """The finished cells of the run directory ``out``: ``{file name: mtime in ns}`` of its
    ``cells/*.parquet``."""
    return {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.parquet")}


@pytest.fixture(scope="session")
def funnel_setup():
    """The padded funnel scenario's Setup (plant, iLQR expert gains, nominal), computed once per
    session: the expert's iLQR on the 599-step funnel is one of the suite's longest computations,
    and the runner's own cache (a few entries) is evicted between the modules that use it."""
    from loopid.experiments.families.helicopter import setup
    from loopid.experiments.families.helicopter.scenario import scenario

    return setup(scenario("funnel"))


@pytest.fixture(scope="session")
def funnel_expert():
    """The padded funnel's plant and its expert's gains ``K_expert`` (the 599-step iLQR), from
    the system package alone, computed once per session for the engine's tests."""
    from types import SimpleNamespace

    from loopid.systems.helicopter.expert import expert_gains
    from loopid.systems.helicopter.plant import helicopter_plant
    from loopid.systems.helicopter.tasks import make_task

    plant = helicopter_plant(make_task("funnel"))
    return SimpleNamespace(plant=plant, K_expert=expert_gains(plant.task))
