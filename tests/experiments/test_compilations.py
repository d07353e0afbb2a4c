"""Counting the XLA programs a process builds: a new program is counted as compiled; the same
program in a second process sharing the persistent compilation cache is counted as loaded; a
run's report says what its cells built."""

import json
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp

from loopid.experiments import compilations
from loopid.experiments.report import CellTime, programs_line

PROGRAM = textwrap.dedent(
    """
    import json, sys
    import loopid, jax, jax.numpy as jnp
    from loopid.experiments.backend import compile_cache
    from loopid.experiments import compilations
    compile_cache(sys.argv[1])
    before = compilations.programs()
    jax.jit(lambda x: jnp.tanh(x) @ x.T + 3.0)(jnp.ones((7, 7))).block_until_ready()
    print(json.dumps((compilations.programs() - before)._asdict()))
    """
)


def test_a_new_program_is_counted_once_and_a_reused_one_not_at_all():
    """In this process a new program is built once (compiled, or loaded where an earlier run
    left it in the persistent cache: the next test separates the two), and calling it again
    builds nothing."""
    before = compilations.programs()
    jax.jit(lambda x: jnp.sinh(x) * 5.0 - x)(jnp.ones(4)).block_until_ready()
    built = compilations.programs() - before
    assert built.compiled + built.loaded >= 1
    f = jax.jit(lambda x: jnp.cosh(x) + 2.0)
    f(jnp.ones(4)).block_until_ready()
    again = compilations.programs()
    f(jnp.ones(4)).block_until_ready()  # the same program again: JAX's in-memory cache
    assert compilations.programs() - again == compilations.Programs(0, 0)


def test_a_second_process_loads_what_the_first_compiled(tmp_path):
    def run():
        out = subprocess.run(
            [sys.executable, "-c", PROGRAM, str(tmp_path / "cache")],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        return json.loads(out.stdout.strip().splitlines()[-1])

    first, second = run(), run()
    assert first["compiled"] >= 1 and first["loaded"] == 0
    assert second["loaded"] >= 1 and second["compiled"] < first["compiled"]


def test_the_report_line_sums_the_cells_and_names_the_uncounted():
    times = {
        ("hover", "dagger-t"): CellTime(2.0, 1.0, 0.0, 5, 7),
        ("hover", "batch-t"): CellTime(2.0, 1.0, 0.0, 0, 0),
        ("hover", "expert"): CellTime(1.0, 1.0, 0.0),
    }
    line = programs_line(times)
    assert "5 compiled, 7 loaded" in line and "1 cells from before counting" in line
    assert programs_line({("hover", "expert"): CellTime(1.0, 1.0, 0.0)}) is None
