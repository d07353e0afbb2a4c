"""The agent of an observed system, compiled once: the cost, the nominal model, the model class,
the planner and the host loop program every method shares.

An observed system is one the loop cannot step as a JAX function: a Gymnasium env stepped from
Python (:mod:`loopid.algorithms.gym_loop`) or a rig run by a person round by round. In its
coordinates (``Δx [n] = [o[observe] − o*; 1]``, ``Δu [m] = a − a_op``; :class:`EnvShape`) the
agent is the paper's by default (Ross & Bagnell 2012): a linear offset model learned by FTRL on
top of a nominal ``A [n, n]``, ``B [n, m]`` (``A = I``, ``B = 0`` unless given; ``[T, n, n]``,
``[T, n, m]`` when ``time_varying``) and LQR on the cost's ``Q`` (zero on the constant entry)
and ``R``. Another model class is planned by iLQR (planner kind ``ilqr``) or re-planned every
few steps by MPC (``mpc``), keeping the action box by a penalty
(:func:`loopid.control.quadratic_cost` with ``u_limit``, or :class:`loopid.control.Penalized`
around a planner cost of the user's). The agent is built by
:func:`loopid.algorithms.agents.make_agent`.

:func:`compiled_agent` is cached on its :class:`HostSpec` and :class:`EnvShape` (both frozen and
hashable), so every method of a run, and every round of a round directory, shares one
compilation. Every problem is one line of ``ValueError`` naming the setting's table.
"""

import importlib
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, NamedTuple

import jax
import numpy as np

from loopid.algorithms import agents
from loopid.algorithms.agents import AgentSpec
from loopid.algorithms.gym_loop import gym_nominal_model, make_host_program
from loopid.models.linear_offset import LinearOffsetModel
from loopid.systems.gym_cost import ObservationCost, observation_cost


class EnvShape(NamedTuple):
    """What the compiled agent depends on besides its settings (hashable): the sizes ``n``,
    ``n_obs``, ``m``, the horizon in steps, the target ``o*`` [n_obs], the operating action
    ``a_op`` [m], the observed entries, and ``u_limit``: the largest ``|Δu|`` every action
    entry may take inside the action box (a planner keeps its plan inside it; None when the
    box is unbounded or ``a_op`` sits on its edge)."""

    n: int
    n_obs: int
    m: int
    horizon: int
    target: tuple
    a_op: tuple
    observe: tuple | None = None
    u_limit: float | None = None


@dataclass(frozen=True, kw_only=True)
class HostSpec:
    """The settings of an observed system's agent, as frozen TOML values (tuples for lists).

    Attributes:
      system: what messages call the system (the env id, ``[system]``).
      Q, R: the ``[cost]`` table's quadratic on the observed entries and the actions (full
        matrices, diagonals or scalars): what the controller is designed for.
      A, B, time_varying: the ``[model]`` table's nominal model (None: ``A = I``, ``B = 0``).
      start: the ``[planner]`` table's observation an iLQR plan starts from (None: the target).
      cost: the ``[planner]`` table's ``module:function`` cost (None: the quadratic).
      samples: transitions per iteration (the host loop program's batch).
      agent: the model class, learner and planner (:class:`~loopid.algorithms.agents.AgentSpec`).
    """

    system: str
    Q: Any
    R: Any
    A: Any
    B: Any
    time_varying: bool
    start: Any
    cost: str | None
    samples: int
    agent: AgentSpec


def _listed(v):
    """A frozen TOML value with its tuples as lists, as the file wrote it (for messages)."""
    return [_listed(x) for x in v] if isinstance(v, tuple) else v


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


def design_cost(spec: HostSpec, shape: EnvShape) -> ObservationCost:
    """The ``[cost]`` table's quadratic on the observed entries and the actions (what the
    controller is designed for); ValueError when ``Q`` or ``R`` does not fit."""
    Q, R = _listed(spec.Q), _listed(spec.R)
    sizes = (("Q", Q, shape.n_obs, "observed entries"), ("R", R, shape.m, "actions"))
    for name, value, size, what in sizes:
        M = np.asarray(value, dtype=np.float64)
        if M.ndim >= 1 and M.shape[0] != size:
            raise ValueError(
                f"[cost] {name} must be {size}x{size} or {size} diagonal entries "
                f"({spec.system} has {size} {what}), got shape {M.shape}"
            )
    return checked("cost", observation_cost, np.asarray(shape.target), Q, R,
                   np.asarray(shape.a_op))  # fmt: skip


def nominal_model(spec: HostSpec, shape: EnvShape) -> LinearOffsetModel:
    """The ``[model]`` table's nominal ``A``, ``B`` in the system's coordinates (what every
    seed's learned offsets add to)."""
    return checked("model", gym_nominal_model, shape, _listed(spec.A), _listed(spec.B),
                   time_varying=spec.time_varying)  # fmt: skip


class CompiledAgent(NamedTuple):
    """An observed system's agent, its compiled host loop program
    (:func:`loopid.algorithms.gym_loop.make_host_program`) and what flies its policy's episodes
    (``controller(learner_states, K) -> policy``; None: the gains). Under planner kind
    ``mpc``: ``mpc(params) -> policy``, the MPC of the models ``params`` (a leading seed axis),
    and ``model``, the model class whose saved arrays it re-plans on (``loopid evaluate``)."""

    agent: Any
    program: Any
    controller: Any = None
    mpc: Any = None
    model: Any = None


@lru_cache(maxsize=4)
def compiled_agent(spec: HostSpec, shape: EnvShape) -> CompiledAgent:
    """The :class:`CompiledAgent` of ``spec`` on a system of ``shape`` (kept: every method of a
    run shares it)."""
    cost = design_cost(spec, shape)
    model = nominal_model(spec, shape)
    if agents.is_paper_agent(spec.agent):
        Q, R = cost.augmented()  # sized to the system by design_cost
        agent = agents.make_agent(spec.agent, model, Q, R, shape.horizon)
        return CompiledAgent(agent, make_host_program(agent, samples=spec.samples))
    return _planning_agent(spec, shape, cost, model)


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


def _planning_agent(spec: HostSpec, shape: EnvShape, cost, nominal) -> CompiledAgent:
    """A model class of :mod:`loopid.algorithms.planning_agent` planned by iLQR (or MPC) on the
    cost's Q, R, with the action box kept by :func:`loopid.control.action_penalty`."""
    from loopid.control import MPCController, Penalized, quadratic_cost

    planner = spec.agent.planner
    start = _start(_listed(spec.start), shape)
    Q, R = cost.augmented()
    if spec.cost is None:
        plan_cost = quadratic_cost(Q, R, u_limit=shape.u_limit)
    elif shape.u_limit is None:
        plan_cost = import_callable(spec.cost, "planner.cost")
    else:
        plan_cost = Penalized(import_callable(spec.cost, "planner.cost"), shape.u_limit)
    alternatives = None
    if planner.alternatives is not None:
        alternatives = np.asarray(planner.alternatives, np.float64)
        if alternatives.shape[1] != shape.m:
            raise ValueError(
                f"[planner] alternatives must be action vectors of {shape.m} entries, "
                f"got {_listed(planner.alternatives)!r}"
            )
    mc = checked("model", agents.model_class, spec.agent.model, spec.agent.learner, nominal)
    U0 = np.full((shape.horizon, shape.m), 0.1 * (shape.u_limit or 1.0))
    agent = agents.make_agent(
        spec.agent, nominal, Q, R, shape.horizon, start=start, U0=U0, plan_cost=plan_cost,
        model=mc,
    )  # fmt: skip
    program = make_host_program(agent, samples=spec.samples)
    if planner.kind != "mpc":
        return CompiledAgent(agent, program)

    def mpc(params):
        return MPCController(
            mc.dynamics, plan_cost, params, U0[0], horizon=planner.horizon or shape.horizon,
            target=shape.target, observe=shape.observe, a_op=shape.a_op,
            every=planner.every, iterations=planner.iterations, alternatives=alternatives,
            stacked=True,
        )  # fmt: skip

    def controller(states, K):
        return mpc(jax.vmap(mc.params)(states))

    return CompiledAgent(agent, program, controller, mpc, mc)
