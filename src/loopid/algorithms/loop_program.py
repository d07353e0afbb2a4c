"""Algorithm 1 of Ross & Bagnell (2012) as one compiled program for every seed at once:
:func:`make_loop_program` gives a :class:`~loopid.algorithms.contracts.LoopProgram`, whose
``step`` is one iteration, a pure function of a fixed-shape carry (:mod:`loopid.algorithms.loop`
runs it).

One *cell* is one method on one plant over N iterations for S seeds. Iteration ``n = 1`` solves
the initial model; each iteration ``n = 2..N`` draws ``m`` transitions with the policy ``π_{n−1}``
and the exploration distribution ν, gives them to the online learner, solves the new model for
``π_n`` and tests ``π_n`` on the real noisy system (the paper's Algorithm 1)::

    slot i of the batch  ←  a draw from running π_{n−1}   with probability p_n,
                            a draw from ν                   otherwise,

with ``p_n = ½`` for DAgger, ``0`` for Batch, and for Abbeel's method ``0`` at ``n = 2`` (ν = the
expert) and ``1`` afterwards (:mod:`loopid.experiments.families.helicopter.methods`). Both candidate
sets are always drawn (fixed shapes); the model's loss on each is recorded before the update, so
every method reports how well its model predicts its own policy's data and ν's (the train/test
mismatch).

The iteration is vmapped over seeds (and, in a lane set, over the methods' seeds: a method is
data, its ``p_n`` and its ν index) and jitted once; the iteration number and ``p_n`` are traced
arguments, so no iteration retraces. ``steps`` is a block of iterations as one ``lax.scan`` of
``step``.

Randomness (:mod:`loopid.algorithms.keys`, every stream named there): seed ``s`` has key ``k =
jax.random.key(s)``; training draws at iteration n use ``fold_in(fold_in(k, 1), n)``
(:func:`~loopid.algorithms.keys.iteration_keys`, shared by every loop). The test trajectories'
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

from loopid.algorithms.collect import policy_samples
from loopid.algorithms.contracts import (
    Agent,
    Diagnostics,
    EvalNoise,
    LoopPlant,
    LoopProgram,
    LoopSpec,
    Row,
    SharedSampler,
)
from loopid.algorithms.keys import SELECT, TEST, iteration_keys, stream_key
from loopid.algorithms.plant import noise_columns, ordered_sum
from loopid.algorithms.transitions import select

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
    (2, or :data:`~loopid.algorithms.keys.EVALUATE` for fresh noise) and, for ``best``, its
    selection noise from ``fold_in(k, 3)``, ``[horizon, n_noise, S, n_test]``.

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
    """One learning step's diagnostics (the :class:`~loopid.algorithms.contracts.Row` fields
    of the same names)."""

    loss_nu: jax.Array
    loss_policy: jax.Array
    online_loss: jax.Array
    policy_samples: jax.Array
    valid_samples: jax.Array


def no_stats(lanes: int, loss_dtype) -> LearnStats:
    """The statistics of an iteration that learns nothing (iteration 1), zeros for ``lanes``
    lanes: the losses ``[lanes]`` in ``loss_dtype``, the sample counts ``[lanes]`` in JAX's
    default integer (what :func:`learning_step`'s sums of masks give). Written out rather than
    read from a trace of the learning half (``jax.eval_shape``), which traced that half a second
    time in every program."""
    count = jax.dtypes.canonicalize_dtype(jnp.int_)
    return LearnStats(*(jnp.zeros(lanes, d) for d in (loss_dtype,) * 3 + (count,) * 2))


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
    arrays): samplers sharing one :class:`~loopid.algorithms.contracts.SharedSampler` ``draw``
    (ν_e and ν_en) are one branch of the switch that picks a method's ν, so a program holds
    that function once."""
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
    spec: LoopSpec,
    iterations: int,
    *,
    diagnostics: Diagnostics | None = None,
    controller: Callable[[Any, jax.Array], Any] | None = None,
):
    """Build the :class:`~loopid.algorithms.contracts.LoopProgram` ``(start, step, noise, init,
    steps)`` of the loop ``spec`` (:class:`~loopid.algorithms.contracts.LoopSpec`) over
    ``iterations`` iterations, jitted, over all seeds at once.

    Collection and the learner's update are vmapped over seeds; the solve runs as the agent's
    ``policies`` says (default seed by seed, ``seeds_in_turn``) and the test trajectories of all
    seeds as one batch (:meth:`Plant.eval_seeds`), all inside the same compiled call.

    ``start(keys [S], noise) -> (carry, Row)`` solves and tests the initial model (iteration 1);
    ``step(carry, keys, noise, n, p, which=0) -> (carry, Row)`` runs iteration ``n`` with policy
    fraction ``p``; ``noise`` is :func:`eval_noise` of the same keys. ``spec.nu`` may be a list of
    samplers, of which ``which`` (traced, so one compiled program serves them all: ν_t, ν_e and
    ν_en, with DAgger, Batch and Abbeel) picks the one to draw from.

    ``controller(learner_state, K) -> policy`` (one seed; vmapped here): what ``plant`` flies in
    place of the gains ``K``, in the policy's training rollouts and its tests, e.g. the seed's
    model parameters for a model-predictive controller (:mod:`loopid.algorithms.mpc_plant`).
    ``K`` is still what the cell keeps and saves. Only ``test_policy = "last"`` (the best and
    the mixture keep gains). Default: the plant flies ``K``.
    """
    plant, agent, nu, samples, n_test, mode, gamma, test_policy = spec
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
        return carry, no_stats(lane_keys.shape[0], carry.loss_sum.dtype)

    def step(carry: _Carry, keys, noise, n, p, which=0):
        """Iteration ``n`` of every lane: ``keys [S]`` the seeds', ``p``, ``which`` scalars (one
        method) or ``[M]`` (M methods; the carry's lanes ``[M·S]``, method-major; ``noise``
        the lanes' :func:`lane_noise`). Iteration 1 collects nothing: the learning half is
        skipped (a ``cond`` on ``n``, so only the taken branch runs) and its statistics are
        zeros."""
        p, which = jnp.atleast_1d(p), jnp.atleast_1d(which)
        lane_keys = lane_seed_keys(keys, p.shape[0])
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
        lanes = init(lane_seed_keys(keys, methods))
        return step_program(lanes, keys, noise, *first_iteration(methods))

    return LoopProgram(start, step_program, noise_program(plant, n_test, test_policy), init, steps)


def lane_seed_keys(keys: jax.Array, methods: int) -> jax.Array:
    """Each lane's seed key, ``[M·S]`` method-major, from the seeds' ``keys [S]``."""
    return jnp.concatenate([keys] * methods) if methods > 1 else keys


def first_iteration(methods: int) -> tuple:
    """``(n, p, which)`` of iteration 1 for ``methods`` methods (``p`` and ``which`` unused
    there: iteration 1 collects nothing)."""
    return jnp.int32(1), jnp.zeros(methods), jnp.zeros(methods, jnp.int32)
