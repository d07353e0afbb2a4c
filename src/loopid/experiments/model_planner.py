"""The ``[model]`` and ``[planner]`` settings every family shares: fields, defaults and checks.

A scenario chooses its model class and its optimal-control solver (issue 19; the paper's
guarantee holds for any model class with a no-regret learner and any optimal-control solver)::

    [model]    kind = "linear" | "features" | "mlp"
               features = "polynomial" | "fourier"      (kind = "features")
               degree, count, bandwidth, seed           (the feature map)
               hidden, layers, learning_rate, steps, buffer   (kind = "mlp")
    [planner]  kind = "lqr" | "ilqr" | "mpc"
               horizon (mpc: the re-planning window, steps), iterations (iLQR), every (mpc)

In a config dataclass these are flat fields with a prefix (``model_kind``, ``model_degree``,
``planner_kind``, ...; :data:`FIELDS`), so ``--set model_kind=features`` works like any other
field, and a TOML file may write them either flat or as the two tables above
(:func:`loopid.experiments.config.flatten_tables` with :data:`TABLES`).

``linear`` + ``lqr`` is the paper's agent (linear offset model, FTRL, LQR) and the default: a
scenario that sets nothing here runs exactly as before. ``lqr`` needs the linear model (it solves
a Riccati equation on (Â, B̂)); ``ilqr`` and ``mpc`` plan on any model by autodiff.
"""

from loopid.experiments.config import check_choice, check_int, check_number

MODEL_KINDS = ("linear", "features", "mlp")
FEATURE_MAPS = ("polynomial", "fourier")
PLANNER_KINDS = ("lqr", "ilqr", "mpc")

#: Every field with its default, in the order config.toml writes them. ``planner_horizon`` None:
#: the task's horizon.
DEFAULTS: dict = {
    "model_kind": "linear",
    "model_features": "polynomial",
    "model_degree": 3,
    "model_count": 100,
    "model_bandwidth": 1.0,
    "model_seed": 0,
    "model_hidden": 64,
    "model_layers": 2,
    "model_learning_rate": 1e-3,
    "model_steps": 200,
    "model_buffer": 4000,
    "planner_kind": "lqr",
    "planner_horizon": None,
    "planner_iterations": 50,
    "planner_every": 1,
}
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
    if s.planner_kind == "lqr" and s.model_kind != "linear":
        raise ValueError(
            f"planner_kind 'lqr' solves a linear model; model_kind {s.model_kind!r} needs "
            "planner_kind 'ilqr' or 'mpc'"
        )


def is_default(s) -> bool:
    """True when ``s`` runs the paper's agent (linear model, LQR) with nothing else set."""
    return all(getattr(s, k) == v for k, v in DEFAULTS.items())
