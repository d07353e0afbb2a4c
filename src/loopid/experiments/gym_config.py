"""``loopid run gym --config FILE``: any Gymnasium env as the real system, from a TOML file.

The file has five tables (``examples/pendulum.toml`` is a complete one)::

    [env]          id (required), kwargs, reset_options, observe, horizon, num_envs, stop_norm,
                   vectorization ("sync" | "async")
    [cost]         target, Q, R (required; Q, R full matrices, diagonals or scalars over the
                   observed entries and the actions), action_op, test ("quadratic" | "reward" |
                   "module:function"), termination, cap
    [exploration]  ν: exactly one of gain (K [m, n_obs] or [m, n_obs + 1], a = a_op − K Δx),
                   policy ("module:function", obs -> action), nominal (open-loop actions
                   [T, m]); action_std (Gaussian action noise)
    [model]        A, B (nominal, default A = I, B = 0), time_varying, lambda (FTRL λ)
    [run]          methods (dagger | batch | abbeel), iterations, samples, seeds (a count or a
                   list), test_trajectories, dagger_fraction

Every problem (unknown or missing key, wrong size, Discrete space, unknown env id) raises
ValueError with one line naming the value, before anything runs. The run directory is the usual
one (:mod:`loopid.experiments.rundir`, scenario name ``gym``): ``config.toml`` (resolved, with
the defaults), ``cells/``, ``results.parquet`` and ``figure.png`` (mean test cost against
samples, with a standard-error band, per method).
"""

import importlib
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa

import loopid
from loopid.algorithms.host_loop import (
    Exploration,
    gym_agent,
    make_host_cell,
    nominal_model,
    run_learning_host,
)
from loopid.experiments.results import trace_table
from loopid.experiments.rundir import RunDir
from loopid.systems.from_gymnasium import (
    CallablePolicy,
    GymSystem,
    OpenLoopPolicy,
    quadratic_cost,
)

SCENARIO = "gym"
GYM_METHODS = ("dagger", "batch", "abbeel")
_KEYS = {
    "env": {
        "id": None, "kwargs": {}, "reset_options": {}, "observe": None, "horizon": None,
        "num_envs": 8, "stop_norm": None, "vectorization": "sync",
    },
    "cost": {
        "target": None, "Q": None, "R": None, "action_op": None, "test": "quadratic",
        "termination": 0.0, "cap": 1e8,
    },
    "exploration": {"gain": None, "policy": None, "nominal": None, "action_std": 0.0},
    "model": {"A": None, "B": None, "time_varying": False, "lambda": 1e-3},
    "run": {
        "methods": ["dagger", "batch"], "iterations": 10, "samples": 200, "seeds": 5,
        "test_trajectories": 10, "dagger_fraction": 0.5,
    },
}  # fmt: skip
_REQUIRED = {"env": ("id",), "cost": ("target", "Q", "R"), "exploration": ()}


def _import(name: str, what: str):
    mod, _, attr = name.partition(":")
    try:
        obj = getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError, ValueError):
        raise ValueError(f"{what} = {name!r} is not an importable 'module:function'") from None
    if not callable(obj):
        raise ValueError(f"{what} = {name!r} is not callable")
    return obj


def _int(name: str, v, low: int = 1) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
    return v


def _number(name: str, v, low: float = 0.0) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not v >= low:
        raise ValueError(f"{name} must be a number >= {low}, got {v!r}")
    return float(v)


def load_config(path) -> dict:
    """Read and check a gym TOML file; returns the resolved configuration (defaults filled in).

    Checks the keys and the values that need no env; :func:`build` checks sizes against the env.
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"config file {str(path)!r} does not exist") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{path}: not valid TOML: {err}") from None
    for table in raw:
        if table not in _KEYS:
            raise ValueError(f"{path}: unknown table [{table}]; allowed: {', '.join(_KEYS)}")
        if not isinstance(raw[table], dict):
            raise ValueError(f"{path}: {table} must be a table, got {raw[table]!r}")
    cfg = {}
    for table, defaults in _KEYS.items():
        given = raw.get(table, {})
        if table in _REQUIRED and table not in raw:
            raise ValueError(f"{path}: missing table [{table}]")
        for key in given:
            if key not in defaults:
                raise ValueError(
                    f"{path}: unknown key {table}.{key}; allowed: {', '.join(defaults)}"
                )
        for key in _REQUIRED.get(table, ()):
            if key not in given:
                raise ValueError(f"{path}: missing key {table}.{key}")
        cfg[table] = {**defaults, **given}
    ex = cfg["exploration"]
    kinds = [k for k in ("gain", "policy", "nominal") if ex[k] is not None]
    if len(kinds) != 1:
        raise ValueError(
            f"{path}: [exploration] needs exactly one of gain, policy, nominal, "
            f"got {kinds or 'none'}"
        )
    _number("exploration.action_std", ex["action_std"])
    r = cfg["run"]
    methods = r["methods"]
    if not isinstance(methods, list) or not methods:
        raise ValueError(f"run.methods must be a non-empty list, got {methods!r}")
    for m in methods:
        if m not in GYM_METHODS:
            raise ValueError(f"unknown method {m!r} in run.methods; choose from {GYM_METHODS}")
    for key in ("iterations", "samples", "test_trajectories"):
        _int(f"run.{key}", r[key])
    seeds = r["seeds"]
    if isinstance(seeds, int) and not isinstance(seeds, bool):
        seeds = list(range(_int("run.seeds", seeds)))
    if (
        not isinstance(seeds, list)
        or not seeds
        or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
    ):
        raise ValueError(f"run.seeds must be a count or a list of integers >= 0, got {seeds!r}")
    r["seeds"] = seeds
    if not 0.0 <= _number("run.dagger_fraction", r["dagger_fraction"]) <= 1.0:
        raise ValueError(f"run.dagger_fraction must lie in [0, 1], got {r['dagger_fraction']!r}")
    e = cfg["env"]
    if not isinstance(e["id"], str) or not e["id"]:
        raise ValueError(f"env.id must be a Gymnasium id, got {e['id']!r}")
    for key in ("kwargs", "reset_options"):
        if not isinstance(e[key], dict):
            raise ValueError(f"env.{key} must be a table, got {e[key]!r}")
    _int("env.num_envs", e["num_envs"])
    if e["horizon"] is not None:
        _int("env.horizon", e["horizon"])
    if e["stop_norm"] is not None and _number("env.stop_norm", e["stop_norm"]) <= 0:
        raise ValueError(f"env.stop_norm must be > 0, got {e['stop_norm']!r}")
    c = cfg["cost"]
    if c["test"] not in ("quadratic", "reward") and ":" not in str(c["test"]):
        raise ValueError(
            f"cost.test must be 'quadratic', 'reward' or 'module:function', got {c['test']!r}"
        )
    _number("cost.termination", c["termination"], low=-np.inf)
    if _number("cost.cap", c["cap"]) <= 0:
        raise ValueError(f"cost.cap must be > 0, got {c['cap']!r}")
    _number("model.lambda", cfg["model"]["lambda"])
    if not isinstance(cfg["model"]["time_varying"], bool):
        raise ValueError(f"model.time_varying must be true or false, got {cfg['model']!r}")
    cfg["run"]["loopid_version"] = loopid.__version__
    return cfg


def _checked(what: str, f, *args, **kwargs):
    """Call ``f``; prefix a ValueError's one line with the config table it concerns."""
    try:
        return f(*args, **kwargs)
    except ValueError as err:
        raise ValueError(f"[{what}] {str(err).splitlines()[0]}") from None


def build(cfg: dict):
    """(system, cost, test cost, agent, ν, cell) from a resolved configuration; checks sizes."""
    e, c = cfg["env"], cfg["cost"]
    system = GymSystem(
        e["id"], target=c["target"], env_kwargs=e["kwargs"], observe=e["observe"],
        a_op=c["action_op"], horizon=e["horizon"], num_envs=e["num_envs"],
        reset_options=e["reset_options"], vectorization=e["vectorization"],
        stop_norm=e["stop_norm"],
    )  # fmt: skip
    try:
        return (system, *_parts(cfg, system))
    except (ValueError, TypeError) as err:
        system.close()
        raise ValueError(str(err).splitlines()[0]) from None


def _parts(cfg: dict, system: GymSystem):
    e, c, ex, md = cfg["env"], cfg["cost"], cfg["exploration"], cfg["model"]
    sizes = (("Q", system.n_obs, "observed entries"), ("R", system.m, "actions"))
    for name, size, what in sizes:
        M = np.asarray(c[name], dtype=np.float64)
        if M.ndim >= 1 and M.shape[0] != size:
            raise ValueError(
                f"[cost] {name} must be {size}x{size} or {size} diagonal entries "
                f"({e['id']} has {size} {what}), got shape {M.shape}"
            )
    cost = _checked("cost", quadratic_cost, system.target, c["Q"], c["R"], system.a_op)
    test_cost = {"quadratic": cost, "reward": "reward"}.get(c["test"])
    if test_cost is None:
        test_cost = _import(c["test"], "cost.test")
    std = float(ex["action_std"])
    if ex["gain"] is not None:
        policy = _checked("exploration.gain", system.linear_policy, ex["gain"])
    elif ex["policy"] is not None:
        policy = CallablePolicy(_import(ex["policy"], "exploration.policy"), system.m)
    else:
        U = np.asarray(ex["nominal"], dtype=np.float64)
        if U.ndim != 2 or U.shape[1] != system.m or U.shape[0] < 1:
            raise ValueError(f"[exploration] nominal must be [T, {system.m}], got shape {U.shape}")
        policy = OpenLoopPolicy(U)
    model = _checked(
        "model", nominal_model, system, md["A"], md["B"], time_varying=md["time_varying"]
    )
    arrays = tuple((a.shape, a.tobytes()) for a in cost)
    key = (repr(md), arrays, system.horizon, cfg["run"]["samples"])
    if key not in _CELLS:  # the compiled learner/solver, reused by later runs in this process
        agent = gym_agent(system, cost, model, lam=md["lambda"])
        _CELLS[key] = (agent, make_host_cell(agent, samples=cfg["run"]["samples"]))
    agent, cell = _CELLS[key]
    return cost, test_cost, agent, Exploration(policy, std), cell


_CELLS: dict = {}


def fractions(method: str, iterations: int, dagger_fraction: float = 0.5) -> np.ndarray:
    """``p_n`` per iteration: dagger ½, batch 0, abbeel 0 at n = 2 (ν's data) then 1."""
    p = np.zeros(iterations)
    if method == "dagger":
        p[1:] = dagger_fraction
    elif method == "abbeel":
        p[2:] = 1.0
    return p


def run_gym_config(path, out, *, quiet: bool = False, log: Callable[[str], None] | None = None):
    """Run the methods of a gym TOML file into run directory ``out``; returns the table.

    Finished cells in ``out`` are kept (a rerun resumes); a directory holding another
    configuration is refused. ``log(line)`` gets one line per method (unless ``quiet``).
    """
    cfg = load_config(path)
    system, _, test_cost, agent, nu, cell = build(cfg)
    out = Path(out)
    rd = RunDir(out)
    rd.prepare(_written(cfg))
    r = cfg["run"]
    order = [(SCENARIO, m) for m in r["methods"]]
    try:
        for method in r["methods"]:
            if rd.done(SCENARIO, method):
                continue
            t0 = time.perf_counter()
            trace = run_learning_host(
                system, agent, nu, fractions(method, r["iterations"], r["dagger_fraction"]),
                r["seeds"], samples=r["samples"], n_test=r["test_trajectories"], cost=test_cost,
                termination_cost=cfg["cost"]["termination"], cost_cap=cfg["cost"]["cap"],
                cell=cell,
            )  # fmt: skip
            rd.save_cell(SCENARIO, method, trace_table(SCENARIO, method, trace))
            rd.write_results(order)
            if log and not quiet:
                final = np.median(trace.rows.test_cost[:, -1])
                secs = time.perf_counter() - t0
                log(f"gym / {method}: {secs:.1f} s, final median cost {final:.4g}")
    finally:
        system.close()
    table = rd.write_results(order)
    figure(table, out / "figure.png", title=f"{cfg['env']['id']}: test cost")
    return table


def _written(cfg: dict) -> dict:
    """The configuration as written to config.toml (None values left out)."""

    def strip(d):
        return {k: strip(v) if isinstance(v, dict) else v for k, v in d.items() if v is not None}

    return strip(cfg)


def figure(table: pa.Table, path, *, title: str = "") -> None:
    """Mean test cost (± one standard error over seeds) against samples, one line per method,
    log cost axis; written to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    df = {name: np.asarray(table.column(name).to_pylist()) for name in table.column_names}
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, method in enumerate(dict.fromkeys(df["method"].tolist())):
        sel = df["method"] == method
        samples = np.unique(df["samples"][sel])
        costs = [df["test_cost"][sel & (df["samples"] == s)] for s in samples]
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
    fig.savefig(path, dpi=120)
    plt.close(fig)
