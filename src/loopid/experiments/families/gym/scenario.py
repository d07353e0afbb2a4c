"""A Gymnasium experiment's settings: :class:`GymScenario` and its TOML file format.

``loopid run gym --config FILE`` reads a file of five tables (``examples/pendulum.toml`` is a
complete one); each key is a field of :class:`GymScenario` (the field's name in brackets where
it differs)::

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
                   list), test_trajectories, dagger_fraction, test_policy ("last" | "best")

A scenario is frozen and hashable (lists kept as tuples, tables as :class:`Table` s), and so
are the settings its agent is built from (:attr:`GymScenario.spec`), on which the compiled agent
is cached; :attr:`GymScenario.plain` gives every field back as a plain TOML value (what the env,
the test cost and ν are built from), computed once per scenario.
Checks that need no env are made when a scenario is built (:func:`validate`); those that need
its sizes, when its :class:`~loopid.experiments.families.gym.setup.Setup` is built.
"""

from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any

import numpy as np

from loopid.algorithms.host_agent import HostSpec
from loopid.algorithms.schedules import SCHEDULES
from loopid.settings import model_planner, observed
from loopid.settings.checks import check_choice, check_int, check_number, replaced
from loopid.settings.toml import Table, freeze, read_tables, thaw

#: Each method follows the schedule of its name (:mod:`loopid.algorithms.schedules`).
METHODS = SCHEDULES
_TABLE_FIELDS = ("env_kwargs", "reset_options")
_NO_TABLE = Table()


@dataclass(frozen=True)
class GymScenario(model_planner.ModelPlanner):
    """One Gymnasium experiment (module docstring for the file format; frozen and hashable:
    lists are kept as tuples and tables as tuples of pairs, :meth:`GymScenario.to_dict` gives
    them back).

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
        (:mod:`loopid.settings.model_planner`; default a linear model and LQR).
      test_policy: the policy tested at each iteration: ``last`` (the paper's) or ``best``, the
        best so far, selected on episodes of its own
        (:func:`loopid.algorithms.gym_loop.run_learning_host`; gains only, not under ``mpc``).
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
    test_policy: str = "last"
    planner_start: Any = None
    planner_cost: str | None = None

    def __post_init__(self) -> None:
        for f in fields(self):  # TOML lists and tables, kept hashable
            v = getattr(self, f.name)
            if isinstance(v, list | dict | tuple):
                object.__setattr__(self, f.name, freeze(v))
        validate(self)

    @cached_property
    def plain(self) -> dict[str, Any]:
        """Every field as a plain TOML value (tuples back to lists, tables to dicts, ``None``
        kept): what the env, the test cost and ν are built from. Computed once per
        scenario, in one call of :func:`~loopid.settings.toml.thaw`; read it, do not
        change it (it is not part of the scenario's value: equality and hashing ignore it)."""
        return thaw(Table((f.name, getattr(self, f.name)) for f in fields(self)))

    @cached_property
    def spec(self) -> HostSpec:
        """The settings its agent is built from (:func:`loopid.settings.observed.host_spec`;
        computed once per scenario and, like :attr:`plain`, not part of its value)."""
        return observed.host_spec(self, self.env_id)

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
    check_choice("test_policy", s.test_policy, ("last", "best"))
    if s.planner_kind == "mpc" and s.test_policy != "last":
        raise ValueError(
            f"planner_kind 'mpc' flies the last policy only, got test_policy {s.test_policy!r}"
        )
    observed.check_model(s, s.horizon)


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
    **observed.TABLES,
    "run": {
        "methods": None, "iterations": "iterations", "samples": "samples", "seeds": "seeds",
        "test_trajectories": "test_trajectories", "dagger_fraction": "dagger_fraction",
        "test_policy": "test_policy",
    },
}  # fmt: skip
_REQUIRED = {"env": ("id",), "cost": ("target", "Q", "R"), "exploration": ()}


def read_file(path) -> tuple[dict, list[str] | None]:
    """A gym TOML file as ``(fields, methods or None)``; one-line ``ValueError`` naming an
    unknown or missing table or key (values are checked when the scenario is built;
    :func:`loopid.settings.toml.read_tables` with :data:`TABLES`)."""
    return read_tables(path, TABLES, _REQUIRED)


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
