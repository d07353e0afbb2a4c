"""Algorithm 1 of Ross & Bagnell (2012), for every seed at once.

One *cell* is one method on one plant over N iterations for S seeds. Iteration ``n = 1`` solves
the initial model; each iteration ``n = 2..N`` draws ``m`` transitions with the policy ``π_{n−1}``
and the exploration distribution ν, gives them to the online learner, solves the new model for
``π_n`` and tests ``π_n`` on the real noisy system (the paper's Algorithm 1)::

    slot i of the batch  ←  a draw from running π_{n−1}   with probability p_n,
                            a draw from ν                   otherwise,

with ``p_n = ½`` for DAgger, ``0`` for Batch, and for Abbeel's method ``0`` at ``n = 2`` (ν = the
expert) and ``1`` afterwards (:mod:`loopid.algorithms.methods`). Both candidate sets are always
drawn (fixed shapes); the model's loss on each is recorded before the update, so every method
reports how well its model predicts its own policy's data and ν's (the train/test mismatch).

Speed: the iteration is a pure function of a fixed-shape carry, vmapped over seeds (and, in a
lane set, :func:`run_lanes`, over the methods' seeds) and jitted once; :func:`run_learning`
calls it N − 1 times from Python (no retracing: the iteration number and
``p_n`` are traced arguments), which gives progress and early results per iteration. With
``block`` B > 1, :func:`run_lanes` instead runs up to B iterations per call (the largest
divisor of N) as one ``lax.scan`` and fetches their rows once, so the host waits on the device
once per block (the helicopter's lane sets do so on an accelerator).

Randomness (:mod:`loopid.algorithms.keys`, every stream named there): seed ``s`` has key ``k =
jax.random.key(s)``; training draws at iteration n use ``fold_in(fold_in(k, 1), n)``
(:func:`iteration_keys`, shared by every loop). The test trajectories'
process noise is drawn once per seed from ``fold_in(k, 2)`` and reused at every iteration, so every
method sees the same test noise at the same seed and iteration (common random numbers), and a
curve's changes from one iteration to the next come from the policy alone. (Drawing it afresh each
iteration would cost more than the simulation itself: threefry on a CPU makes ~13 M float64 normals
per second.) ``test_policy = "best"`` selects the best policy so far on a second, independent noise
set (``fold_in(k, 3)``), so its reported cost is not biased by the selection.
"""

import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid._renamed import renamed, renamed_argument
from loopid.algorithms.collect import policy_samples
from loopid.algorithms.contracts import (
    Agent,
    Diagnostics,
    EvalNoise,
    LoopProgram,
    Row,
    SharedSampler,
    SolverInfo,
    Trace,
)
from loopid.algorithms.keys import (
    EVALUATE,
    SELECT,
    TEST,
    IterationKeys,
    iteration_key,
    iteration_keys,
    seed_keys,
    stream_key,
)
from loopid.algorithms.plant import LoopPlant, Transitions, noise_columns, ordered_sum, select

TEST_POLICIES = ("last", "best", "mixture")


class _Carry(NamedTuple):
    learner: Any
    K: jax.Array
    best_K: jax.Array
    best_cost: jax.Array
    history: jax.Array
    loss_sum: jax.Array
    diag: Any


def _masked_mean(values: jax.Array, mask: jax.Array) -> jax.Array:
    """Mean of ``values [b]`` over ``mask [b]`` (0 when none), summed in a fixed order
    (:func:`loopid.algorithms.plant.ordered_sum`): under ``vmap`` over S seeds ``jnp.sum`` over
    the b = 100 rows changed a seed's loss in its last bit from S = 41 on (measured)."""
    count = jnp.sum(mask)
    total = ordered_sum(jnp.where(mask, values, 0.0), axis=-1)
    return jnp.where(count > 0, total / jnp.maximum(count, 1).astype(total.dtype), 0.0)


def trajectory_mean(costs: jax.Array) -> jax.Array:
    """``costs [S, n_test] -> [S]``: each seed's mean over its test trajectories, summed in a
    fixed order (:func:`loopid.algorithms.plant.ordered_sum`), so a seed's mean has the same bits
    beside any number of other seeds (``jnp.mean`` over the 100 trajectories changes its last bit
    from S = 41 seeds on, measured)."""
    return ordered_sum(costs, axis=-1) / costs.shape[-1]


def batch_losses(agent: Agent, learner, from_pol, from_nu, take: jax.Array):
    """The model's mean loss, before the update, on the ν draws, on the policy draws and on the
    batch ``select(take, from_pol, from_nu)``. ``agent.loss`` is per row, so each candidate set
    is evaluated once and the batch's row losses are the same row-wise choice of them."""
    rows_pol, rows_nu = agent.loss(learner, from_pol), agent.loss(learner, from_nu)
    batch_mask = jnp.where(take, from_pol.mask, from_nu.mask)
    return (
        _masked_mean(rows_nu, from_nu.mask),
        _masked_mean(rows_pol, from_pol.mask),
        _masked_mean(jnp.where(take, rows_pol, rows_nu), batch_mask),
    )


def noise_program(
    plant: LoopPlant, n_test: int, test_policy: str, stream: int = TEST
) -> Callable[..., EvalNoise]:
    """The jitted ``keys [S] -> EvalNoise``: every seed's test noise from ``fold_in(k, stream)``
    (2, or :data:`EVALUATE` for fresh noise) and, for ``best``, its selection noise from
    ``fold_in(k, 3)``, ``[horizon, n_noise, S, n_test]``.

    Build it once per plant and shape and keep it (a family's setup does), so that every method
    of a run shares one compilation."""

    def one(key):
        test = plant.eval_noise(stream_key(key, stream), n_test)
        if test_policy != "best":
            return EvalNoise(test, jnp.zeros((0,), test.dtype))
        return EvalNoise(test, plant.eval_noise(stream_key(key, SELECT), n_test))

    def columns(keys):
        return jax.tree_util.tree_map(noise_columns, jax.vmap(one)(keys))

    return jax.jit(columns)


def eval_noise(plant: LoopPlant, keys: jax.Array, n_test: int, test_policy: str) -> EvalNoise:
    """The test (and selection) noise of every seed (:func:`noise_program`, compiled afresh)."""
    return noise_program(plant, n_test, test_policy)(keys)


class LearnStats(NamedTuple):
    """One learning step's diagnostics (the :class:`Row` fields of the same names)."""

    loss_nu: jax.Array
    loss_policy: jax.Array
    online_loss: jax.Array
    policy_samples: jax.Array
    valid_samples: jax.Array


def learning_step(agent: Agent, learner, loss_sum, from_pol, from_nu, k_mix, n, p, samples: int):
    """Algorithm 1's learning half for one seed, the same for the JAX loop and the host loop.

    Slot i of the batch is row i of the policy's draws ``from_pol`` with probability ``p``
    (``bernoulli(k_mix, p, [samples])``), else row i of ν's draws ``from_nu``; the model's mean
    loss on each set and on the batch is taken *before* the update; the learner is updated on
    the batch; the online loss is the running mean of the batch losses over iterations 2..n
    (``loss_sum`` carries their sum). Returns ``(learner, loss_sum, LearnStats)``.
    """
    take = jax.random.bernoulli(k_mix, p, (samples,))
    batch = select(take, from_pol, from_nu)
    loss_nu, loss_pol, loss_batch = batch_losses(agent, learner, from_pol, from_nu, take)
    loss_sum = loss_sum + loss_batch
    learner = agent.update(learner, batch)
    online = loss_sum / (n - 1).astype(loss_sum.dtype)
    counts = (jnp.sum(take & batch.mask), jnp.sum(batch.mask))
    return learner, loss_sum, LearnStats(loss_nu, loss_pol, online, *counts)


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


def lane_noise(noise: EvalNoise, methods: int) -> EvalNoise:
    """The test noise of a lane set's lanes: each seed's noise (``[horizon, n_noise, S,
    n_test]``, :func:`loopid.algorithms.plant.noise_columns`) repeated for each of ``methods``
    methods along the seed axis, method-major, so that every lane is tested as a seed of a
    single method is, by the same program, and has its numbers. (Testing the methods' lanes by
    a ``vmap`` over the methods, reading the noise without a copy, changed last bits.)"""
    if methods == 1:
        return noise

    def lanes(w):  # the seed axis is the second last (noise_columns); unused noise is [0]
        return jnp.concatenate([w] * methods, axis=-2) if w.ndim >= 2 else w

    return jax.tree_util.tree_map(lanes, noise)


def _evaluate(
    plant: LoopPlant, carry: _Carry, K, keys, noise: EvalNoise, n, test_policy: str, flown=None
):
    """Test every lane's policy ``K [L, horizon, m, n]`` (``flown``: what the plant flies in its
    place, a controller's policies of every lane) on its noise (:func:`lane_noise`); returns
    (costs [L, n_test], diverged [L, n_test], new carry). ``keys [L]``: each lane's seed key."""
    carry = carry._replace(K=K)
    if test_policy == "last":
        costs, div = plant.eval_seeds(K if flown is None else flown, noise.test)
    elif test_policy == "best":
        score = trajectory_mean(plant.eval_seeds(K, noise.select)[0])
        better = score < carry.best_cost
        best_K = jnp.where(better[:, None, None, None], K, carry.best_K)
        carry = carry._replace(best_K=best_K, best_cost=jnp.minimum(score, carry.best_cost))
        costs, div = plant.eval_seeds(best_K, noise.test)
    else:  # the uniform mixture: one of π_1..π_n drawn per test trajectory
        history = carry.history.at[:, n - 1].set(K)
        carry = carry._replace(history=history)

        def one_seed(hist, key, w):  # w [horizon, n_noise, n_test]
            pick = jax.random.randint(stream_key(key, SELECT), (w.shape[-1],), 0, n)
            return jax.vmap(plant.eval_one, in_axes=(0, -1))(hist[pick], w)

        costs, div = jax.vmap(one_seed, in_axes=(0, 0, 2))(history, keys, noise.test)
    return costs, div, carry


def _sampler_branches(nus: Sequence[Callable], samples: int):
    """The distinct drawing functions of the samplers ``nus``, each vmapped over seeds as
    ``f(keys [S], param)``, and per sampler its function's index and parameter (``[len(nus)]``
    arrays): samplers sharing one :class:`SharedSampler` ``draw`` (ν_e and ν_en) are one branch
    of the switch that picks a method's ν, so a program holds that function once."""
    index: dict[int, int] = {}  # id(draw) -> its branch
    draws, branch, param = [], [], []
    for f in nus:
        d = f.draw if isinstance(f, SharedSampler) else (lambda key, count, _, f=f: f(key, count))
        if id(d) not in index:
            index[id(d)] = len(draws)
            draws.append(d)
        branch.append(index[id(d)])
        param.append(f.param if isinstance(f, SharedSampler) else 0.0)
    branches = [jax.vmap(lambda k, q, d=d: d(k, samples, q), in_axes=(0, None)) for d in draws]
    return branches, jnp.asarray(branch, jnp.int32), jnp.asarray(param, jnp.float64)


def make_loop_program(
    plant: LoopPlant,
    agent: Agent,
    nu: Callable[[jax.Array, int], Transitions] | Sequence[Callable] | None,
    *,
    samples: int,
    iterations: int,
    n_test: int,
    mode: str = "trajectory",
    gamma: float = 0.99,
    test_policy: str = "last",
    diagnostics: Diagnostics | None = None,
    controller: Callable[[Any, jax.Array], Any] | None = None,
):
    """Build the :class:`LoopProgram` ``(start, step, noise, init, steps)``, jitted, over all
    seeds at once.

    Collection and the learner's update are vmapped over seeds; the solve runs as the agent's
    ``policies`` says (default seed by seed, ``seeds_in_turn``) and the test trajectories of all
    seeds as one batch (:meth:`Plant.eval_seeds`), all inside the same compiled call.

    ``start(keys [S], noise) -> (carry, Row)`` solves and tests the initial model (iteration 1);
    ``step(carry, keys, noise, n, p, which=0) -> (carry, Row)`` runs iteration ``n`` with policy
    fraction ``p``; ``noise`` is :func:`eval_noise` of the same keys. ``nu`` may be a list of
    samplers, of which ``which`` (traced, so one compiled program serves them all: ν_t, ν_e and
    ν_en, with DAgger, Batch and Abbeel) picks the one to draw from.

    ``controller(learner_state, K) -> policy`` (one seed; vmapped here): what ``plant`` flies in
    place of the gains ``K``, in the policy's training rollouts and its tests, e.g. the seed's
    model parameters for a model-predictive controller (:mod:`loopid.algorithms.mpc_plant`).
    ``K`` is still what the cell keeps and saves. Only ``test_policy = "last"`` (the best and
    the mixture keep gains). Default: the plant flies ``K``.
    """
    if test_policy not in TEST_POLICIES:
        raise ValueError(f"test_policy must be one of {TEST_POLICIES}, got {test_policy!r}")
    if controller is not None and test_policy != "last":
        raise ValueError(
            f"a controller flies the last policy only, got test_policy {test_policy!r}"
        )
    hist_len = iterations if test_policy == "mixture" else 1
    nus = [nu] if callable(nu) else list(nu or [])
    branches, branch, param = _sampler_branches(nus, samples)

    def seeds_in_turn(f, *args):
        """``f`` on each lane in turn (``lax.map``): a solver's ``cond`` then skips the branch it
        does not take (under ``vmap`` both branches would run)."""
        return jax.lax.map(lambda a: f(*a), args)

    def solve_and_test(carry: _Carry, keys, noise, n, p):
        """Solve every lane's model, then test all the policies in one batch."""
        if agent.policies is not None:
            K, info = agent.policies(carry.learner)
        else:
            K, info = seeds_in_turn(agent.policy, carry.learner)
        extra = {}
        if diagnostics is not None:
            diag, extra = seeds_in_turn(
                lambda d, s, k, q: diagnostics.update(d, s, k, q, n), carry.diag, carry.learner,
                K, p,
            )  # fmt: skip
            carry = carry._replace(diag=diag)
        flown = None if controller is None else jax.vmap(controller)(carry.learner, K)
        costs, div, carry = _evaluate(plant, carry, K, keys, noise, n, test_policy, flown)
        stats = (trajectory_mean(costs), jnp.median(costs, axis=1), jnp.sum(div, axis=1))
        return carry, (*stats, info, extra)

    def first(key):
        state = agent.init()
        K = jax.eval_shape(agent.policy, state)[0]  # iteration 1 of ``step`` solves it
        K = jnp.zeros(K.shape, K.dtype)
        return _Carry(
            learner=state,
            K=K,
            best_K=K,
            best_cost=jnp.float64(jnp.inf),
            history=jnp.zeros((hist_len, *K.shape), K.dtype),
            loss_sum=jnp.float64(0.0),
            diag=diagnostics.init() if diagnostics is not None else (),
        )

    init = jax.jit(jax.vmap(first))

    def nu_draws(keys, n, which):
        """ν's draws for every lane, ``[M·S, ...]`` (None without ν: a lane's policy draws
        stand in). ν depends on the seed and iteration only, so each sampler the lanes use
        draws once per seed and the methods' lanes share the draws: one method's lanes draw
        from its sampler alone (``which [1]``, a switch), several methods' lanes from every
        sampler (each once, whichever methods use it)."""
        if not nus:
            return None
        methods = which.shape[0]
        nu_keys = jax.vmap(lambda k: iteration_keys(k, n).nu)(keys)

        def drawn(kind):  # one sampler's draws, its drawing function picked by a switch
            return jax.lax.switch(branch[kind], branches, nu_keys, param[kind])

        if len(nus) == 1:
            one = jax.vmap(lambda k: nus[0](k, samples))(nu_keys)
        elif methods == 1:
            one = drawn(which[0])
        else:
            # each sampler under the same switch as a single method's (a lax.map over the kinds
            # keeps the index traced): drawn outside one, ν_e's and ν_en's last bits changed
            every = jax.lax.map(drawn, jnp.arange(len(nus)))
            return jax.tree_util.tree_map(lambda a: a[which].reshape(-1, *a.shape[2:]), every)
        return jax.tree_util.tree_map(lambda a: jnp.concatenate([a] * methods), one)

    def learn(carry: _Carry, key, n, p, from_nu):
        keys = iteration_keys(key, n)
        policy = carry.K if controller is None else controller(carry.learner, carry.K)
        from_pol = policy_samples(plant, policy, keys.policy, samples, mode=mode, gamma=gamma)
        if from_nu is None:
            from_nu = from_pol
        learner, loss_sum, stats = learning_step(
            agent, carry.learner, carry.loss_sum, from_pol, from_nu, keys.mix, n, p, samples
        )
        return carry._replace(learner=learner, loss_sum=loss_sum), stats

    def learn_lanes(carry: _Carry, keys, lane_keys, n, p, which):
        from_nu = nu_draws(keys, n, which)
        nu_axis = None if from_nu is None else 0
        return jax.vmap(learn, in_axes=(0, 0, None, 0, nu_axis))(carry, lane_keys, n, p, from_nu)

    def skip(carry: _Carry, keys, lane_keys, n, p, which):
        stats = jax.eval_shape(learn_lanes, carry, keys, lane_keys, n, p, which)[1]
        return carry, jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), stats)

    def step(carry: _Carry, keys, noise, n, p, which=0):
        """Iteration ``n`` of every lane: ``keys [S]`` the seeds', ``p``, ``which`` scalars (one
        method) or ``[M]`` (M methods; the carry's lanes ``[M·S]``, method-major; ``noise``
        the lanes' :func:`lane_noise`). Iteration 1 collects nothing: the learning half is
        skipped (a ``cond`` on ``n``, so only the taken branch runs) and its statistics are
        zeros."""
        p, which = jnp.atleast_1d(p), jnp.atleast_1d(which)
        lane_keys = _lane_keys(keys, p.shape[0])
        lane_p = jnp.repeat(p, keys.shape[0])
        args = (carry, keys, lane_keys, n, lane_p, which)
        carry, stats = jax.lax.cond(n > 1, learn_lanes, skip, *args)
        carry, (mean, median, div, info, extra) = solve_and_test(carry, lane_keys, noise, n, lane_p)
        return carry, Row(
            test_cost=mean, test_cost_median=median, diverged=div, **stats._asdict(),
            solver_converged=info.converged, spectral_radius=info.spectral_radius, extra=extra,
        )  # fmt: skip

    # the carry is donated: run_learning never reads the old one, and XLA then updates the
    # learner's sufficient statistics in place instead of copying them (~110 MB on the funnel)
    step_program = jax.jit(step, donate_argnums=0)

    @functools.partial(jax.jit, donate_argnums=0)
    def steps(carry: _Carry, keys, noise, ns, ps, which):
        """Iterations ``ns [B]`` of every lane as one ``lax.scan`` of ``step`` (``ps [B, M]``
        their policy fractions, ``which [M]``): the carry after them and their rows stacked,
        leaves ``[B, M·S]``. The same computation as ``step`` called B times, compiled inside
        a loop: bit for bit on the helicopter's lane sets (measured on a CPU), within one ulp in
        a few rows of a finite MDP's. (A block is never padded with iterations that a ``cond``
        skips: that ``cond`` moved the hover's test costs by up to 7e-4 relative.)"""
        return jax.lax.scan(lambda c, x: step(c, keys, noise, *x, which), carry, (ns, ps))

    def start(keys, noise, methods: int = 1):
        """Iteration 1 of ``methods`` methods' lanes (``noise``: the lanes' :func:`lane_noise`):
        the initial model solved and tested (the same compiled ``step``)."""
        lanes = init(_lane_keys(keys, methods))
        return step_program(lanes, keys, noise, *_first_iteration(methods))

    return LoopProgram(start, step_program, noise_program(plant, n_test, test_policy), init, steps)


def _lane_keys(keys: jax.Array, methods: int) -> jax.Array:
    """Each lane's seed key, ``[M·S]`` method-major, from the seeds' ``keys [S]``."""
    return jnp.concatenate([keys] * methods) if methods > 1 else keys


def _first_iteration(methods: int) -> tuple:
    """``(n, p, which)`` of iteration 1 for ``methods`` methods (``p`` and ``which`` unused
    there: iteration 1 collects nothing)."""
    return jnp.int32(1), jnp.zeros(methods), jnp.zeros(methods, jnp.int32)


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
    carry = jax.eval_shape(lambda k, w: program.start(k, w, methods)[0], keys, noise)
    if block > 1 and program.steps is not None:  # as run_lanes runs it
        ns = jax.ShapeDtypeStruct((block,), jnp.int32)
        ps = jax.ShapeDtypeStruct((block, methods), jnp.float64)
        which = jax.ShapeDtypeStruct((methods,), jnp.int32)
        lowered = program.steps.lower(carry, keys, noise, ns, ps, which)
    else:
        lowered = program.step.lower(carry, keys, noise, *_first_iteration(methods))
    return max(peak, program_bytes(lowered.compile()))


def run_learning(
    plant: LoopPlant,
    agent: Agent,
    nu,
    fractions,
    seeds,
    *,
    samples: int,
    n_test: int,
    mode: str = "trajectory",
    gamma: float = 0.99,
    test_policy: str = "last",
    progress: Callable[[int, Row], None] | None = None,
    program: LoopProgram | None = None,
    which: int = 0,
    noise: EvalNoise | None = None,
    cell: LoopProgram | None = None,
) -> Trace:
    """Run one learning method for ``len(fractions)`` iterations on every seed
    (:func:`run_lanes` with one method).

    ``fractions[n−1]`` is the probability ``p_n`` that a slot of iteration n's batch comes from
    the policy (``fractions[0]`` is unused: iteration 1 collects nothing). ``progress(n, row)`` is
    called after each iteration with that iteration's :class:`Row` (leaves ``[S]``).
    ``program``: a :class:`LoopProgram` from :func:`make_loop_program` with the same arguments,
    to reuse its compilation across methods (DAgger, Batch, Abbeel) and calls (``cell``: its
    earlier name); ``which`` picks the ν of a list. ``noise``: the seeds' :class:`EvalNoise`
    (default: the program's ``noise(keys)``).
    """
    program = renamed_argument("run_learning", "cell", "program", cell, program)
    return run_lanes(
        plant, agent, nu, [fractions], seeds, samples=samples, n_test=n_test, mode=mode,
        gamma=gamma, test_policy=test_policy, progress=progress, program=program,
        which=[which], noise=noise,
    )[0]  # fmt: skip


def run_lanes(
    plant: LoopPlant,
    agent: Agent,
    nu,
    schedules,
    seeds,
    *,
    samples: int,
    n_test: int,
    mode: str = "trajectory",
    gamma: float = 0.99,
    test_policy: str = "last",
    progress: Callable[[int, Row], None] | None = None,
    program: LoopProgram | None = None,
    which: Sequence[int] = (0,),
    noise: EvalNoise | None = None,
    cell: LoopProgram | None = None,
    block: int = 1,
) -> list[Trace]:
    """Run M learning methods on every seed as one *lane set*: the lanes are the (method, seed)
    pairs, ``M·S`` of them, method-major, and every iteration of all of them is one call of the
    program's ``step`` (with ``block``, a block of iterations one call of its ``steps``;
    ``program``, ``cell``: as in :func:`run_learning`). Returns one :class:`Trace` per method.

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
    program = renamed_argument("run_lanes", "cell", "program", cell, program)
    if program is None:
        program = make_loop_program(
            plant, agent, nu, samples=samples, iterations=iterations, n_test=n_test, mode=mode,
            gamma=gamma, test_policy=test_policy,
        )  # fmt: skip
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
    if agent.params is not None:
        final |= jax.vmap(agent.params)(carry.learner)
    if test_policy == "best":
        final["best_K"] = carry.best_K
    if test_policy == "mixture":
        final["history"] = carry.history
    rows, final = jax.device_get((rows, final))  # to NumPy once, then each method's a view
    S = len(keys)
    return [
        _trace(
            seeds,
            samples,
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
    transfer. Iteration 1's ``p`` is :func:`_first_iteration`'s (the diagnostics read it); its
    ``which`` is the methods' own, unused there (iteration 1 collects nothing)."""
    methods, iterations = schedules.shape
    carry = program.init(_lane_keys(keys, methods))
    ps = schedules.T.copy()
    ps[0] = _first_iteration(methods)[1]  # iteration 1's p, as start passes it
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
    return _trace(seeds, samples, rows, {"K": jnp.broadcast_to(K, (S, *K.shape))})


#: The fewest seeds a compiled cell computes at once. XLA's CPU backend lowers a batch of one or
#: two seeds differently from larger ones (measured: a seed's rows then differ in their last
#: bits, which a diverging test trajectory amplifies), so :func:`at_least` pads smaller runs and a
#: seed's numbers are the same however many seeds run beside it
#: (:mod:`loopid.experiments.chunks`).
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


def _trace(seeds, samples: int, rows: list[Row], final: dict | None = None) -> Trace:
    stacked = jax.tree_util.tree_map(lambda *a: np.stack([np.asarray(x) for x in a], axis=1), *rows)
    n = len(rows)
    iteration = np.arange(1, n + 1)
    final = None if final is None else {k: np.asarray(v) for k, v in final.items()}
    return Trace(np.asarray(seeds), iteration, (iteration - 1) * samples, stacked, final)


#: Names of earlier releases (warn, and go in the next one).
__getattr__ = renamed(
    __name__,
    {
        "Cell": ("loopid.algorithms.contracts", "LoopProgram"),
        "make_cell": (__name__, "make_loop_program"),
        "cell_memory": (__name__, "program_memory"),
    },
)

__all__ = [  # the contracts and key streams, importable from here as before
    "EVALUATE", "TEST_POLICIES", "Agent", "Diagnostics", "EvalNoise", "IterationKeys",
    "LoopProgram", "Row", "SolverInfo", "Trace", "at_least", "cut_seeds", "drive", "eval_noise",
    "iteration_block", "iteration_key", "iteration_keys", "lane_noise", "learning_step",
    "make_loop_program", "noise_program", "pad_seeds", "program_memory", "run_fixed_policy",
    "run_lanes", "run_learning", "seed_keys", "trajectory_mean",
]  # fmt: skip
