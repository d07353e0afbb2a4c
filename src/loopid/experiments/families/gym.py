"""The Gymnasium family: any Gymnasium env with Box spaces as the real system, from a TOML file.

``loopid run gym --config FILE`` (``examples/pendulum.toml`` is a complete file). The file has
five tables; each key is a field of :class:`GymScenario` (the field's name in brackets where it
differs)::

    [env]          id [env_id] (required), kwargs [env_kwargs], reset_options, observe,
                   horizon, num_envs, stop_norm, vectorization ("sync" | "async")
    [cost]         target, Q, R (required; Q, R full matrices, diagonals or scalars over the
                   observed entries and the actions), action_op, test [test_cost]
                   ("quadratic" | "reward" | "module:function"), termination, cap [cost_cap]
    [exploration]  ν: exactly one of gain (K [m, n_obs] or [m, n_obs + 1], a = a_op − K Δx),
                   policy ("module:function", obs -> action), nominal (open-loop actions
                   [T, m]); action_std (Gaussian action noise)
    [model]        A, B (nominal, default A = I, B = 0), time_varying, lambda [ftrl_lambda],
                   kind, features, degree, count, bandwidth, seed, hidden, layers,
                   learning_rate, steps, buffer [model_*]
    [planner]      kind, horizon, iterations, every, alternatives, start, cost [planner_*]
                   (start: the observation an iLQR plan starts from, default the target;
                   cost: "module:function", the planner's cost(Δx, Δu, t) in JAX, default the
                   [cost] table's quadratic; either way the action box is kept by a penalty)
    [run]          methods (dagger | batch | abbeel), iterations, samples, seeds (a count or a
                   list), test_trajectories, dagger_fraction

The common options (``--seeds``, ``--iterations``, ``--samples``, ``--test-trajectories``,
``--methods``) and ``--set FIELD=VALUE`` override the file, as for every family. Every problem
(unknown or missing key, wrong size, Discrete space, unknown env id) raises ``ValueError`` with
one line naming the value, before anything is written (:func:`check` builds the env once).

Methods: ``dagger`` (p_n = ``dagger_fraction``), ``batch`` (p_n = 0), ``abbeel`` (ν's data at
n = 2, then the policy's), run by :func:`loopid.algorithms.gym_loop.run_learning_host`. Figure:
mean test cost against samples, ± one standard error, per method; report: the final costs.
"""

import importlib
from dataclasses import dataclass, fields
from functools import lru_cache
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import pyarrow as pa

from loopid.algorithms.gym_loop import (
    EVALUATE,
    Exploration,
    gym_nominal_model,
    make_host_cell,
    run_learning_host,
    test_episodes,
)
from loopid.algorithms.loop import Trace
from loopid.algorithms.methods import policy_fractions
from loopid.experiments import model_planner
from loopid.experiments.config import (
    Table,
    check_choice,
    check_int,
    check_number,
    freeze,
    read_toml,
    replaced,
    seed_list,
    thaw,
)
from loopid.experiments.families.base import Family, Progress
from loopid.experiments.report import final_cost_sections
from loopid.models.linear_offset import LinearOffsetModel
from loopid.systems.from_gymnasium import (
    CallablePolicy,
    GymSystem,
    OpenLoopPolicy,
    observation_cost,
)

METHODS = ("dagger", "batch", "abbeel")
#: The helicopter method whose p_n schedule each gym method follows.
_FRACTIONS = {"dagger": "dagger-t", "batch": "batch-t", "abbeel": "abbeel"}
_TABLE_FIELDS = ("env_kwargs", "reset_options")
_NO_TABLE = Table()


@dataclass(frozen=True)
class GymScenario(model_planner.ModelPlanner):
    """One Gymnasium experiment (module docstring for the file format; frozen and hashable:
    lists are kept as tuples and tables as tuples of pairs, :meth:`to_dict` gives them back).

    Attributes:
      name: the scenario name (``gym``).
      env_id: the Gymnasium id; env_kwargs: ``gymnasium.make`` keywords; reset_options: the
        ``options`` of every reset; observe: the observation entries the model sees (default
        all); horizon: steps per episode (default the env's limit); num_envs, vectorization:
        the vector env; stop_norm: training episodes restart when ``‖[Δx; Δu]‖ > stop_norm``.
      target, Q, R, action_op: the quadratic cost the controller is designed for (on the
        observed entries and ``a − action_op``); test_cost: the test cost (``quadratic``,
        ``reward``: the env's own, negated, or ``module:function``); termination: added when an
        episode ends by ``terminated``; cost_cap: a test episode's cost cap.
      gain, policy, nominal, action_std: ν (exactly one of the first three) and its noise.
      A, B, time_varying, ftrl_lambda: the nominal model and the FTRL regulariser.
      model_*, planner_*: the model class and the optimal-control solver
        (:mod:`loopid.experiments.model_planner`; default a linear model and LQR).
      iterations, samples, seeds, test_trajectories, dagger_fraction: the protocol (``seeds``: a
        count or a tuple of seeds).
    """

    env_id: str
    target: Any
    Q: Any
    R: Any
    name: str = "gym"
    env_kwargs: Any = _NO_TABLE
    reset_options: Any = _NO_TABLE
    observe: Any = None
    horizon: int | None = None
    num_envs: int = 8
    stop_norm: float | None = None
    vectorization: str = "sync"
    action_op: Any = None
    test_cost: str = "quadratic"
    termination: float = 0.0
    cost_cap: float = 1e8
    gain: Any = None
    policy: str | None = None
    nominal: Any = None
    action_std: float = 0.0
    A: Any = None
    B: Any = None
    time_varying: bool = False
    ftrl_lambda: float = 1e-3
    iterations: int = 10
    samples: int = 200
    seeds: Any = 5
    test_trajectories: int = 10
    dagger_fraction: float = 0.5
    planner_start: Any = None
    planner_cost: str | None = None

    def __post_init__(self) -> None:
        for f in fields(self):  # TOML lists and tables, kept hashable
            v = getattr(self, f.name)
            if isinstance(v, list | dict | tuple):
                object.__setattr__(self, f.name, freeze(v))
        validate(self)

    def replace(self, **changes) -> "GymScenario":
        """A copy with ``changes``; unknown fields and bad values raise ``ValueError``."""
        return replaced(self, changes, "gym scenario")

    def to_dict(self) -> dict:
        """The fields as plain TOML values (lists, tables), ``None`` left out; the model and
        planner fields only when one differs from the default linear model and LQR (so such a
        run records the same ``config.toml`` as before they existed)."""
        skip = set(model_planner.FIELDS) if model_planner.is_default(self) else set()
        out = {}
        names = [f.name for f in fields(self) if f.name not in model_planner.FIELDS]
        for k, v in ((k, getattr(self, k)) for k in (*names, *model_planner.FIELDS)):
            if v is None or (k in _TABLE_FIELDS and not v) or k in skip:
                continue
            out[k] = thaw(v)
        return out


FIELDS = tuple(f.name for f in fields(GymScenario))


def validate(s: GymScenario) -> None:
    """Raise ``ValueError`` naming the first bad field (checks that need no env)."""
    if not isinstance(s.env_id, str) or not s.env_id:
        raise ValueError(f"env_id must be a Gymnasium id, got {s.env_id!r}")
    for name in _TABLE_FIELDS:
        v = getattr(s, name)
        if not (isinstance(v, Table) or v == ()):
            raise ValueError(f"{name} must be a table, got {thaw(v)!r}")
    check_int("num_envs", s.num_envs)
    if s.horizon is not None:
        check_int("horizon", s.horizon)
    if s.stop_norm is not None:
        check_number("stop_norm", s.stop_norm, 0.0, open_low=True)
    check_choice("vectorization", s.vectorization, ("sync", "async"))
    if s.test_cost not in ("quadratic", "reward") and ":" not in str(s.test_cost):
        raise ValueError(
            f"test_cost must be 'quadratic', 'reward' or 'module:function', got {s.test_cost!r}"
        )
    check_number("termination", s.termination, -np.inf)
    check_number("cost_cap", s.cost_cap, 0.0, open_low=True)
    kinds = [k for k in ("gain", "policy", "nominal") if getattr(s, k) is not None]
    if len(kinds) != 1:
        raise ValueError(f"exploration needs exactly one of gain, policy, nominal, got {kinds}")
    check_number("action_std", s.action_std, 0.0)
    if not isinstance(s.time_varying, bool):
        raise ValueError(f"time_varying must be true or false, got {s.time_varying!r}")
    check_number("ftrl_lambda", s.ftrl_lambda, 0.0)
    for name in ("iterations", "samples", "test_trajectories"):
        check_int(name, getattr(s, name))
    seeds = s.seeds
    if isinstance(seeds, tuple):
        if not seeds or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 0
                                for x in seeds):  # fmt: skip
            raise ValueError(f"seeds must be a count or a list of integers >= 0, got {seeds!r}")
    else:
        check_int("seeds", seeds)
    check_number("dagger_fraction", s.dagger_fraction, 0.0, 1.0)
    model_planner.validate(s, s.horizon)
    if s.time_varying and s.model_kind != "linear":
        raise ValueError(
            f"time_varying applies to the linear model; model_kind {s.model_kind!r} learns one "
            "model for every step"
        )


#: TOML table -> {key: field} (the file format of the module docstring).
TABLES = {
    "env": {
        "id": "env_id", "kwargs": "env_kwargs", "reset_options": "reset_options",
        "observe": "observe", "horizon": "horizon", "num_envs": "num_envs",
        "stop_norm": "stop_norm", "vectorization": "vectorization",
    },
    "cost": {
        "target": "target", "Q": "Q", "R": "R", "action_op": "action_op", "test": "test_cost",
        "termination": "termination", "cap": "cost_cap",
    },
    "exploration": {
        "gain": "gain", "policy": "policy", "nominal": "nominal", "action_std": "action_std",
    },
    "model": {
        "A": "A", "B": "B", "time_varying": "time_varying", "lambda": "ftrl_lambda",
        **{k: f"model_{k}" for k in model_planner.TABLES["model"]},
    },
    "planner": {k: f"planner_{k}" for k in (*model_planner.TABLES["planner"], "start", "cost")},
    "run": {
        "methods": None, "iterations": "iterations", "samples": "samples", "seeds": "seeds",
        "test_trajectories": "test_trajectories", "dagger_fraction": "dagger_fraction",
    },
}  # fmt: skip
_REQUIRED = {"env": ("id",), "cost": ("target", "Q", "R"), "exploration": ()}


def read_file(path) -> tuple[dict, list[str] | None]:
    """A gym TOML file as ``(fields, methods or None)``; one-line ``ValueError`` naming an
    unknown or missing table or key (values are checked when the scenario is built)."""
    raw = read_toml(path)
    where = f"--config {str(path)!r}"
    out: dict = {}
    methods = None
    for table, given in raw.items():
        if table not in TABLES:
            raise ValueError(f"{where}: unknown table [{table}]; allowed: {', '.join(TABLES)}")
        if not isinstance(given, dict):
            raise ValueError(f"{where}: {table} must be a table, got {given!r}")
        for key, value in given.items():
            if key not in TABLES[table]:
                raise ValueError(
                    f"{where}: unknown key {table}.{key}; allowed: {', '.join(TABLES[table])}"
                )
            if TABLES[table][key] is None:
                methods = value
            else:
                out[TABLES[table][key]] = value
    for table, keys in _REQUIRED.items():
        if table not in raw:
            raise ValueError(f"{where}: missing table [{table}]")
        for key in keys:
            if key not in raw[table]:
                raise ValueError(f"{where}: missing key {table}.{key}")
    if methods is not None and (
        not isinstance(methods, list) or not methods or not all(isinstance(m, str) for m in methods)
    ):
        raise ValueError(f"{where}: run.methods must be a non-empty list, got {methods!r}")
    return out, methods


def build(name: str, changes: dict) -> GymScenario:
    """A :class:`GymScenario` from a file's fields (and the command line's changes)."""
    missing = [k for k in ("env_id", "target", "Q", "R") if k not in changes]
    if missing:
        raise ValueError(
            f"loopid run {name} needs --config FILE with [env] id and [cost] target, Q, R "
            "(see examples/pendulum.toml)"
        )
    unknown = sorted(set(changes) - set(FIELDS))
    if unknown:
        raise ValueError(f"unknown gym scenario field(s): {', '.join(unknown)}")
    return GymScenario(**{"name": name, **changes})


# ----------------------------------------------------------------------------- the system
def _import(name: str, what: str):
    mod, _, attr = name.partition(":")
    try:
        obj = getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError, ValueError):
        raise ValueError(f"{what} = {name!r} is not an importable 'module:function'") from None
    if not callable(obj):
        raise ValueError(f"{what} = {name!r} is not callable")
    return obj


def _checked(what: str, f, *args, **kwargs):
    """Call ``f``; prefix a ValueError's one line with the field it concerns."""
    try:
        return f(*args, **kwargs)
    except ValueError as err:
        raise ValueError(f"[{what}] {str(err).splitlines()[0]}") from None


def make_system(s: GymScenario) -> GymSystem:
    """The scenario's env as a :class:`loopid.systems.from_gymnasium.GymSystem` (close it)."""
    return GymSystem(
        s.env_id, target=thaw(s.target), env_kwargs=thaw(s.env_kwargs),
        observe=thaw(s.observe), a_op=thaw(s.action_op), horizon=s.horizon,
        num_envs=s.num_envs, reset_options=thaw(s.reset_options),
        vectorization=s.vectorization, stop_norm=s.stop_norm,
    )  # fmt: skip


class Shape(NamedTuple):
    """What the compiled learner depends on besides the scenario: the system's sizes and
    coordinates (hashable); ``u_limit``: the largest |Δu| every action entry may take inside the
    action box (a planner keeps its plan inside it)."""

    n: int
    n_obs: int
    m: int
    horizon: int
    target: tuple
    a_op: tuple
    observe: tuple | None = None
    u_limit: float | None = None


def _shape(system: GymSystem) -> Shape:
    room = np.minimum(system.high - system.a_op, system.a_op - system.low)
    u_limit = float(room.min()) if np.all(np.isfinite(room)) and room.min() > 0 else None
    observe = None if system.observe is None else tuple(int(i) for i in system.observe)
    return Shape(system.n, system.n_obs, system.m, system.horizon,
                 tuple(np.asarray(system.target).tolist()),
                 tuple(np.asarray(system.a_op).tolist()), observe, u_limit)  # fmt: skip


def _cost(s: GymScenario, shape: Shape):
    sizes = (("Q", shape.n_obs, "observed entries"), ("R", shape.m, "actions"))
    for name, size, what in sizes:
        M = np.asarray(thaw(getattr(s, name)), dtype=np.float64)
        if M.ndim >= 1 and M.shape[0] != size:
            raise ValueError(
                f"[cost] {name} must be {size}x{size} or {size} diagonal entries "
                f"({s.env_id} has {size} {what}), got shape {M.shape}"
            )
    return _checked("cost", observation_cost, np.asarray(shape.target), thaw(s.Q), thaw(s.R),
                    np.asarray(shape.a_op))  # fmt: skip


class Learner(NamedTuple):
    """A scenario's agent, its compiled host cell and what flies its policy's episodes
    (``controller(learner_states, K) -> policy``; None: the gains). Under ``[planner] kind =
    "mpc"``: ``mpc(params) -> policy``, the MPC of the models ``params`` (a leading seed axis),
    and ``model``, the model class whose saved arrays it re-plans on (``loopid evaluate``)."""

    agent: Any
    cell: Any
    controller: Any = None
    mpc: Any = None
    model: Any = None


@lru_cache(maxsize=4)
def _learner(s: GymScenario, shape: Shape) -> Learner:
    """The agent and its compiled host cell (kept: every method of a run shares them)."""
    cost = _cost(s, shape)
    model = _checked("model", gym_nominal_model, shape, thaw(s.A), thaw(s.B),
                     time_varying=s.time_varying)  # fmt: skip
    if model_planner.is_paper_agent(s):
        Q, R = cost.augmented()  # sized to the system by _cost
        agent = model_planner.make_agent(s, model, Q, R, shape.horizon)
        return Learner(agent, make_host_cell(agent, samples=s.samples))
    return _planning_learner(s, shape, cost, model)


def _start(s: GymScenario, shape: Shape) -> np.ndarray:
    """Δx of ``planner_start`` (default the target): where an iLQR plan starts."""
    target = np.asarray(shape.target)
    if s.planner_start is None:
        return np.concatenate([np.zeros(shape.n_obs), [1.0]])
    o = np.asarray(thaw(s.planner_start), np.float64)
    if o.shape != (shape.n_obs,) or not np.all(np.isfinite(o)):
        raise ValueError(
            f"[planner] start must be {shape.n_obs} finite numbers (the observed entries), "
            f"got {thaw(s.planner_start)!r}"
        )
    return np.concatenate([o - target, [1.0]])


def _planning_learner(s: GymScenario, shape: Shape, cost, nominal) -> Learner:
    """A model class of :mod:`loopid.algorithms.planning_agent` planned by iLQR (or MPC) on the
    cost's Q, R, with the action box kept by :func:`loopid.control.action_penalty`."""
    from loopid.control import MPCController, Penalized, quadratic_cost

    Q, R = cost.augmented()
    if s.planner_cost is None:
        plan_cost = quadratic_cost(Q, R, u_limit=shape.u_limit)
    elif shape.u_limit is None:
        plan_cost = _import(s.planner_cost, "planner.cost")
    else:
        plan_cost = Penalized(_import(s.planner_cost, "planner.cost"), shape.u_limit)
    alternatives = None
    if s.planner_alternatives is not None:
        alternatives = np.asarray(thaw(s.planner_alternatives), np.float64)
        if alternatives.shape[1] != shape.m:
            raise ValueError(
                f"[planner] alternatives must be action vectors of {shape.m} entries, "
                f"got {thaw(s.planner_alternatives)!r}"
            )
    mc = _checked("model", model_planner.model_class, s, nominal)
    U0 = np.full((shape.horizon, shape.m), 0.1 * (shape.u_limit or 1.0))
    agent = model_planner.make_agent(
        s, nominal, Q, R, shape.horizon, start=_start(s, shape), U0=U0, plan_cost=plan_cost,
        alternatives=alternatives, model=mc,
    )  # fmt: skip
    cell = make_host_cell(agent, samples=s.samples)
    if s.planner_kind != "mpc":
        return Learner(agent, cell)

    def mpc(params):
        return MPCController(
            mc.dynamics, plan_cost, params, U0[0], horizon=s.planner_horizon or shape.horizon,
            target=shape.target, observe=shape.observe, a_op=shape.a_op,
            every=s.planner_every, iterations=s.planner_iterations, alternatives=alternatives,
            stacked=True,
        )  # fmt: skip

    def controller(states, K):
        return mpc(jax.vmap(mc.params)(states))

    return Learner(agent, cell, controller, mpc, mc)


def _exploration(s: GymScenario, system: GymSystem) -> Exploration:
    if s.gain is not None:
        policy = _checked("exploration.gain", system.linear_policy, thaw(s.gain))
    elif s.policy is not None:
        policy = CallablePolicy(_import(s.policy, "exploration.policy"), system.m)
    else:
        U = np.asarray(thaw(s.nominal), dtype=np.float64)
        if U.ndim != 2 or U.shape[1] != system.m or U.shape[0] < 1:
            raise ValueError(f"[exploration] nominal must be [T, {system.m}], got shape {U.shape}")
        policy = OpenLoopPolicy(U)
    return Exploration(policy, float(s.action_std))


def _test_cost(s: GymScenario, shape: Shape):
    if s.test_cost == "quadratic":
        return _cost(s, shape)
    if s.test_cost == "reward":
        return "reward"
    return _import(s.test_cost, "cost.test")


def _parts(s: GymScenario, system: GymSystem):
    try:
        shape = _shape(system)
        return _learner(s, shape), _exploration(s, system), _test_cost(s, shape)
    except (ValueError, TypeError) as err:
        raise ValueError(str(err).splitlines()[0]) from None


def check(s: GymScenario) -> None:
    """Build the env and every part once, so that a size that does not fit the env is refused
    before anything is written."""
    system = make_system(s)
    try:
        _parts(s, system)
    finally:
        system.close()


def run(method: str, s: GymScenario, seeds=None, progress: Progress | None = None) -> Trace:
    """Run ``method`` (:data:`METHODS`) on every seed (default :func:`seed_list`)."""
    if method not in METHODS:
        raise ValueError(f"unknown gym method {method!r}; choose from {', '.join(METHODS)}")
    seeds = seed_list(s) if seeds is None else np.asarray(seeds)
    system = make_system(s)
    try:
        learner, nu, test_cost = _parts(s, system)
        fractions = policy_fractions(
            _FRACTIONS[method], s.iterations, dagger_fraction=s.dagger_fraction
        )
        return run_learning_host(
            system, learner.agent, nu, fractions, [int(x) for x in seeds], samples=s.samples,
            n_test=s.test_trajectories, cost=test_cost, termination_cost=s.termination,
            cost_cap=s.cost_cap, progress=progress, cell=learner.cell,
            controller=learner.controller,
        )  # fmt: skip
    finally:
        system.close()


def figure(table: pa.Table, path, configs) -> None:
    """Mean test cost (± one standard error over seeds) against samples, one line per method,
    log cost axis; written to ``path``."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from loopid.experiments.results import write_atomic_bytes

    title = ", ".join(f"{s.env_id}: test cost" for s in configs.values())
    df = {name: np.asarray(table.column(name).to_pylist()) for name in table.column_names}
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, method in enumerate(dict.fromkeys(df["method"].tolist())):
        sel = df["method"] == method
        samples = np.unique(df["samples"][sel])
        costs = [df["test_cost"][sel & (df["samples"] == x)] for x in samples]
        mean = np.array([c.mean() for c in costs])
        se = np.array([c.std(ddof=1) / np.sqrt(c.size) if c.size > 1 else 0.0 for c in costs])
        style = ("-", "--", ":")[k % 3]  # dashes keep coinciding curves visible
        ax.plot(samples, mean, style, marker="o", ms=3, label=method)
        ax.fill_between(samples, np.maximum(mean - se, 1e-12), mean + se, alpha=0.25)
    ax.set_yscale("log")
    ax.set_xlabel("samples collected")
    ax.set_ylabel("mean test cost")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    write_atomic_bytes(buf.getvalue(), path)


def report(table: pa.Table, configs) -> list[str]:
    """The final costs per method, under the env's id."""
    notes = {
        name: f"Env: `{s.env_id}`, horizon {s.horizon or 'the env limit'}, test cost "
        f"{s.test_cost}. {model_planner.describe(s)}"
        for name, s in configs.items()
    }
    return final_cost_sections(table, notes)


def load(s: GymScenario, method: str, arrays: dict):
    """One seed's saved model and controller in the env's coordinates: ``a = a_op − K_t [o[observe]
    − o*; 1]`` (the env is made once to read its sizes and operating action, then closed)."""
    from loopid.experiments.learned import FeatureModel, GainController, LinearModel

    system = make_system(s)
    try:
        shape = _shape(system)
        observe = system.observe
    finally:
        system.close()
    target = np.asarray(shape.target)

    def error(obs, t):
        o = obs if observe is None else obs[np.asarray(observe)]
        return np.concatenate([o - target, [1.0]])

    model = None  # the MLP's network is saved (mlp.*) but not rebuilt here
    if "W" in arrays or "W_features" in arrays:  # the nominal the cell kept (shared.A, .B)
        nominal = LinearOffsetModel(np.asarray(arrays["shared.A"]), np.asarray(arrays["shared.B"]))
        if "W" in arrays:
            model = LinearModel(nominal, arrays["W"])
        else:
            fmap = model_planner.feature_map(s, nominal.n, nominal.m)
            model = FeatureModel(nominal, fmap, arrays["W_features"])
    return model, GainController(arrays["K"], error, np.asarray(shape.a_op))


def _saved_policy(learner: Learner, system: GymSystem, arrays: dict):
    """What the seeds' saved arrays ``{name: [S, ...]}`` fly: MPC re-planning on each seed's
    saved model where the cell flew MPC (``[planner] kind = "mpc"`` and a learned model
    saved), else the gains ``K``."""
    from loopid.algorithms.planning_agent import holds_model, restore_seeds

    if learner.mpc is None or not holds_model(arrays):
        return system.linear_policy(np.asarray(arrays["K"]))
    return learner.mpc(restore_seeds(learner.model, arrays))


def evaluate(s: GymScenario, arrays: dict, seeds, episodes: int, env=None) -> np.ndarray:
    """Capped test costs ``[S, episodes]`` of the saved policies ``arrays["K"] [S, T, m, n]``
    on fresh episodes (slot stream 4); ``env``: fly them on another Gymnasium id (transfer)
    with the same observation indices, target and costs. A cell that flew MPC (``[planner]
    kind = "mpc"``, a learned model saved) flies MPC again, re-planning on each seed's saved
    model."""
    if env is not None:
        s = s.replace(env_id=env)
    system = make_system(s)
    try:
        learner, _, test_cost = _parts(s, system)
        policy = _saved_policy(learner, system, arrays)
        costs, _ = test_episodes(system, policy, [int(x) for x in seeds], episodes,
                                 test_cost, s.termination, s.cost_cap, stream=EVALUATE)  # fmt: skip
    finally:
        system.close()
    return costs


def trajectories(run_dir, configs, path) -> None:
    """``trajectories.png``: each method's saved final policy at the first seed flying that
    seed's first test episode (MPC where the cell flew MPC, :func:`_saved_policy`); one panel
    per observed coordinate (``o − o*`` against steps)."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from loopid.algorithms.gym_loop import slot_seeds
    from loopid.algorithms.keys import HOST_TEST
    from loopid.experiments import artifacts
    from loopid.experiments.results import write_atomic_bytes
    from loopid.systems.from_gymnasium import Slot

    for name, s in configs.items():
        cells = Path(run_dir) / "cells"
        methods = [m for m in METHODS if (cells / f"{name}__{m}.json").is_file()]
        if not methods:
            continue
        system = make_system(s)
        try:
            learner = _parts(s, system)[0]
            flights = {}
            for m in methods:
                _, arrays = artifacts.read(cells, name, m)
                seed = int(arrays["seeds"][0])
                slot = Slot(0, 0, slot_seeds(seed, 0, HOST_TEST, 1)[0], 0.0, False)
                first = {k: v if k.startswith("shared.") else v[:1] for k, v in arrays.items()}
                r = system.rollouts([_saved_policy(learner, system, first)], [slot])
                steps = int(r.mask[0].sum())
                flights[m] = system.observed(r.x[0, :steps]) - np.asarray(_shape(system).target)
            n_obs = system.n_obs
        finally:
            system.close()
        fig, axes = plt.subplots(n_obs, 1, figsize=(7, 2.2 * n_obs), squeeze=False,
                                 layout="constrained")  # fmt: skip
        for i, ax in enumerate(axes[:, 0]):
            for k, (m, o) in enumerate(flights.items()):
                ax.plot(o[:, i], color=f"C{k}", lw=1.0, label=m)
            ax.axhline(0.0, color="k", ls="--", lw=0.8)
            ax.set(ylabel=f"observed {i}: o − o*")
        axes[0, 0].set_title(f"{s.env_id}: seed {seed}'s first test episode")
        axes[-1, 0].set_xlabel("step")
        axes[0, 0].legend(fontsize=8)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        write_atomic_bytes(buf.getvalue(), path)
        return  # one gym scenario per run


def animate(run_dir, s: GymScenario, methods, seed: int, path, every: int = 2) -> None:
    """An animated GIF of the env's own ``rgb_array`` frames: each method's saved final policy
    at ``seed`` flying one episode (reset with ``seed`` and the scenario's reset options), the
    methods side by side."""
    import gymnasium
    from PIL import Image

    from loopid.experiments import artifacts

    policies = []
    for m in methods:
        _, arrays = artifacts.read(Path(run_dir) / "cells", s.name, m)
        one = artifacts.for_seed(arrays, seed, f"{s.name}/{m}")
        policies.append(load(s, m, one)[1])
    films = []
    for controller in policies:
        env = None
        try:  # any failure of the env's own renderer (a missing pygame, say) is one line
            env = gymnasium.make(s.env_id, render_mode="rgb_array", **thaw(s.env_kwargs))
            policy = controller.as_gymnasium_policy(env.action_space)
            obs, _ = env.reset(seed=int(seed), options=thaw(s.reset_options) or None)
            policy.reset()
            frames = [env.render()]
            for _ in range(s.horizon or env.spec.max_episode_steps or 200):
                obs, _, terminated, truncated, _ = env.step(policy(obs))
                frames.append(env.render())
                if terminated or truncated:
                    break
        except (gymnasium.error.Error, ImportError, TypeError) as e:
            what = " ".join(str(e).split())
            raise ValueError(f"{s.env_id} cannot render rgb_array frames ({what})") from None
        finally:
            if env is not None:
                env.close()
        if frames[0] is None:
            raise ValueError(f"{s.env_id} renders no rgb_array frames")
        films.append(frames)
    T = max(len(f) for f in films)
    images = [
        Image.fromarray(np.concatenate([f[min(t, len(f) - 1)] for f in films], axis=1))
        for t in range(0, T, every)
    ]
    tmp = Path(path).with_name(f".{Path(path).name}.tmp.gif")
    images[0].save(tmp, save_all=True, append_images=images[1:], duration=40 * every, loop=0)
    tmp.replace(path)


def shared(s: GymScenario, method: str) -> dict:
    """The nominal model ``A``, ``B`` every seed's learned offsets add to."""
    system = make_system(s)
    try:
        shape = _shape(system)
    finally:
        system.close()
    nominal = _checked("model", gym_nominal_model, shape, thaw(s.A), thaw(s.B),
                       time_varying=s.time_varying)  # fmt: skip
    return {"A": np.asarray(nominal.A), "B": np.asarray(nominal.B)}


FAMILY = Family(
    name="gym",
    config=GymScenario,
    methods=METHODS,
    scenarios={},
    default_methods=lambda s: ("dagger", "batch"),
    build=build,
    read_file=read_file,
    run=run,
    figure=figure,
    report=report,
    check=check,
    shared=shared,
    load=load,
    evaluate=evaluate,
    trajectories=trajectories,
    animate=animate,
)
