"""Running a helicopter scenario's methods: one method on every seed (:func:`run`), or the
learning methods as one lane set (:func:`run_lanes`), and their programs' memory."""

import numpy as np

from loopid.algorithms.contracts import Trace
from loopid.algorithms.exploration import NU_KINDS
from loopid.algorithms.loop import (
    cut_seeds,
    iteration_block,
    pad_seeds,
    program_memory,
    run_fixed_policy,
)
from loopid.algorithms.loop import run_lanes as run_learning_lanes
from loopid.algorithms.policy_gradient import run_policy_gradient
from loopid.experiments import backend
from loopid.experiments.families.base import Progress
from loopid.experiments.families.helicopter import methods as M
from loopid.experiments.families.helicopter.assembly import setup
from loopid.experiments.families.helicopter.scenario import Scenario
from loopid.systems.helicopter.tasks import is_hover


def run(method: str, s: Scenario, seeds=None, progress: Progress | None = None) -> Trace:
    """Run ``method`` (:data:`loopid.experiments.families.helicopter.methods.METHODS`) on scenario
    ``s``.

    ``seeds``: integer seeds (default ``range(s.seeds)``). Returns a
    :class:`~loopid.algorithms.contracts.Trace` with one row per seed and iteration;
    ``progress(n, row)`` is called after every iteration. A learning method runs as a lane set
    of one (:func:`run_lanes`).
    """
    M.check_method(method)
    if method not in NOT_LANES:
        return run_lanes((method,), s, seeds, progress)[method]
    seeds = np.arange(s.seeds) if seeds is None else np.asarray(seeds)
    padded = pad_seeds(seeds)
    st = setup(s)
    noise = st.test_noise(padded)
    if method == "expert":
        trace = run_fixed_policy(
            st.plant, st.K_expert, padded, iterations=s.iterations, samples=s.samples,
            n_test=s.test_trajectories, progress=progress, noise=noise.test,
        )  # fmt: skip
    else:
        # hover: the trim-holding base flies π_1's test trajectories (π_1 never acts from μ);
        # the funnel's π_1 acts, so its gains are the base there (policy_gradient docstring)
        trace = run_policy_gradient(
            st.plant, st.agent, padded, iterations=s.iterations, samples=s.samples,
            n_test=s.test_trajectories, horizon=s.pg_horizon, sigma=s.pg_sigma, step=s.pg_step,
            hold=is_hover(s.task), nu_state_var=s.nu_state_var, cost_cap=s.cost_cap,
            samples_mode=s.pg_samples, update=s.pg_update, progress=progress, noise=noise.test,
        )  # fmt: skip
    return cut_seeds(trace, seeds)


#: The methods that are not learning lanes: the fixed expert and the policy-gradient baseline.
NOT_LANES = ("expert", "pg")


def lane_sets(s: Scenario, methods) -> list[tuple[str, ...]]:
    """The methods of ``methods`` grouped as they can run: the learning methods (DAgger, Batch
    and Abbeel with any ν) as one lane set, the expert and the policy gradient alone."""
    learning = tuple(m for m in methods if m not in NOT_LANES)
    return ([learning] if learning else []) + [(m,) for m in methods if m in NOT_LANES]


def run_lanes(
    methods, s: Scenario, seeds=None, progress: Progress | None = None
) -> dict[str, Trace]:
    """Learning methods of scenario ``s`` as one lane set
    (:func:`loopid.algorithms.loop.run_lanes`: every (method, seed) pair a lane of one
    compiled program, the ν draws and test noise shared): ``{method: Trace}``, each the same
    numbers as :func:`run` of that method. ``progress(n, row)``: the row's leaves ``[M·S]``."""
    for m in methods:
        M.check_method(m)
        if m in NOT_LANES:
            raise ValueError(f"{m} is not a learning method; run it alone")
    seeds = np.arange(s.seeds) if seeds is None else np.asarray(seeds)
    padded = pad_seeds(seeds)
    st = setup(s)
    noise = st.test_noise(padded)
    schedules = [
        M.policy_fractions(m, s.iterations, dagger_fraction=s.dagger_fraction) for m in methods
    ]
    traces = run_learning_lanes(
        st.loop,
        schedules,
        padded,
        which=[NU_KINDS.index(M.nu_kind(m)) for m in methods],
        program=st.program,
        noise=noise,
        block=backend.default_block(),
        progress=progress,
    )
    return cut_seeds(dict(zip(methods, traces, strict=True)), seeds)


def memory(s: Scenario, method: str | tuple[str, ...], seeds: int) -> int:
    """Peak bytes of the loop's programs for ``seeds`` seeds (of each method of a lane set)
    (:func:`loopid.algorithms.loop.program_memory`). The expert and the policy-gradient baseline
    run the test-noise program and a test that reads it (plus, for PG, rollouts of one state per
    probe), so the noise program is their peak."""
    program = setup(s).program
    block = iteration_block(s.iterations, backend.default_block())  # as run_lanes runs it
    if isinstance(method, tuple):  # a lane set (run_lanes)
        return program_memory(program, seeds, methods=len(method), block=block)
    M.check_method(method)
    if method in NOT_LANES:
        return program_memory(program, seeds, test_only=True)
    return program_memory(program, seeds, block=block)  # a lane set of one (run)


def shared(s: Scenario, method: str) -> dict:
    """What a learning cell's seeds share: the nominal model ``A``, ``B`` its offsets add to."""
    if method in ("expert", "pg"):
        return {}
    nominal = setup(s).nominal
    return {"A": np.asarray(nominal.A), "B": np.asarray(nominal.B)}
