"""A round directory's settings: :class:`RoundsConfig` and its TOML file format.

``loopid round init DIR --config FILE`` reads a file of five tables. ``[model]`` and
``[planner]`` are those of every observed system (:mod:`loopid.settings.observed`, as in a
Gymnasium scenario's file); ``[system]`` takes the place of a Gymnasium env (there is no env: the
system is run by a person) and ``[rounds]`` of the run's settings::

    [system]   states (names, n_obs of them), actions (names, m), target (o* [n_obs], required),
               action_op (a_op [m], default 0), horizon (steps of one episode, default 100),
               action_limit (the largest |a − a_op| a planner may use; default none),
               A [n_obs, n_obs] or [n_obs + 1, n_obs + 1], B [n_obs, m] or [n_obs + 1, m]
               (the initial model; default A = I, B = 0: "knows nothing")
    [cost]     Q, R (required; full matrices, diagonals or scalars)
    [model]    time_varying, lambda, kind, features, degree, count, bandwidth, seed, hidden,
               layers, learning_rate, steps, buffer
    [planner]  kind, horizon, iterations, every, alternatives, start, cost
    [rounds]   samples (m, transitions per round, default 200), method (dagger | batch |
               abbeel, default dagger), dagger_fraction (default 0.5), scale (std | none,
               default std: each column divided by its first round's standard deviation
               before the fit, loopid.rounds.scale)

The coordinates are an observed system's (:class:`~loopid.algorithms.host_agent.EnvShape`):
``Δx = [o − o*; 1]`` (``n = n_obs + 1``), ``Δu = a − a_op``, and a linear controller acts
``a = a_op − K_t Δx``. A config is frozen and hashable; its agent is the compiled agent of
:func:`loopid.algorithms.host_agent.compiled_agent`, built from :attr:`RoundsConfig.spec`
exactly as a Gymnasium scenario's (the same model class, learner and planner).
"""

from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any

from loopid.algorithms.host_agent import EnvShape, HostSpec
from loopid.algorithms.schedules import SCHEDULES
from loopid.settings import model_planner, observed
from loopid.settings.checks import check_choice, check_int, check_number
from loopid.settings.toml import freeze, read_tables, thaw


@dataclass(frozen=True)
class RoundsConfig(model_planner.ModelPlanner):
    """One system identified round by round (module docstring for the file format).

    Attributes:
      states, actions: the coordinates' names (columns of a round's file).
      target, action_op: the operating point ``o*`` [n_obs] and action ``a_op`` [m].
      horizon: steps of one episode on the system (finite-horizon and time-varying solves).
      action_limit: the largest ``|Δu|`` a planner's plan may use (None: unbounded).
      A, B: the initial model; time_varying, ftrl_lambda: the ``[model]`` table's nominal
        settings (:mod:`loopid.settings.observed`).
      Q, R: the quadratic cost the controller is designed for.
      samples, method, dagger_fraction: transitions per round, and how they are split between
        the policy and ν (a schedule of :mod:`loopid.algorithms.schedules`).
      planner_start, planner_cost: the ``[planner]`` table's ``start`` and ``cost``.
      scale: ``std`` (each state and action column in units of its first round's standard
        deviation while the model is fitted and solved, so the controller does not depend on
        the log's units) or ``none`` (the log's units: the regulariser is absolute).
    """

    states: Any
    actions: Any
    target: Any
    Q: Any
    R: Any
    action_op: Any = None
    horizon: int = 100
    action_limit: float | None = None
    A: Any = None
    B: Any = None
    time_varying: bool = False
    ftrl_lambda: float = 1e-3
    samples: int = 200
    method: str = "dagger"
    dagger_fraction: float = 0.5
    planner_start: Any = None
    planner_cost: str | None = None
    scale: str = "std"

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, list | dict | tuple):
                object.__setattr__(self, f.name, freeze(v))
        if self.action_op is None:
            object.__setattr__(self, "action_op", (0.0,) * _count(self.actions, "actions"))
        validate(self)

    @cached_property
    def spec(self) -> HostSpec:
        """The settings its agent is built from (:func:`loopid.settings.observed.host_spec`,
        the system named ``[system]`` in messages; not part of the config's value)."""
        return observed.host_spec(self, "[system]")

    @property
    def n_obs(self) -> int:
        return len(self.states)

    @property
    def m(self) -> int:
        return len(self.actions)

    @property
    def shape(self) -> EnvShape:
        """The sizes and coordinates the compiled agent is built for."""
        return EnvShape(
            self.n_obs + 1, self.n_obs, self.m, self.horizon,
            tuple(float(v) for v in self.target), tuple(float(v) for v in self.action_op),
            None, self.action_limit,
        )  # fmt: skip


def _count(names, what: str) -> int:
    if not isinstance(names, tuple) or not names or not all(isinstance(s, str) for s in names):
        raise ValueError(f"[system] {what} must be a non-empty list of names, got {thaw(names)!r}")
    return len(names)


def _numbers(name: str, v, size: int) -> None:
    ok = isinstance(v, tuple) and len(v) == size
    ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
    if not ok or not all(abs(x) < float("inf") for x in v):
        raise ValueError(f"[system] {name} must be {size} finite numbers, got {thaw(v)!r}")


def validate(c: RoundsConfig) -> None:
    """Raise ``ValueError`` naming the first bad field (sizes against the names included)."""
    n_obs, m = _count(c.states, "states"), _count(c.actions, "actions")
    names = [*c.states, *c.actions]
    names += [f"next_{s}" for s in c.states]
    dup = sorted({s for s in names if names.count(s) > 1} | ({"source"} & set(names)))
    if dup:
        raise ValueError(f"[system] names must be distinct and not 'source', got {dup}")
    _numbers("target", c.target, n_obs)
    _numbers("action_op", c.action_op, m)
    check_int("horizon", c.horizon)
    if c.action_limit is not None:
        check_number("action_limit", c.action_limit, 0.0, open_low=True)
    check_int("samples", c.samples)
    check_choice("method", c.method, SCHEDULES)
    check_number("dagger_fraction", c.dagger_fraction, 0.0, 1.0)
    check_choice("scale", c.scale, SCALES)
    observed.check_model(c, c.horizon)


#: ``[rounds] scale``: per-column standard deviation of the first round, or the log's units.
SCALES = ("std", "none")
SYSTEM_KEYS = ("states", "actions", "target", "action_op", "horizon", "action_limit", "A", "B")
#: TOML table -> {key: field}; [model] and [planner] as every observed system's (A and B are
#: in [system]).
TABLES = {
    "system": {k: k for k in SYSTEM_KEYS},
    "cost": {"Q": "Q", "R": "R"},
    "model": {k: f for k, f in observed.TABLES["model"].items() if k not in ("A", "B")},
    "planner": observed.TABLES["planner"],
    "rounds": {k: k for k in ("samples", "method", "dagger_fraction", "scale")},
}
_REQUIRED = {"system": ("states", "actions", "target"), "cost": ("Q", "R")}


def read_config(path) -> RoundsConfig:
    """The :class:`RoundsConfig` of a TOML file; one-line ``ValueError`` naming an unknown or
    missing table or key (:func:`loopid.settings.toml.read_tables`), or a bad value."""
    out, _ = read_tables(path, TABLES, _REQUIRED)
    try:
        return RoundsConfig(**out)
    except (ValueError, TypeError) as err:
        raise ValueError(f"--config {str(path)!r}: {str(err).splitlines()[0]}") from None
