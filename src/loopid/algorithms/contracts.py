"""The contracts between the engine's parts: what an agent is, what an iteration reports, what a
cell returns.

- :class:`Transitions`: a fixed-shape batch of recorded transitions; :class:`LoopPlant`: what
  Algorithm 1 needs of a real system.
- :class:`Agent`: model class + online learner + optimal-control solver, as pure functions
  (Algorithm 1's "fit" and "solve"); built by a family from its config.
- :class:`SolverInfo`: the solve's status (converged, closed-loop spectral radius).
- :class:`Row`: one iteration's results per seed; :class:`Trace`: a cell's rows over
  iterations and what it ended with.
- :class:`Diagnostics`: an optional per-iteration hook for quantities only one system can
  compute.
- :class:`LoopSpec`: one learning loop's parts and protocol; :class:`LoopProgram`: its compiled
  programs; :class:`EvalNoise`: the seeds' test
  noise in the layout the test rollouts read.
- :class:`SharedSampler`: an exploration sampler ν that is a drawing function shared with other
  samplers, at its own parameter.

They are NamedTuples of arrays and pure functions, so they pass through ``jit`` and ``vmap``
(the sampler, a function itself, excepted).
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol, runtime_checkable

import jax
import numpy as np


class Transitions(NamedTuple):
    """A fixed-shape batch of recorded transitions ``(x_t, Δu_t, x_{t+1})``; leading axis ``[b]``.

    ``x`` is the raw state ``[n_x]`` (needed to query the system again), ``dx``/``dx_next`` the
    error coordinates relative to ``target[t]``/``target[t+1]``, ``t`` the target time index
    (int32), ``mask`` which rows hold real data. Masked rows are zero-filled, never NaN.
    """

    x: jax.Array
    dx: jax.Array
    du: jax.Array
    dx_next: jax.Array
    t: jax.Array
    mask: jax.Array


@runtime_checkable
class LoopPlant(Protocol):
    """What Algorithm 1 (:mod:`loopid.algorithms.loop_program`) needs of a real system: the
    contract that :class:`Plant` (JAX systems),
    :class:`loopid.experiments.families.mdp.agent.MDPPlant` (finite MDPs) and
    :func:`loopid.algorithms.mpc_plant.mpc_plant` implement. ``policy`` is what the plant flies:
    gains ``K [horizon, m, n]`` for :class:`Plant`, action probabilities ``[states, actions]`` for
    ``MDPPlant``, a model's parameters (any pytree) that MPC re-plans on for ``mpc_plant``. Shapes:
    ``S`` seeds, ``n_test`` test runs.

    - ``horizon``: steps of one training rollout and of one test trajectory.
    - ``rollout(policy, key) -> transitions [horizon]``: one training rollout (a NamedTuple of
      arrays with a leading ``[horizon]`` axis and a boolean ``mask``).
    - ``eval_noise(key, n_test) -> [n_test, ...]``: the noise of ``n_test`` test runs.
    - ``eval_one(policy, noise) -> (cost, diverged)``: one test run (scalars).
    - ``eval_seeds(policies, noise) -> (costs [S, n_test], diverged [S, n_test])``: every
      seed's test runs (``policies``: a leading seed axis); ``noise`` in the column layout of
      :func:`noise_columns`.
    """

    horizon: int

    def rollout(self, policy, key, *args): ...

    def eval_noise(self, key, n_test: int): ...

    def eval_one(self, policy, noise): ...

    def eval_seeds(self, policies, noise): ...


@dataclass(frozen=True)
class SharedSampler:
    """A sampler ν that is a drawing function shared with other samplers, at its own parameter:
    ``sampler(key, count) = draw(key, count, param)`` -> :class:`Transitions` of ``count`` rows.

    ν_e and ν_en are one ``draw`` (the expert's rollouts) at two action-noise levels
    (:func:`loopid.algorithms.exploration.make_nus`). A loop program that serves several samplers
    (its ``which``) compiles each distinct ``draw`` once and passes the parameter as a traced value,
    so the expert's rollouts appear in the program once, not once per ν. (A frozen dataclass,
    not a NamedTuple, so that it can be jitted like the plain function it stands for.)"""

    draw: Callable[[jax.Array, int, jax.Array], Transitions]
    param: float

    def __call__(self, key: jax.Array, count: int) -> Transitions:
        return self.draw(key, count, self.param)


class SolverInfo(NamedTuple):
    """The optimal-control solve's status: ``converged`` and the closed-loop spectral radius."""

    converged: jax.Array
    spectral_radius: jax.Array


class Agent(NamedTuple):
    """Model class + online learner + optimal-control solver, as pure functions.

    - ``init() -> state``: the learner's initial state (the initial model).
    - ``update(state, batch: Transitions) -> state``: one online-learning step on a batch (masked
      rows ignored).
    - ``policy(state) -> (K [horizon, m, n], SolverInfo)``: solve the optimal-control problem on
      the current model.
    - ``loss(state, batch) -> [b]``: per-row prediction loss of the current model, float64 (the
      loop's loss statistics are float64).
    - ``policies(states) -> (K [S, horizon, m, n], SolverInfo [S])`` (optional): ``policy`` of
      every seed (a leading seed axis), in whatever way suits the solver (batched, or seed by
      seed so that a ``cond`` skips the branch it does not take); default seed by seed.
    - ``params(state) -> {name: array}`` (optional): the learned model's parameters, what a run
      saves of it (:attr:`Trace.final`).
    """

    init: Callable[[], Any]
    update: Callable[[Any, Transitions], Any]
    policy: Callable[[Any], tuple[jax.Array, SolverInfo]]
    loss: Callable[[Any, Transitions], jax.Array]
    policies: Callable[[Any], tuple[jax.Array, SolverInfo]] | None = None
    params: Callable[[Any], dict] | None = None


class Row(NamedTuple):
    """One iteration's results, per seed (leaves ``[S]``); stacked over iterations in a Trace.

    - ``test_cost``: mean capped total cost over the test trajectories;
    - ``test_cost_median``: their median;
    - ``diverged``: how many reached the cap or a non-finite state;
    - ``loss_nu`` / ``loss_policy``: the model's mean squared prediction error, before the update,
      on this iteration's ν draws / policy draws (0 when there were none);
    - ``online_loss``: running average over iterations of the loss on the trained batch, before
      each update (the no-regret learner's average online loss);
    - ``policy_samples``: how many of the m trained transitions came from the policy;
    - ``valid_samples``: how many were usable (not cut by the safe region);
    - ``solver_converged``, ``spectral_radius``: the optimal-control solve's status;
    - ``extra``: ``{name: [S] array}`` from a :class:`Diagnostics` hook (empty without one).
    """

    test_cost: jax.Array
    test_cost_median: jax.Array
    diverged: jax.Array
    loss_nu: jax.Array
    loss_policy: jax.Array
    online_loss: jax.Array
    policy_samples: jax.Array
    valid_samples: jax.Array
    solver_converged: jax.Array
    spectral_radius: jax.Array
    extra: dict


class Diagnostics(NamedTuple):
    """An optional per-iteration hook for quantities only a particular system can compute (the
    exact finite-MDP bounds, say). ``init() -> state``; ``update(state, learner_state, K, p, n)
    -> (state, {name: scalar})`` runs after each solve (iteration n, policy ``K``, policy
    fraction ``p`` of the batch that was just learned from; ``p = 0`` at n = 1). The names become
    extra result columns."""

    init: Callable[[], Any]
    update: Callable[..., tuple[Any, dict]]


class Trace(NamedTuple):
    """All iterations of one cell: ``iteration [N]``, ``samples [N]`` (collected before the
    policy of that iteration was solved), ``rows`` (a :class:`Row` with leaves ``[S, N]``) and
    ``final``: what the cell ended with, ``{name: [S, ...] array}``: ``K`` the last policy's
    gains, the model's parameters (:attr:`Agent.params`), and ``best_K`` / ``history`` (every
    policy) when the test policy is the best one or the mixture."""

    seeds: np.ndarray
    iteration: np.ndarray
    samples: np.ndarray
    rows: Row
    final: dict | None = None

    @classmethod
    def from_rows(cls, seeds, samples: int, rows: list[Row], final: dict | None = None) -> "Trace":
        """The trace of a cell's ``rows`` (one :class:`Row` per iteration, leaves ``[S]``), of
        ``samples`` transitions per iteration: leaves stacked to ``[S, N]``, iteration n's
        ``samples`` = ``(n − 1) · samples``, ``final``'s leaves as NumPy arrays."""
        stacked = jax.tree_util.tree_map(
            lambda *a: np.stack([np.asarray(x) for x in a], axis=1), *rows
        )
        iteration = np.arange(1, len(rows) + 1)
        final = None if final is None else {k: np.asarray(v) for k, v in final.items()}
        return cls(np.asarray(seeds), iteration, (iteration - 1) * samples, stacked, final)


class LoopSpec(NamedTuple):
    """One learning loop: its parts and its protocol (Algorithm 1), what
    :func:`~loopid.algorithms.loop_program.make_loop_program` compiles and
    :func:`~loopid.algorithms.loop.run_lanes` runs on every seed.

    - ``plant``: the real system (:class:`LoopPlant`); ``agent``: model class, learner and
      solver (:class:`Agent`).
    - ``nu``: the exploration distribution ν, a sampler ``(key, m) -> Transitions``, or a list
      of them that each lane picks from by index (``which``), or None where a compiled program
      already holds them.
    - ``samples``: transitions collected per iteration (the paper's m); ``n_test``: test
      trajectories per evaluation.
    - ``mode``: how the policy's share of a batch is drawn (``trajectory``: uniformly among
      the steps of whole rollouts; ``geometric``: one step per rollout, stopped at step k with
      probability ∝ gamma^k: exact draws from the discounted state distribution
      ``D_{μ,π}``); ``gamma``: that discount.
    - ``test_policy``: the policy each iteration tests: the ``last`` one fitted, the ``best``
      so far (on a second noise set), or the uniform ``mixture`` of all so far.
    """

    plant: Any
    agent: Any
    nu: Any
    samples: int
    n_test: int
    mode: str = "trajectory"
    gamma: float = 0.99
    test_policy: str = "last"


class LoopProgram(NamedTuple):
    """The compiled programs of the learning loop (:func:`make_loop_program`): ``start(keys,
    noise) -> (carry, Row)``, ``step(carry, keys, noise, n, p, which) -> (carry, Row)`` and
    ``noise(keys) -> EvalNoise``
    (the seeds' test noise, :func:`noise_program`), each compiled once and reused by every
    method that shares the cell; ``init(lane_keys) -> carry`` (the lanes' state before
    iteration 1) and ``steps(carry, keys, noise, ns [B], ps [B, M], which [M]) -> (carry, rows
    [B, ...])``, a block of B iterations as one ``lax.scan`` of ``step``."""

    start: Callable
    step: Callable
    noise: Callable
    init: Callable | None = None
    steps: Callable | None = None


class EvalNoise(NamedTuple):
    """The test noise of every seed, ``test [horizon, n_noise, S, n_test]`` (the column layout
    of :meth:`loopid.algorithms.plant.Plant.eval_seeds`), and for ``best`` the selection noise
    ``select``, likewise."""

    test: jax.Array
    select: jax.Array
