"""Running Algorithm 1 (:mod:`loopid.algorithms.loop_program`) on every seed at once:
:func:`run_learning` (one method), :func:`run_lanes` (M methods as one *lane set*, every
(method, seed) pair a lane of one compiled program), :func:`run_fixed_policy` (the expert),
each a :class:`~loopid.algorithms.contracts.Trace` with one row per seed and iteration;
:func:`program_memory`, what their programs need; and the padding of small seed batches
(:data:`~loopid.algorithms.loop.MIN_SEEDS`).

Speed: :func:`drive` calls the program's ``step`` N − 1 times from Python (no retracing: the
iteration number and ``p_n`` are traced arguments), which gives progress and early results per
iteration. With ``block`` B > 1, :func:`run_lanes` instead runs up to B iterations per call
(the largest divisor of N) as one ``lax.scan`` and fetches their rows once, so the host waits
on the device once per block (the helicopter's lane sets do so on an accelerator).
"""

from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.contracts import (
    EvalNoise,
    LoopPlant,
    LoopProgram,
    LoopSpec,
    Row,
    Trace,
)
from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop_program import (
    eval_noise,
    first_iteration,
    lane_noise,
    lane_seed_keys,
    make_loop_program,
    trajectory_mean,
)


def drive(
    start: Callable[[], tuple[Any, Row]],
    step: Callable[[Any, int], tuple[Any, Row]],
    iterations: int,
    progress: Callable[[int, Row], None] | None = None,
) -> list[Row]:
    """The Python loop over iterations that every runner shares: ``start() -> (carry, row)`` is
    iteration 1, ``step(carry, n) -> (carry, row)`` iteration n = 2..N; ``progress(n, row)``
    after each. Returns the last carry and the N rows."""
    carry, row = start()
    rows = [row]
    if progress:
        progress(1, row)
    for n in range(2, iterations + 1):
        carry, row = step(carry, n)
        rows.append(row)
        if progress:
            progress(n, row)
    return carry, rows


def program_bytes(compiled) -> int:
    """Peak bytes of one compiled program by XLA's buffer assignment: arguments + outputs +
    temporaries − the argument buffers its outputs reuse (donation)."""
    m = compiled.memory_analysis()
    return int(
        m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
        - m.alias_size_in_bytes
    )  # fmt: skip


def program_memory(
    program: LoopProgram,
    seeds: int,
    *,
    test_only: bool = False,
    methods: int = 1,
    block: int = 1,
) -> int:
    """Peak bytes of a :class:`LoopProgram`'s programs for ``seeds`` seeds of ``methods`` methods
    (:func:`program_bytes`): the larger of the test-noise program and one ``step`` (which holds
    the noise, the carry and the row), or with ``block`` > 1 (:func:`iteration_block`'s) one
    ``steps`` of that many iterations. ``test_only``: the noise program alone (a fixed
    policy's test, or the policy-gradient baseline's, reads the noise in place and keeps one
    state per trajectory).

    Both programs are compiled for ``seeds`` seeds exactly as :func:`run_lanes` calls them,
    so a run of that many seeds in this process reuses the compilation (JAX's executable cache)."""
    keys = jax.ShapeDtypeStruct((int(seeds),), jax.random.key(0).dtype)
    noise = jax.eval_shape(program.noise, keys)
    peak = program_bytes(program.noise.lower(keys).compile())
    if test_only:
        return peak
    noise = jax.eval_shape(lambda w: lane_noise(w, methods), noise)
    carry = jax.eval_shape(lambda k: program.init(lane_seed_keys(k, methods)), keys)
    if block > 1 and program.steps is not None:  # as run_lanes runs it
        ns = jax.ShapeDtypeStruct((block,), jnp.int32)
        ps = jax.ShapeDtypeStruct((block, methods), jnp.float64)
        which = jax.ShapeDtypeStruct((methods,), jnp.int32)
        lowered = program.steps.lower(carry, keys, noise, ns, ps, which)
    else:
        lowered = program.step.lower(carry, keys, noise, *first_iteration(methods))
    return max(peak, program_bytes(lowered.compile()))


def run_learning(
    spec: LoopSpec,
    fractions,
    seeds,
    *,
    which: int = 0,
    program: LoopProgram | None = None,
    noise: EvalNoise | None = None,
    progress: Callable[[int, Row], None] | None = None,
) -> Trace:
    """Run one learning method of the loop ``spec`` (:class:`~loopid.algorithms.contracts.LoopSpec`)
    for ``len(fractions)`` iterations on every seed (:func:`run_lanes` with one method).

    ``fractions[n−1]`` is the probability ``p_n`` that a slot of iteration n's batch comes from
    the policy (``fractions[0]`` is unused: iteration 1 collects nothing). ``progress(n, row)`` is
    called after each iteration with that iteration's :class:`Row` (leaves ``[S]``).
    ``program``: a :class:`LoopProgram` from :func:`make_loop_program` of the same ``spec``,
    to reuse its compilation across methods (DAgger, Batch, Abbeel) and calls; ``which`` picks
    the ν of a list. ``noise``: the seeds' :class:`EvalNoise` (default: the program's
    ``noise(keys)``).
    """
    return run_lanes(
        spec, [fractions], seeds, which=[which], program=program, noise=noise, progress=progress
    )[0]


def run_lanes(
    spec: LoopSpec,
    schedules,
    seeds,
    *,
    which: Sequence[int] = (0,),
    program: LoopProgram | None = None,
    noise: EvalNoise | None = None,
    block: int = 1,
    progress: Callable[[int, Row], None] | None = None,
) -> list[Trace]:
    """Run M learning methods of the loop ``spec`` on every seed as one *lane set*: the lanes
    are the (method, seed) pairs, ``M·S`` of them, method-major, and every iteration of all of
    them is one call of the program's ``step`` (with ``block``, a block of iterations one call
    of its ``steps``; ``program``: as in :func:`run_learning`). Returns one :class:`Trace` per
    method.

    A method is data: its row of ``schedules [M, N]`` (the policy fractions ``p_n``, as
    ``fractions`` of :func:`run_learning`) and its ν index ``which[m]``. Every draw depends on
    the seed and the iteration only (:mod:`loopid.algorithms.keys`) and each lane's numbers on
    its own inputs only, so a lane has the same numbers in any lane set (the same as
    :func:`run_learning` of its method: tested), and any subset of methods or seeds reruns
    bit for bit. ν's draws and the test noise are computed once per seed and shared by the
    methods' lanes. ``progress(n, row)``: after each iteration (with ``block``, after each
    block, for each of its iterations), the row's leaves ``[M·S]``.

    ``block``: iterations per call at most. 1 calls ``step`` once per iteration; B > 1 runs
    blocks of the largest divisor of N up to B iterations (:func:`iteration_block`), each one
    ``lax.scan`` of ``step`` (the program's ``steps``), so an accelerator meets the host once
    per block: the rows then come back, and ``progress`` sees them, a block at a time. The same
    computation, compiled inside a loop: the helicopter's lane sets were measured bit for bit
    on a CPU, and a finite MDP's rows within one ulp (tested to 1e-12 relative).
    """
    schedules = np.asarray(schedules, dtype=np.float64)
    if schedules.ndim != 2 or schedules.shape[0] < 1:
        raise ValueError(f"schedules must be [methods, iterations], got shape {schedules.shape}")
    methods, iterations = schedules.shape
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if ((schedules < 0) | (schedules > 1)).any():
        raise ValueError(f"policy fractions must lie in [0, 1], got {schedules.tolist()}")
    which = jnp.asarray(np.asarray(which, dtype=np.int32).reshape(methods))
    keys = seed_keys(seeds)
    if program is None:
        program = make_loop_program(spec, iterations)
    noise = lane_noise(program.noise(keys) if noise is None else noise, methods)
    block = iteration_block(iterations, block)
    if block > 1 and program.steps is not None:
        carry, rows = _blocks(program, keys, noise, schedules, which, block, progress)
    else:

        def one(carry, n):
            p = jnp.asarray(schedules[:, n - 1])
            return program.step(carry, keys, noise, jnp.int32(n), p, which)

        start = lambda: program.start(keys, noise, methods)  # noqa: E731
        carry, rows = drive(start, one, iterations, progress)
    final = {"K": carry.K}
    if spec.agent.params is not None:
        final |= jax.vmap(spec.agent.params)(carry.learner)
    if spec.test_policy == "best":
        final["best_K"] = carry.best_K
    if spec.test_policy == "mixture":
        final["history"] = carry.history
    rows, final = jax.device_get((rows, final))  # to NumPy once, then each method's a view
    S = len(keys)
    return [
        Trace.from_rows(
            seeds,
            spec.samples,
            [_lanes(row, m, S) for row in rows],
            {k: _lanes(v, m, S) for k, v in final.items()},
        )
        for m in range(methods)
    ]


def iteration_block(iterations: int, block: int) -> int:
    """The iterations :func:`run_lanes` runs per call for ``block``: the largest divisor of
    ``iterations`` up to ``block``, so that every call is one compiled program of that length
    (ValueError naming a ``block`` below 1)."""
    if isinstance(block, bool) or not isinstance(block, int | np.integer) or block < 1:
        raise ValueError(f"block must be an integer >= 1, got {block!r}")
    return max(b for b in range(1, min(int(block), iterations) + 1) if iterations % b == 0)


def _blocks(program: LoopProgram, keys, noise, schedules, which, block: int, progress):
    """:func:`run_lanes`' iterations in blocks of ``block`` (a divisor of their number) by
    ``program.steps``: the last carry and the rows, each block's fetched to the host in one
    transfer. Iteration 1's ``p`` is
    :func:`~loopid.algorithms.loop_program.first_iteration`'s (the diagnostics read it); its
    ``which`` is the methods' own, unused there (iteration 1 collects nothing)."""
    methods, iterations = schedules.shape
    carry = program.init(lane_seed_keys(keys, methods))
    ps = schedules.T.copy()
    ps[0] = first_iteration(methods)[1]  # iteration 1's p, as start passes it
    rows = []
    for first in range(1, iterations + 1, block):
        ns = np.arange(first, first + block, dtype=np.int32)
        carry, stacked = program.steps(carry, keys, noise, ns, ps[ns - 1], which)
        stacked = jax.device_get(stacked)
        for i, n in enumerate(ns):
            rows.append(jax.tree_util.tree_map(lambda a, i=i: a[i], stacked))
            if progress:
                progress(int(n), rows[-1])
    return carry, rows


def _lanes(tree, m: int, seeds: int):
    """Method ``m``'s lanes (``[m·S : (m+1)·S]``) of every leaf of a lane set's tree."""
    return jax.tree_util.tree_map(lambda a: a[m * seeds : (m + 1) * seeds], tree)


def run_fixed_policy(
    plant: LoopPlant,
    K: jax.Array,
    seeds,
    *,
    iterations: int,
    samples: int,
    n_test: int,
    progress: Callable[[int, Row], None] | None = None,
    noise: jax.Array | None = None,
) -> Trace:
    """Test one fixed policy (the linearised expert L) on the learning methods' test noise
    (``noise``: the seeds' ``EvalNoise.test`` when the caller keeps a :func:`noise_program`).

    The policy and the noise are the same at every iteration, so the test runs once and its row
    is repeated (a flat line); the diagnostics are 0 and the solver status True.
    """
    if noise is None:
        noise = eval_noise(plant, seed_keys(seeds), n_test, "last").test

    @jax.jit
    def test(w):
        S = w.shape[2]
        costs, div = plant.eval_seeds(jnp.broadcast_to(K, (S, *K.shape)), w)
        zero, count = jnp.zeros(S), jnp.zeros(S, jnp.int32)
        return Row(
            test_cost=trajectory_mean(costs), test_cost_median=jnp.median(costs, axis=1),
            diverged=jnp.sum(div, axis=1), loss_nu=zero, loss_policy=zero, online_loss=zero,
            policy_samples=count, valid_samples=count, solver_converged=jnp.ones(S, bool),
            spectral_radius=zero, extra={},
        )  # fmt: skip

    row = test(noise)
    _, rows = drive(lambda: (None, row), lambda carry, n: (carry, row), iterations, progress)
    S = noise.shape[2]
    return Trace.from_rows(seeds, samples, rows, {"K": jnp.broadcast_to(K, (S, *K.shape))})


#: The fewest seeds a compiled cell computes at once. XLA's CPU backend lowers a batch of one or
#: two seeds differently from larger ones (measured: a seed's rows then differ in their last
#: bits, which a diverging test trajectory amplifies), so :func:`at_least` pads smaller runs and a
#: seed's numbers are the same however many seeds run beside it (so the experiment pipeline may
#: split seeds into chunks).
MIN_SEEDS = 3


def at_least(run: Callable[[np.ndarray], Any], seeds):
    """``run(seeds)`` on at least :data:`MIN_SEEDS` seeds (:func:`pad_seeds`), its
    :class:`Trace` (or each of a dict of them) cut back to ``seeds`` (:func:`cut_seeds`)."""
    seeds = np.asarray(seeds)
    return cut_seeds(run(pad_seeds(seeds)), seeds)


def pad_seeds(seeds) -> np.ndarray:
    """``seeds`` (1-D) padded with copies of the last to at least :data:`MIN_SEEDS`."""
    seeds = np.asarray(seeds)
    if seeds.ndim != 1 or seeds.size == 0 or seeds.size >= MIN_SEEDS:
        return seeds
    return np.concatenate([seeds, np.full(MIN_SEEDS - seeds.size, seeds[-1], seeds.dtype)])


def cut_seeds(out, seeds):
    """A :class:`Trace` of :func:`pad_seeds` ``(seeds)`` (or each of a dict of them) cut back to
    its first ``len(seeds)`` seeds (unchanged when nothing was padded)."""
    seeds = np.asarray(seeds)
    if isinstance(out, dict):
        return {k: cut_seeds(trace, seeds) for k, trace in out.items()}
    if out.seeds.size == seeds.size:
        return out
    n = seeds.size
    rows = jax.tree_util.tree_map(lambda a: a[:n], out.rows)
    final = None if out.final is None else {k: v[:n] for k, v in out.final.items()}
    return out._replace(seeds=seeds, rows=rows, final=final)


__all__ = [
    "MIN_SEEDS", "at_least", "cut_seeds", "drive", "iteration_block", "pad_seeds",
    "program_bytes", "program_memory", "run_fixed_policy", "run_lanes", "run_learning",
]  # fmt: skip
