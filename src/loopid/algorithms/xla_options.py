"""The XLA options the learning loop's programs compile with
(:func:`loopid.algorithms.loop_program.make_loop_program`).

On a CPU, LLVM optimises them at level 1 instead of XLA's default 3
(``xla_backend_optimization_level``, passed to each ``jax.jit`` as a compiler option). loopid is
compile-bound on a CPU, and the loop's iteration is its largest program: a hover iteration of 10
seeds (100 test trajectories) compiled in 4.6-5.3 s against 6.8-7.2 s and the funnel's in 4.2 s
against 6.1 s, while one iteration ran in the same 0.04-0.05 s; the test-noise program in 0.4 s
against 1.0-1.4 s. Rounding moves in the last bits, and the learning cells of ``loopid
reproduce`` stay within the equivalence rule of the development page.

Only these programs, the largest a panel compiles, and not for the whole process (an
``XLA_FLAGS`` setting would also change the programs of a user's own code in the same process).
On an accelerator no option is set (it would lower the optimisation of the device's kernels
too).
"""

import jax

#: The option set on a CPU.
CPU_OPTIONS = {"xla_backend_optimization_level": 1}


def loop_options() -> dict | None:
    """The compiler options of the loop's programs on this process's default backend:
    :data:`CPU_OPTIONS` on a CPU, None (XLA's defaults) on an accelerator."""
    return dict(CPU_OPTIONS) if jax.default_backend() == "cpu" else None
