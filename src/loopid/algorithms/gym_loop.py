"""Algorithm 1 stepped from the host: the loop for a Gymnasium env (a system that is not a JAX
function, :mod:`loopid.systems.from_gymnasium`).

Same semantics as :func:`loopid.algorithms.loop.run_learning`: iteration 1 solves the initial
model; iteration n = 2..N collects, for every seed, ``ceil(m / horizon)`` training slots of the
policy ``π_{n−1}`` and as many of the exploration policy ν (both always, fixed shapes), draws m
transitions uniformly without replacement among the valid steps of each (:func:`draw`), takes slot
i of the batch from the policy draws with probability ``p_n`` and from ν otherwise
(:func:`select`), records the model's loss on each set before the update, gives the batch to the
learner (each sample seen once), solves for ``π_n`` and tests it. The rows are the same
:class:`~loopid.algorithms.contracts.Row` diagnostics.

Only the plant differs: collection and testing are Python driving the vector env; the learner's
update, its losses and the solve are one jitted function vmapped over seeds (compiled once per
run and shared by every method through ``program``).

Randomness: slot seeds are ``SeedSequence([seed, n, stream]).generate_state(k, uint32)`` with
the host streams of :mod:`loopid.algorithms.keys`: 1 (policy), 2 (ν) and 3 (test, with n = 0:
the same test episodes at every iteration and for every method at that seed, i.e. common random
numbers); each slot seeds its env resets and action noise (:mod:`loopid.systems.gym_slots`).
The draws and the policy/ν choice use the JAX loop's keys
(:func:`loopid.algorithms.keys.iteration_keys`), and the learning step is the JAX loop's
(:func:`loopid.algorithms.loop_program.learning_step`).

Test cost of one episode: ``Σ_t c(o_t, a_t)`` over the actions taken (plus ``termination_cost`` if
it ended by ``terminated``), capped at ``cost_cap``; an episode that reaches the cap or a non-finite
value counts as diverged. ``c`` is a :class:`~loopid.systems.gym_cost.ObservationCost` (on the
observed entries), ``"reward"`` (the env's own reward, negated: ``c_t = −r_t``) or any callable
``cost(obs, action) -> float`` on the raw observation. The tested policy is the last one, or
with ``test_policy = "best"`` the best so far: each seed's π_n is scored by its mean capped cost
on episodes of its own (slot stream 5, :data:`~loopid.algorithms.keys.HOST_SELECT`, the same at
every iteration), kept when strictly cheaper than the best before it, and the kept one is tested
(as :func:`loopid.algorithms.loop.run_learning`'s ``best``: on random episodes the reported
cost is not the selection's, so it is not biased by it; from a deterministic start the two are
the same episode, and the reported cost is each seed's running minimum).
"""

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.agents import paper_agent
from loopid.algorithms.contracts import Agent, Row, Trace, Transitions
from loopid.algorithms.keys import (
    HOST_EVALUATE,
    HOST_NU,
    HOST_POLICY,
    HOST_SELECT,
    HOST_TEST,
    iteration_keys,
    seed_keys,
)
from loopid.algorithms.loop import drive
from loopid.algorithms.loop_program import learning_step
from loopid.algorithms.transitions import draw
from loopid.models.linear_offset import LinearOffsetModel
from loopid.systems.from_gymnasium import GymSystem
from loopid.systems.gym_cost import ObservationCost
from loopid.systems.gym_slots import Rollouts, Slot

#: The slot stream of ``loopid evaluate``'s episodes: noise the run never saw.
EVALUATE = HOST_EVALUATE


class Exploration(NamedTuple):
    """ν for a system with a reset model only: rollouts of ``policy`` (an object with
    ``act(obs [k, n_obs], t [k], index [k]) -> [k, m]``: a base policy, a gain, an open-loop
    nominal) with Gaussian action noise of std ``action_std``."""

    policy: Any
    action_std: float = 0.0


def gym_nominal_model(system: GymSystem, A=None, B=None, *, time_varying: bool = False):
    """The initial linear offset model in the system's coordinates ``Δx = [o − o*; 1]``.

    ``A``: ``[n, n]`` or ``[n_obs, n_obs]`` (embedded with the constant kept at 1), default the
    identity; ``B``: ``[n, m]`` or ``[n_obs, m]`` (zero row for the constant), default zeros.
    ``time_varying``: the same pair at every one of the ``horizon`` steps, offsets learned per step.
    """
    n, n_obs, m = system.n, system.n_obs, system.m
    if A is None:
        A = np.eye(n)
    A = np.asarray(A, dtype=np.float64)
    if A.shape == (n_obs, n_obs):
        A = np.block([[A, np.zeros((n_obs, 1))], [np.zeros((1, n_obs)), np.ones((1, 1))]])
    if A.shape != (n, n) or not np.all(np.isfinite(A)):
        raise ValueError(f"model A must be finite, {n_obs}x{n_obs} or {n}x{n}, got shape {A.shape}")
    B = np.zeros((n, m)) if B is None else np.asarray(B, dtype=np.float64)
    if B.shape == (n_obs, m):
        B = np.concatenate([B, np.zeros((1, m))], axis=0)
    if B.shape != (n, m) or not np.all(np.isfinite(B)):
        raise ValueError(f"model B must be finite, {n_obs}x{m} or {n}x{m}, got shape {B.shape}")
    if time_varying:
        T = system.horizon
        A, B = np.broadcast_to(A, (T, n, n)), np.broadcast_to(B, (T, n, m))
    return LinearOffsetModel(jnp.asarray(A), jnp.asarray(B))


def gym_agent(system: GymSystem, cost: ObservationCost, model: LinearOffsetModel, *, lam=1e-3):
    """The paper's agent (:func:`loopid.algorithms.agents.paper_agent`) for ``system``: ``model``
    + FTRL(λ) + LQR (time-varying LQR for a time-varying model) on the cost's ``Q`` (zero on the
    constant coordinate) and ``R``, over the system's horizon."""
    Q, R = cost.augmented()
    if Q.shape[0] != system.n or R.shape[0] != system.m:
        raise ValueError(
            f"cost is for {Q.shape[0] - 1} observations and {R.shape[0]} actions, "
            f"the system has {system.n_obs} and {system.m}"
        )
    return paper_agent(model, lam, Q, R, system.horizon)


def slot_seeds(seed: int, n: int, stream: int, count: int) -> list[int]:
    """``count`` slot seeds of one (seed, iteration, stream)."""
    state = np.random.SeedSequence([int(seed), int(n), int(stream)]).generate_state(count)
    return [int(s) for s in state]


class HostLoopProgram(NamedTuple):
    """The jitted, seed-vmapped pieces: ``start(S) -> (carry, K, info)`` and ``learn(carry, pol,
    nu, keys, n, p) -> (carry, K, info, stats)``."""

    start: Callable
    learn: Callable


class _Carry(NamedTuple):
    learner: Any
    loss_sum: jax.Array


def make_host_program(agent: Agent, *, samples: int, with_nu: bool = True) -> HostLoopProgram:
    """Compile-once pieces of :func:`run_learning_host` (shared by methods differing in ``p_n``)."""

    def first(_):
        state = agent.init()
        K, info = agent.policy(state)
        return _Carry(state, jnp.float64(0.0)), K, info

    @jax.jit
    def start(dummy):
        return jax.vmap(first)(dummy)

    def one(carry: _Carry, pol: Transitions, nu: Transitions, key, n, p):
        keys = iteration_keys(key, n)
        from_pol = draw(pol, keys.policy, samples)
        from_nu = draw(nu, keys.nu, samples) if with_nu else from_pol
        learner, loss_sum, stats = learning_step(
            agent, carry.learner, carry.loss_sum, from_pol, from_nu, keys.mix, n, p, samples
        )
        K, info = agent.policy(learner)
        return _Carry(learner, loss_sum), K, info, stats

    learn = jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, None, None)))
    return HostLoopProgram(start, learn)


def _transitions(r: Rollouts, S: int) -> Transitions:
    """Slots ``[S·R, T]`` (seed-major) as JAX Transitions ``[S, R·T]``."""

    def f(a, dtype):
        return jnp.asarray(a.reshape(S, -1, *a.shape[2:]), dtype)

    return Transitions(
        f(r.x, jnp.float64), f(r.dx, jnp.float64), f(r.du, jnp.float64),
        f(r.dx_next, jnp.float64), f(r.t, jnp.int32), f(r.mask, jnp.bool_),
    )  # fmt: skip


def episode_costs(system: GymSystem, r: Rollouts, cost, *, termination_cost=0.0, cost_cap=1e8):
    """Capped total costs ``[R]`` and diverged flags ``[R]`` of test slots (module docstring).

    ``cost``: a :class:`ObservationCost` (on the observed entries, all rows at once), ``"reward"``
    (``−r_t``) or ``cost(obs, action) -> float`` on the raw observation, row by row.
    """
    action = r.du + system.a_op
    if isinstance(cost, ObservationCost):
        stage = np.where(r.mask, cost(system.observed(r.x), action), 0.0)
    elif isinstance(cost, str):
        if cost != "reward":
            raise ValueError(
                f"cost must be an ObservationCost, 'reward' or a callable, got {cost!r}"
            )
        stage = np.where(r.mask, -r.reward, 0.0)
    else:
        stage = np.zeros(r.mask.shape)
        for i, j in zip(*np.nonzero(r.mask), strict=True):
            stage[i, j] = float(cost(r.x[i, j], action[i, j]))
    with np.errstate(over="ignore", invalid="ignore"):
        total = stage.sum(axis=1) + termination_cost * r.terminated
    diverged = ~r.finite | ~np.isfinite(total) | (total >= cost_cap)
    return np.where(diverged, cost_cap, total), diverged


def test_episodes(
    system: GymSystem,
    K,
    seeds,
    n_test: int,
    cost,
    termination_cost=0.0,
    cost_cap=1e8,
    stream: int = HOST_TEST,
) -> tuple[np.ndarray, np.ndarray]:
    """Capped costs and diverged flags ``[S, n_test]`` of every seed's policy ``K [S, T, m, n]``
    on that seed's test episodes (slot seeds ``SeedSequence([seed, 0, stream])``; the default
    stream 3 gives the same episodes at every iteration, for every method, and for a policy
    reloaded later; :data:`EVALUATE` gives fresh ones). ``K`` may also be a policy object
    (``act(obs, t, index)``, the seed's index) such as a model-predictive controller."""
    S = len(seeds)
    slots = [
        Slot(0, s, x, 0.0, False) for s in range(S) for x in slot_seeds(seeds[s], 0, stream, n_test)
    ]
    policy = K if hasattr(K, "act") else system.linear_policy(np.asarray(K))
    r = system.rollouts([policy], slots)
    costs, div = episode_costs(
        system, r, cost, termination_cost=termination_cost, cost_cap=cost_cap
    )
    return costs.reshape(S, n_test), div.reshape(S, n_test)


def run_learning_host(
    system: GymSystem,
    agent: Agent,
    nu: Exploration | None,
    fractions,
    seeds,
    *,
    samples: int,
    n_test: int,
    cost,
    termination_cost: float = 0.0,
    cost_cap: float = 1e8,
    progress: Callable[[int, Row], None] | None = None,
    program: HostLoopProgram | None = None,
    controller: Callable[[Any, Any], Any] | None = None,
    test_policy: str = "last",
) -> Trace:
    """Run one learning method on a host system for ``len(fractions)`` iterations, every seed.

    ``fractions[n−1]`` = ``p_n`` (``fractions[0]`` unused); ``cost(obs, action) -> float`` is the
    test cost (:class:`~loopid.systems.gym_cost.ObservationCost` or any callable);
    ``progress(n, row)`` after each iteration; ``program`` from :func:`make_host_program` to reuse
    its compilation.
    ``controller(learner_states, K) -> policy``: what flies the policy's training and test
    episodes, given every seed's learner state (leading seed axis) and gains (a model-predictive
    controller re-plans on the seed's model); default the gains ``K`` themselves.
    ``test_policy``: ``last`` or ``best`` (module docstring; gains only, not a controller); with
    ``best`` the Trace's ``final`` also holds ``best_K``, the tested gains.
    """
    if test_policy not in ("last", "best"):
        raise ValueError(f"test_policy must be 'last' or 'best' here, got {test_policy!r}")
    if controller is not None and test_policy != "last":
        raise ValueError(
            f"a controller flies the last policy only, got test_policy {test_policy!r}"
        )
    fractions = np.asarray(fractions, dtype=np.float64)
    N = int(fractions.shape[0]) if fractions.ndim == 1 else 0
    if N < 1:
        raise ValueError(f"fractions must be a non-empty vector, got shape {fractions.shape}")
    if ((fractions < 0) | (fractions > 1)).any():
        raise ValueError(f"policy fractions must lie in [0, 1], got {fractions.tolist()}")
    for name, v in (("samples", samples), ("n_test", n_test)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
    keys = seed_keys(seeds)
    seeds = np.asarray(seeds)
    S = len(seeds)
    if program is None:
        program = make_host_program(agent, samples=samples, with_nu=nu is not None)
    runs = -(-samples // system.horizon)

    def flies(carry, K):
        if controller is None:
            return system.linear_policy(np.asarray(K))
        return controller(carry.learner, K)

    def test(carry, K, best) -> tuple:
        """The tested policy's (mean, median, diverged) [S] and the best so far ``(K, score)``."""
        if test_policy == "best":
            scores = test_episodes(system, np.asarray(K), seeds, n_test, cost, termination_cost,
                                   cost_cap, stream=HOST_SELECT)[0].mean(1)  # fmt: skip
            better = scores < best[1]
            K = np.where(better.reshape(-1, *[1] * (np.ndim(K) - 1)), K, best[0])
            best = (K, np.where(better, scores, best[1]))
        policy = flies(carry, K)
        costs, div = test_episodes(system, policy, seeds, n_test, cost, termination_cost, cost_cap)
        return (costs.mean(1), np.median(costs, axis=1), div.sum(1)), best

    def start():
        carry, K, info = program.start(jnp.zeros(S))
        zero, count = np.zeros(S), np.zeros(S, np.int64)
        stats, best = test(carry, K, (np.asarray(K), np.full(S, np.inf)))
        return (carry, K, best), _row(*stats, zero, zero, zero, count, count, info)

    def step(state, n):
        carry, K, best = state
        policies = [flies(carry, K)]
        slots = [
            Slot(0, s, x, 0.0, True)
            for s in range(S)
            for x in slot_seeds(seeds[s], n, HOST_POLICY, runs)
        ]
        if nu is not None:
            policies.append(nu.policy)
            slots += [
                Slot(1, s, x, float(nu.action_std), True)
                for s in range(S)
                for x in slot_seeds(seeds[s], n, HOST_NU, runs)
            ]
        r = system.rollouts(policies, slots)
        half = S * runs
        pol = _transitions(Rollouts(*(a[:half] for a in r)), S)
        from_nu = _transitions(Rollouts(*(a[half:] for a in r)), S) if nu is not None else pol
        carry, K, info, stats = program.learn(
            carry, pol, from_nu, keys, jnp.int32(n), jnp.float64(fractions[n - 1])
        )
        tested, best = test(carry, K, best)
        return (carry, K, best), _row(*tested, *(np.asarray(a) for a in stats), info)

    (carry, K, best), rows = drive(start, step, N, progress)
    final = {"K": K}
    if test_policy == "best":
        final["best_K"] = best[0]
    if agent.params is not None:
        final |= jax.vmap(agent.params)(carry.learner)
    return Trace.from_rows(seeds, samples, rows, final)


def _row(mean, median, div, loss_nu, loss_pol, online, pol_n, valid_n, info) -> Row:
    fields = dict(
        test_cost=np.asarray(mean, np.float64),
        test_cost_median=np.asarray(median, np.float64),
        diverged=np.asarray(div, np.int64),
        loss_nu=np.asarray(loss_nu, np.float64),
        loss_policy=np.asarray(loss_pol, np.float64),
        online_loss=np.asarray(online, np.float64),
        policy_samples=np.asarray(pol_n, np.int64),
        valid_samples=np.asarray(valid_n, np.int64),
        solver_converged=np.asarray(info.converged, bool),
        spectral_radius=np.asarray(info.spectral_radius, np.float64),
    )
    return Row(**fields, extra={})
