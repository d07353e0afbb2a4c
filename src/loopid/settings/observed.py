"""The settings of an observed system's agent (a Gymnasium env, a rig run round by round): the
``[model]`` table's nominal model and FTRL λ and the ``[planner]`` table's start and cost, on top
of the shared model and planner fields (:mod:`loopid.settings.model_planner`).

In a config dataclass they are the fields ``A``, ``B``, ``time_varying``, ``ftrl_lambda``,
``planner_start`` and ``planner_cost``; with the config's ``Q``, ``R`` and ``samples`` they give
the :class:`~loopid.algorithms.host_agent.HostSpec` the compiled agent is built from
(:func:`host_spec`)::

    [model]    A, B (nominal, default A = I, B = 0), time_varying, lambda [ftrl_lambda],
               kind, features, degree, count, bandwidth, seed, hidden, layers,
               learning_rate, steps, buffer [model_*]
    [planner]  kind, horizon, iterations, every, alternatives, start, cost [planner_*]
"""

from loopid.algorithms.host_agent import HostSpec
from loopid.settings import model_planner
from loopid.settings.checks import check_number

#: TOML table -> {key: field}: the ``[model]`` and ``[planner]`` tables of the module docstring.
TABLES = {
    "model": {
        "A": "A", "B": "B", "time_varying": "time_varying", "lambda": "ftrl_lambda",
        **{k: f"model_{k}" for k in model_planner.TABLES["model"]},
    },
    "planner": {k: f"planner_{k}" for k in (*model_planner.TABLES["planner"], "start", "cost")},
}  # fmt: skip


def check_model(s, horizon: int | None) -> None:
    """``ValueError`` naming the first bad ``[model]`` or ``[planner]`` field of the config
    ``s`` (a gym scenario, a round directory's config: any object with these fields)."""
    if not isinstance(s.time_varying, bool):
        raise ValueError(f"time_varying must be true or false, got {s.time_varying!r}")
    check_number("ftrl_lambda", s.ftrl_lambda, 0.0)
    model_planner.validate(s, horizon)
    if s.time_varying and s.model_kind != "linear":
        raise ValueError(
            f"time_varying applies to the linear model; model_kind {s.model_kind!r} learns one "
            "model for every step"
        )


def host_spec(s, system: str) -> HostSpec:
    """The :class:`~loopid.algorithms.host_agent.HostSpec` of the config ``s`` (frozen: its
    lists kept as tuples); ``system``: what messages call the system."""
    return HostSpec(
        system=system, Q=s.Q, R=s.R, A=s.A, B=s.B, time_varying=s.time_varying,
        start=s.planner_start, cost=s.planner_cost, samples=s.samples,
        agent=model_planner.specs(s),
    )  # fmt: skip
