"""loopid: closed-loop system identification and model-based control.

An implementation of Ross & Bagnell (ICML 2012), "Agnostic System Identification for
Model-Based Reinforcement Learning": fit a model of a real system, synthesise a controller on
it, run the controller on the system, add what it saw to the data, repeat.

Importing loopid turns on JAX float64 (every hot path is float64), keeps JAX from
preallocating most of a GPU's memory (``XLA_PYTHON_CLIENT_PREALLOCATE=false`` unless set), makes
a GPU's programs deterministic (``--xla_gpu_deterministic_ops=true`` added to ``XLA_FLAGS``
unless they name it), lets XLA's CPU compiler update a skipped branch's buffers in place
(``--xla_cpu_copy_insertion_use_region_analysis=true``, the same way), runs
the BLAS and LAPACK libraries of this process (those behind JAX's CPU linear algebra among them)
on one thread, and registers the helicopter tasks as Gymnasium environments
(``loopid/HelicopterHover-v0``, ``loopid/HelicopterHoverDelay-v0``,
``loopid/HelicopterFunnel-v0``).
"""

import os
import re
from importlib.metadata import PackageNotFoundError, version

# On a GPU no process takes most of the device's memory up front: loopid's worker processes
# (one per device) and the process that starts them would otherwise each claim 75 % of it.
# Effective when set before JAX starts a backend; a value the user set is kept.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")


# On a GPU the same seeds give the same table from run to run, with any number of workers: XLA's
# default lets a GPU program's rounding vary between compilations (measured on one H200: two
# cold runs of the same hover cells differed in 5 of 72 rows, by 2e-16 at first, which a chaotic
# test trajectory can amplify to 0.7 %). Deterministic ops made runs with one and with four
# workers bit for bit equal, for 4 % more time. No effect on a CPU's numbers; a setting the user
# chose is kept. (XLA_FLAGS is part of JAX's compilation cache key.)
#
# On a CPU, XLA's copy insertion analyses a conditional's branches as regions, so that a loop
# iteration's learning half (skipped by a ``cond`` at iteration 1) updates the learner's
# statistics in place instead of copying them in and out of the branch: a funnel iteration of 10
# seeds took 231-251 ms against 266-283 ms (best of 6, two runs each), with the same bits.
# No effect on a GPU's programs. jaxlib 0.5 and later know the flag (XLA stops a process at a
# flag it does not know), so older ones go without it.
def _jaxlib_at_least(major: int, minor: int) -> bool:
    """Whether the installed jaxlib is at least ``major.minor`` (read without importing it)."""
    try:
        found = re.match(r"(\d+)\.(\d+)", version("jaxlib"))
    except PackageNotFoundError:
        return False
    return found is not None and (int(found[1]), int(found[2])) >= (major, minor)


_XLA_DEFAULTS = ["xla_gpu_deterministic_ops=true"]
if _jaxlib_at_least(0, 5):
    _XLA_DEFAULTS.append("xla_cpu_copy_insertion_use_region_analysis=true")
if _missing := [
    f"--{flag}"
    for flag in _XLA_DEFAULTS
    if not re.search(rf"(^|\s)--{flag.split('=')[0]}(=|\s|$)", os.environ.get("XLA_FLAGS", ""))
]:
    os.environ["XLA_FLAGS"] = " ".join(
        filter(None, [os.environ.get("XLA_FLAGS", "").strip(), *_missing])
    )

# the flags above must be set before JAX starts: these imports come after them
import jax  # noqa: E402
import scipy.linalg  # noqa: E402, F401  (the LAPACK behind JAX's CPU linear algebra, loaded now)
from threadpoolctl import threadpool_limits  # noqa: E402

jax.config.update("jax_enable_x64", True)

# One BLAS thread: a multi-threaded LAPACK call (a least-squares solve, say) can round
# differently with its number of threads, which follows the cores the process may use. With
# one, a table has the same bits on any number of cores and in any worker, pinned or not; the
# matrices here are small (at most a few hundred rows), where threads gain little.
threadpool_limits(limits=1, user_api="blas")

try:
    #: The installed version of loopid (``0.0.0+unknown`` in a source tree without an install).
    __version__ = version("loopid")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+unknown"

from loopid.systems._register import register_envs as _register_envs  # noqa: E402

_register_envs()


def load(run_dir, scenario: str, method: str, seed: int):
    """The saved final model and controller of a run (:func:`loopid.experiments.saved.load`).

    Raises:
      loopid.experiments.artifacts.Damaged: a file of the run cannot be read (a ``ValueError``
        whose one-line message names the file and says to run the command again).
    """
    from loopid.experiments.saved import load as _load

    return _load(run_dir, scenario, method, seed)


__all__ = ["__version__", "load"]
