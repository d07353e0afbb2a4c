"""A gym scenario's agent, compiled once: the cost, the nominal model, the model class, the
planner and the host loop program every method of a run shares.

In the env's coordinates (``Δx [n] = [o[observe] − o*; 1]``, ``Δu [m] = a − a_op``) the agent is
the paper's by default: a linear offset model learned by FTRL on top of a nominal ``A [n, n]``,
``B [n, m]`` (``A = I``, ``B = 0`` unless given; ``[T, n, n]``, ``[T, n, m]`` when
``time_varying``) and LQR on the cost's ``Q`` (zero on the constant entry) and ``R``. Another
``[model] kind`` is planned by iLQR (``[planner] kind = "ilqr"``) or re-planned every few steps
by MPC (``"mpc"``), keeping the action box by a penalty
(:func:`loopid.control.quadratic_cost` with ``u_limit``, or :class:`loopid.control.Penalized`
around a ``[planner] cost``). :func:`compiled_agent` is cached on the scenario and the env's
:class:`~loopid.experiments.families.gym.env.EnvShape`, so every method of a run shares one
compilation.
"""

import importlib
from functools import lru_cache
from typing import Any, NamedTuple

import jax
import numpy as np

from loopid.algorithms import agents
from loopid.algorithms.gym_loop import gym_nominal_model, make_host_program
from loopid.experiments.families.gym.env import EnvShape
from loopid.experiments.families.gym.scenario import GymScenario
from loopid.models.linear_offset import LinearOffsetModel
from loopid.settings import model_planner
from loopid.systems.from_gymnasium import ObservationCost, observation_cost


def import_callable(name: str, what: str):
    """The callable ``module:function`` ``name`` of the field ``what``; one-line ValueError."""
    mod, _, attr = name.partition(":")
    try:
        obj = getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError, ValueError):
        raise ValueError(f"{what} = {name!r} is not an importable 'module:function'") from None
    if not callable(obj):
        raise ValueError(f"{what} = {name!r} is not callable")
    return obj


def checked(what: str, f, *args, **kwargs):
    """Call ``f``; prefix a ValueError's one line with the table it concerns."""
    try:
        return f(*args, **kwargs)
    except ValueError as err:
        raise ValueError(f"[{what}] {str(err).splitlines()[0]}") from None


def design_cost(v: dict, shape: EnvShape) -> ObservationCost:
    """The ``[cost]`` table's quadratic on the observed entries and the actions (what the
    controller is designed for), from a scenario's plain values ``v``
    (:attr:`~.scenario.GymScenario.plain`); ValueError when ``Q`` or ``R`` does not fit."""
    sizes = (("Q", shape.n_obs, "observed entries"), ("R", shape.m, "actions"))
    for name, size, what in sizes:
        M = np.asarray(v[name], dtype=np.float64)
        if M.ndim >= 1 and M.shape[0] != size:
            raise ValueError(
                f"[cost] {name} must be {size}x{size} or {size} diagonal entries "
                f"({v['env_id']} has {size} {what}), got shape {M.shape}"
            )
    return checked("cost", observation_cost, np.asarray(shape.target), v["Q"], v["R"],
                   np.asarray(shape.a_op))  # fmt: skip


def nominal(v: dict, shape: EnvShape) -> LinearOffsetModel:
    """The ``[model]`` table's nominal ``A``, ``B`` in the env's coordinates (what every seed's
    learned offsets add to), from a scenario's :attr:`~.scenario.GymScenario.plain` ``v``."""
    return checked("model", gym_nominal_model, shape, v["A"], v["B"],
                   time_varying=v["time_varying"])  # fmt: skip


class CompiledAgent(NamedTuple):
    """A scenario's agent, its compiled host loop program
    (:func:`loopid.algorithms.gym_loop.make_host_program`) and what flies its policy's episodes
    (``controller(learner_states, K) -> policy``; None: the gains). Under ``[planner] kind =
    "mpc"``: ``mpc(params) -> policy``, the MPC of the models ``params`` (a leading seed axis),
    and ``model``, the model class whose saved arrays it re-plans on (``loopid evaluate``)."""

    agent: Any
    program: Any
    controller: Any = None
    mpc: Any = None
    model: Any = None


@lru_cache(maxsize=4)
def compiled_agent(s: GymScenario, shape: EnvShape) -> CompiledAgent:
    """The :class:`CompiledAgent` of ``s`` on an env of ``shape`` (kept: every method of a run
    shares it)."""
    v = s.plain
    cost = design_cost(v, shape)
    model = nominal(v, shape)
    spec = model_planner.specs(s)
    if agents.is_paper_agent(spec):
        Q, R = cost.augmented()  # sized to the system by design_cost
        agent = agents.make_agent(spec, model, Q, R, shape.horizon)
        return CompiledAgent(agent, make_host_program(agent, samples=s.samples))
    return _planning_agent(s, spec, v, shape, cost, model)


def _start(start, shape: EnvShape) -> np.ndarray:
    """Δx of ``[planner] start`` (default the target): where an iLQR plan starts."""
    if start is None:
        return np.concatenate([np.zeros(shape.n_obs), [1.0]])
    o = np.asarray(start, np.float64)
    if o.shape != (shape.n_obs,) or not np.all(np.isfinite(o)):
        raise ValueError(
            f"[planner] start must be {shape.n_obs} finite numbers (the observed entries), "
            f"got {start!r}"
        )
    return np.concatenate([o - np.asarray(shape.target), [1.0]])


def _planning_agent(s: GymScenario, spec, v: dict, shape: EnvShape, cost, nominal) -> CompiledAgent:
    """A model class of :mod:`loopid.algorithms.planning_agent` planned by iLQR (or MPC) on the
    cost's Q, R, with the action box kept by :func:`loopid.control.action_penalty`."""
    from loopid.control import MPCController, Penalized, quadratic_cost

    start = _start(v["planner_start"], shape)
    Q, R = cost.augmented()
    if s.planner_cost is None:
        plan_cost = quadratic_cost(Q, R, u_limit=shape.u_limit)
    elif shape.u_limit is None:
        plan_cost = import_callable(s.planner_cost, "planner.cost")
    else:
        plan_cost = Penalized(import_callable(s.planner_cost, "planner.cost"), shape.u_limit)
    alternatives = None
    if v["planner_alternatives"] is not None:
        alternatives = np.asarray(v["planner_alternatives"], np.float64)
        if alternatives.shape[1] != shape.m:
            raise ValueError(
                f"[planner] alternatives must be action vectors of {shape.m} entries, "
                f"got {v['planner_alternatives']!r}"
            )
    mc = checked("model", agents.model_class, spec.model, spec.learner, nominal)
    U0 = np.full((shape.horizon, shape.m), 0.1 * (shape.u_limit or 1.0))
    agent = agents.make_agent(
        spec, nominal, Q, R, shape.horizon, start=start, U0=U0, plan_cost=plan_cost, model=mc,
    )  # fmt: skip
    program = make_host_program(agent, samples=s.samples)
    if s.planner_kind != "mpc":
        return CompiledAgent(agent, program)

    def mpc(params):
        return MPCController(
            mc.dynamics, plan_cost, params, U0[0], horizon=s.planner_horizon or shape.horizon,
            target=shape.target, observe=shape.observe, a_op=shape.a_op,
            every=s.planner_every, iterations=s.planner_iterations, alternatives=alternatives,
            stacked=True,
        )  # fmt: skip

    def controller(states, K):
        return mpc(jax.vmap(mc.params)(states))

    return CompiledAgent(agent, program, controller, mpc, mc)
