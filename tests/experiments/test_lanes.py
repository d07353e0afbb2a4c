"""A lane set (:func:`loopid.algorithms.loop.run_lanes`): several methods on every seed as one
program gives each method the numbers it has alone, bit for bit, in any subset and order.

Small finite MDPs keep the programs cheap; two ν samplers make the lanes draw from a list
(the helicopter's three, with the expert's rollouts, are checked end to end in
``tests/experiments/test_lane_sets.py``). The plant, agent and diagnostics are the MDP family's
(:mod:`loopid.experiments.families.mdp.agent`), so these tests live here; the lane set's pieces
that need no system are ``tests/algorithms/test_lane_inputs.py``."""

import jax
import numpy as np
import pytest

from conftest import tree_allclose
from loopid.algorithms import loop
from loopid.algorithms.contracts import LoopSpec
from loopid.algorithms.loop import iteration_block, program_memory, run_lanes, run_learning
from loopid.algorithms.loop_program import make_loop_program
from loopid.experiments.families.helicopter.methods import policy_fractions
from loopid.experiments.families.mdp.agent import (
    counts_model,
    explicit_nu,
    mdp_agent,
    mdp_diagnostics,
    mdp_plant,
    policy_nu,
)
from loopid.systems.mdp import random_mdp

ITERATIONS, SAMPLES, SEEDS = 5, 12, np.arange(4)
#: JAX's monitoring event for one XLA compilation
BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
#: (policy fractions of DAgger, Batch or Abbeel, ν index): six methods of two ν samplers
METHODS = [(m, w) for m in ("dagger-t", "batch-t", "abbeel") for w in (0, 1)]


@pytest.fixture(scope="module")
def lanes():
    mdp = random_mdp(jax.random.key(3), 5, 2, gamma=0.9)
    uniform = np.full((5, 2), 0.1)
    _, second = policy_nu(mdp, np.tile([0.8, 0.2], (5, 1)))
    model = counts_model(5, 2)
    plant, agent = mdp_plant(mdp, 15), mdp_agent(mdp, model)
    nus = [explicit_nu(mdp, uniform), second]
    loop = LoopSpec(plant, agent, nus, samples=SAMPLES, n_test=1, mode="geometric", gamma=0.9)
    cell = make_loop_program(loop, ITERATIONS, diagnostics=mdp_diagnostics(mdp, uniform, model))

    def run(methods, iterations=ITERATIONS, **options):
        schedules = [policy_fractions(m, iterations) for m, _ in methods]
        which = [w for _, w in methods]
        return run_lanes(loop, schedules, SEEDS, which=which, program=cell, **options)

    def alone(method):
        m, w = method
        return run_learning(loop, policy_fractions(m, ITERATIONS), SEEDS, which=w, program=cell)

    return run, alone, cell


def _assert_same(a, b, what):
    leaves_a = jax.tree_util.tree_leaves((a.rows, a.final))
    leaves_b = jax.tree_util.tree_leaves((b.rows, b.final))
    assert len(leaves_a) == len(leaves_b)
    for x, y in zip(leaves_a, leaves_b, strict=True):
        np.testing.assert_array_equal(x, y, err_msg=str(what))


def test_a_lane_set_equals_each_method_alone(lanes):
    run, alone, _ = lanes
    traces = run(METHODS)
    assert len(traces) == len(METHODS)
    for method, trace in zip(METHODS, traces, strict=True):
        assert trace.rows.test_cost.shape == (len(SEEDS), ITERATIONS)
        assert set(trace.rows.extra)  # the exact diagnostics ran per lane, with its own p
        _assert_same(trace, alone(method), method)
    # the methods differ, so a lane that read another method's p or ν would have been caught
    costs = [t.rows.loss_nu[:, 1:] for t in traces]
    assert not np.array_equal(costs[0], costs[1])  # ν index 0 vs 1
    assert not np.array_equal(traces[0].rows.policy_samples, traces[2].rows.policy_samples)


def test_any_subset_in_any_order_gives_the_same_rows(lanes):
    run, _, _ = lanes
    full = dict(zip(METHODS, run(METHODS), strict=True))
    subset = [METHODS[4], METHODS[1], METHODS[3]]
    for method, trace in zip(subset, run(subset), strict=True):
        _assert_same(trace, full[method], method)


def test_blocks_of_iterations_give_the_rows_of_one_call_per_iteration(lanes, monkeypatch):
    """``block``: iterations as one ``lax.scan`` per block (the largest divisor of N = 6 up to
    the block: 4 runs blocks of 3) give every lane's rows and final arrays to 1e-12 relative
    (the scan's program rounds the MDP's last bit differently in a few rows; the helicopter's
    lane sets were measured bit for bit), and ``progress`` still sees every iteration's row, in
    order. The memory estimate compiles the block program the run then uses."""
    run, _, program = lanes
    seen, blocks = {}, []
    run_blocks = loop._blocks

    def in_blocks(program, keys, noise, schedules, which, block, progress):
        blocks.append(block)
        return run_blocks(program, keys, noise, schedules, which, block, progress)

    monkeypatch.setattr(loop, "_blocks", in_blocks)

    def progress(block):
        def record(n, row):
            seen.setdefault(block, []).append((n, np.asarray(row.test_cost)))

        return record

    one = run(METHODS, 6, progress=progress(1))
    for block in (4, 6):
        traces = run(METHODS, 6, block=block, progress=progress(block))
        for method, a, b in zip(METHODS, one, traces, strict=True):
            assert tree_allclose((a.rows, a.final), (b.rows, b.final), rtol=1e-12, atol=0), method
            np.testing.assert_array_equal(a.rows.policy_samples, b.rows.policy_samples)
        assert [n for n, _ in seen[block]] == list(range(1, 7))
        assert blocks == [3 if block == 4 else 6]  # one run in blocks of that size
        blocks.clear()
        for (_, x), (_, y) in zip(seen[1], seen[block], strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-12)
    # blocks of 2: the estimate compiles them, and the run then compiles nothing
    assert program_memory(program, len(SEEDS), methods=len(METHODS), block=2) > 0
    compiles = []

    def listen(event, _seconds, **_):
        if event == BACKEND_COMPILE:
            compiles.append(event)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        run(METHODS, 6, block=2)
        assert blocks == [2]
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert compiles == []
    assert [iteration_block(6, b) for b in (1, 2, 3, 4, 5, 6, 7)] == [1, 2, 3, 3, 3, 6, 6]
    assert iteration_block(7, 5) == 1
    with pytest.raises(ValueError, match="block must be an integer >= 1, got 0"):
        run(METHODS, block=0)
