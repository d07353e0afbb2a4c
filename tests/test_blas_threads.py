"""A table's bits do not depend on how many cores the process may use: importing loopid runs
BLAS and LAPACK on one thread. Without it, a least-squares solve of the policy gradient's size
(498 x 84, a threaded LAPACK call) rounds differently on one core than on two, and the local
executor's workers, each pinned to its own cores, would compute other bits than one process."""

import os
import subprocess
import sys

import pytest
from threadpoolctl import threadpool_info

import loopid  # noqa: F401  (one BLAS thread)

PROGRAM = """
import os, sys
if sys.argv[1] == "one":
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
import loopid, jax, jax.numpy as jnp
A = jax.random.normal(jax.random.key(0), (498, 84))
b = jax.random.normal(jax.random.key(1), (498,))
g = jnp.linalg.lstsq(A, b)[0]
print(jnp.asarray(g).tobytes().hex())
"""


def test_every_blas_runs_on_one_thread():
    blas = [lib for lib in threadpool_info() if lib["user_api"] == "blas"]
    assert blas and all(lib["num_threads"] == 1 for lib in blas)


@pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs two cores to compare with one",
)
def test_least_squares_has_the_same_bits_on_one_core_and_on_all():
    def bits(cores: str) -> str:
        out = subprocess.run(
            [sys.executable, "-c", PROGRAM, cores], capture_output=True, text=True, check=True
        )
        return out.stdout.strip()

    assert bits("one") == bits("all")
