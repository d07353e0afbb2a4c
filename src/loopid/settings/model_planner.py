"""The ``[model]`` and ``[planner]`` settings every family shares: fields, defaults, checks and
the agent specs they give.

A scenario chooses its model class and its optimal-control solver (the paper's
guarantee holds for any model class with a no-regret learner and any optimal-control solver)::

    [model]    kind = "linear" | "features" | "mlp"
               features = "polynomial" | "fourier"      (kind = "features")
               degree, count, bandwidth, seed           (the feature map)
               hidden, layers, learning_rate, steps, buffer   (kind = "mlp")
    [planner]  kind = "lqr" | "ilqr" | "mpc"
               horizon: mpc: the re-planning window (steps); ilqr: when set, the task-horizon
                 plan starts from the actions of an MPC episode of that window on the model
               iterations: iLQR iterations (per plan, per re-plan)
               every: mpc: re-plan every that many steps
               alternatives: constant actions Δu [k, m] also tried at every re-plan (the
                 cheapest plan is kept): the torque-limited swing-up needs [[2], [-2]]

In a config dataclass these are flat fields with a prefix (``model_kind``, ``model_degree``,
``planner_kind``, ...; :data:`FIELDS`), so ``--set model_kind=features`` works like any other
field, and a TOML file may write them either flat or as the two tables above
(:func:`loopid.settings.toml.flatten_tables` with :data:`TABLES`).

``linear`` + ``lqr`` is the paper's agent (linear offset model, FTRL, LQR) and the default: a
scenario that sets nothing here runs exactly as before. ``lqr`` needs the linear model (it solves
a Riccati equation on (Â, B̂)); ``ilqr`` and ``mpc`` plan on any model by autodiff.

:func:`specs` turns a config's fields into the frozen specs of
:mod:`loopid.algorithms.agents`, whose :func:`~loopid.algorithms.agents.make_agent` builds the
agent.
"""

import dataclasses
from dataclasses import dataclass
from typing import Any

from loopid.algorithms.agents import AgentSpec, LearnerSpec, ModelSpec, PlannerSpec
from loopid.models.feature_maps import DEFAULT_BANDWIDTH, DEFAULT_COUNT, DEFAULT_DEGREE
from loopid.settings.checks import check_choice, check_int, check_number
from loopid.settings.toml import freeze

MODEL_KINDS = ("linear", "features", "mlp")
FEATURE_MAPS = ("polynomial", "fourier")
PLANNER_KINDS = ("lqr", "ilqr", "mpc")


@dataclass(frozen=True, kw_only=True)
class ModelPlanner:
    """The model and planner fields (module docstring), shared by the config dataclasses that
    inherit them (keyword-only, so they follow the inheriting class's own fields).

    Attributes:
      model_kind: ``linear``, ``features`` or ``mlp``.
      model_features: the feature map, ``polynomial`` or ``fourier``.
      model_degree: the polynomial's highest degree (:mod:`loopid.models.feature_maps`).
      model_count, model_bandwidth, model_seed: random Fourier features: how many, their
        bandwidth σ (in the error coordinates' units) and the seed of their draw (the MLP's
        initial weights too).
      model_hidden, model_layers: the MLP's hidden width and number of hidden layers.
      model_learning_rate, model_steps, model_buffer: its Adam step size, Adam steps per
        update, and replay buffer rows (:mod:`loopid.models.mlp`).
      planner_kind: ``lqr``, ``ilqr`` or ``mpc``.
      planner_horizon: mpc: the re-planning window; ilqr: the window of the MPC episode on the
        model that gives the task-horizon plan its initial actions (None: no such episode).
      planner_iterations: iLQR iterations per plan (per re-plan under mpc).
      planner_every: mpc: steps between re-plans.
      planner_alternatives: constant actions ``Δu [k, m]`` also tried at each re-plan.
    """

    model_kind: str = "linear"
    model_features: str = "polynomial"
    model_degree: int = DEFAULT_DEGREE
    model_count: int = DEFAULT_COUNT
    model_bandwidth: float = DEFAULT_BANDWIDTH
    model_seed: int = 0
    model_hidden: int = 64
    model_layers: int = 2
    model_learning_rate: float = 1e-3
    model_steps: int = 200
    model_buffer: int = 4000
    planner_kind: str = "lqr"
    planner_horizon: int | None = None
    planner_iterations: int = 50
    planner_every: int = 1
    planner_alternatives: Any = None


#: Every field with its default, in the order config.toml writes them.
DEFAULTS: dict = {f.name: f.default for f in dataclasses.fields(ModelPlanner)}
FIELDS = tuple(DEFAULTS)
#: TOML table -> its keys (each key ``k`` of table ``t`` is the field ``t_k``).
TABLES = {
    "model": tuple(f[len("model_") :] for f in FIELDS if f.startswith("model_")),
    "planner": tuple(f[len("planner_") :] for f in FIELDS if f.startswith("planner_")),
}


def validate(s, horizon: int | None = None) -> None:
    """``ValueError`` (one line, naming the field) for a bad model or planner setting of the
    config ``s`` (any object with the :data:`FIELDS` as attributes). ``horizon``: the task's
    horizon when known, which ``planner_horizon`` may not exceed."""
    check_choice("model_kind", s.model_kind, MODEL_KINDS)
    check_choice("model_features", s.model_features, FEATURE_MAPS)
    for name in ("model_degree", "model_count", "model_hidden", "model_layers", "model_steps",
                 "model_buffer", "planner_iterations", "planner_every"):  # fmt: skip
        check_int(name, getattr(s, name))
    check_int("model_seed", s.model_seed, minimum=0)
    check_number("model_bandwidth", s.model_bandwidth, 0.0, open_low=True)
    check_number("model_learning_rate", s.model_learning_rate, 0.0, open_low=True)
    check_choice("planner_kind", s.planner_kind, PLANNER_KINDS)
    if s.planner_horizon is not None:
        check_int("planner_horizon", s.planner_horizon)
        if horizon is not None and s.planner_horizon > horizon:
            raise ValueError(
                f"planner_horizon {s.planner_horizon} is longer than the task's horizon {horizon}"
            )
    if s.planner_horizon is not None and s.planner_every > s.planner_horizon:
        raise ValueError(
            f"planner_every {s.planner_every} is longer than planner_horizon {s.planner_horizon}"
        )
    alt = s.planner_alternatives
    if alt is not None:
        rows = alt if isinstance(alt, tuple | list) else ()
        ok = len(rows) > 0 and all(
            isinstance(r, tuple | list) and len(r) > 0 and len(r) == len(rows[0])
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in r)
            for r in rows
        )  # fmt: skip
        if not ok:
            raise ValueError(
                f"planner_alternatives must be a list of action vectors [[...], ...], got {alt!r}"
            )
    if s.planner_kind == "lqr" and s.model_kind != "linear":
        raise ValueError(
            f"planner_kind 'lqr' solves a linear model; model_kind {s.model_kind!r} needs "
            "planner_kind 'ilqr' or 'mpc'"
        )


def is_default(s) -> bool:
    """True when ``s`` runs the paper's agent (linear model, LQR) with nothing else set."""
    return all(getattr(s, k) == v for k, v in DEFAULTS.items())


def describe(s) -> str:
    """One sentence for ``report.md``: the model class and the planner of the config ``s``, and
    for the MLP that its rows make no regret claim."""
    if s.model_kind == "features" and s.model_features == "polynomial":
        what = f"polynomial features of degree {s.model_degree}"
    else:
        what = f"{s.model_count} random Fourier features (bandwidth {s.model_bandwidth:g})"
    if s.model_kind == "features":
        model = f"a feature model ({what}), learned by FTRL (convex: the regret guarantee holds)"
    elif s.model_kind == "mlp":
        model = (
            f"an MLP ({s.model_layers} x {s.model_hidden} tanh) trained online with Adam "
            "(non-convex: the online loss is reported, no regret claim is made)"
        )
    else:
        model = "the linear offset model, learned by FTRL"
    window = "" if s.planner_horizon is None else f"{s.planner_horizon}-step "
    every = f"MPC ({window}iLQR plans re-planned every {s.planner_every} steps)"
    planner = {"lqr": "LQR", "ilqr": "iLQR over the task horizon", "mpc": every}[s.planner_kind]
    return f"Model: {model}; planner: {planner}."


def specs(s) -> AgentSpec:
    """The :class:`~loopid.algorithms.agents.AgentSpec` of the config ``s`` (its :data:`FIELDS`
    and ``ftrl_lambda``): what :func:`loopid.algorithms.agents.make_agent` builds the agent
    from. Hashable (the alternatives frozen), so a family may key a cache on it."""
    model = ModelSpec(
        kind=s.model_kind, features=s.model_features, degree=s.model_degree,
        count=s.model_count, bandwidth=s.model_bandwidth, seed=s.model_seed,
        hidden=s.model_hidden, layers=s.model_layers,
    )  # fmt: skip
    learner = LearnerSpec(
        ftrl_lambda=s.ftrl_lambda, learning_rate=s.model_learning_rate, steps=s.model_steps,
        buffer=s.model_buffer,
    )  # fmt: skip
    planner = PlannerSpec(
        kind=s.planner_kind, horizon=s.planner_horizon, iterations=s.planner_iterations,
        every=s.planner_every, alternatives=freeze(s.planner_alternatives),
    )  # fmt: skip
    return AgentSpec(model, learner, planner)
