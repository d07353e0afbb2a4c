"""The helicopter family: the paper's Figure 2 (its hover and funnel tasks and nine methods)
through the one pipeline.

Config: :class:`loopid.experiments.scenarios.Scenario` (the packaged panels ``hover``,
``hover-delay`` and ``funnel``, every protocol setting a field). Methods: the paper's nine,
:data:`loopid.algorithms.methods.METHODS`.

For a scenario this module builds the plant (the JAX helicopter under the task:
:func:`loopid.algorithms.helicopter_plant.helicopter_plant`), the linearised expert L, the
initial model (:func:`loopid.algorithms.helicopter_plant.helicopter_nominal_model`), the
model-based agent (linear offset model, FTRL, LQR) and the exploration distributions, then
runs a method on all seeds at once (:mod:`loopid.algorithms.loop`). Figure: the paper's Figure 2
(:mod:`loopid.experiments.plots`); report: the final costs with each panel's readings of the
details the paper leaves open (:mod:`loopid.experiments.readings`), and the paper's five
findings (:mod:`loopid.experiments.findings`). The learning methods can run as one lane set
(:func:`run_lanes`, the default on an accelerator).

Caching: the setup, the agent and the compiled cell (with its test-noise program) are kept in
bounded caches keyed on :func:`program_key` (the scenario itself with the fields that cannot change
a compiled program, its name and seed count, set to fixed values), so every method of a run shares
one compilation and renamed copies of a panel (the readings study) share it too.
"""

from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms import helicopter_plant as core
from loopid.algorithms import methods as M
from loopid.algorithms.expert import expert_gains
from loopid.algorithms.keys import TEST, stream_key
from loopid.algorithms.loop import (
    EVALUATE,
    Agent,
    Trace,
    at_least,
    cell_memory,
    make_cell,
    noise_program,
    run_fixed_policy,
    seed_keys,
)
from loopid.algorithms.loop import run_lanes as run_learning_lanes
from loopid.algorithms.plant import Plant
from loopid.algorithms.policy_gradient import run_policy_gradient
from loopid.experiments import model_planner
from loopid.experiments.config import read_flat_file
from loopid.experiments.families.base import Family, Progress
from loopid.experiments.findings import findings_section
from loopid.experiments.report import final_cost_sections
from loopid.experiments.scenarios import FIELDS, SCENARIOS, Scenario, readings_line, scenario
from loopid.exploration import NU_KINDS, make_nu
from loopid.models.linear_offset import LinearOffsetModel
from loopid.systems import helicopter
from loopid.systems.tasks import is_hover, make_task


class Setup(NamedTuple):
    """What a scenario's methods share: the plant, the expert's gains, the nominal model."""

    plant: Plant
    K_expert: jax.Array
    nominal: LinearOffsetModel


def program_key(s: Scenario) -> Scenario:
    """The cache key of ``s``: the scenario with its name and seed count fixed (neither changes
    a compiled program: the seeds are an argument, vmapped)."""
    return s.replace(name="program", seeds=1)


@lru_cache(maxsize=8)
def _setup(key: Scenario) -> Setup:
    task = make_task(key.task, noise_std=key.noise_std, delay=key.delay, pads=key.pads)
    plant = core.helicopter_plant(
        task, stop_norm=key.stop_norm, nu_pending=key.nu_pending, cost_cap=key.cost_cap,
        delay_mode=key.delay_mode,
    )  # fmt: skip
    return Setup(
        plant, expert_gains(task), core.helicopter_nominal_model(plant, key.funnel_nominal)
    )


def setup(s: Scenario) -> Setup:
    """The shared :class:`Setup` of a scenario (cached: the expert is computed once)."""
    return _setup(program_key(s))


@lru_cache(maxsize=8)
def _agent(key: Scenario) -> Agent:
    """The scenario's agent (:func:`loopid.experiments.model_planner.make_agent`): the paper's
    by default; a ``model_*`` model class (one global model for every step; the funnel's
    time-varying nominal is kept) is planned by iLQR on the task's quadratic cost from the task's
    start, over the task horizon (under ``mpc`` too: its gains are what the cell saves; MPC
    flies, :func:`_mpc`)."""
    st = _setup(key)
    task, horizon = st.plant.task, st.plant.horizon
    target = jnp.asarray(task.target)
    return model_planner.make_agent(
        key, st.nominal, task.Q, task.R, horizon,
        start=helicopter.to_error(jnp.asarray(task.x0), target[0]),
        U0=np.zeros((horizon, helicopter.N_ACTION)),
        alternatives=None if model_planner.is_paper_agent(key) else _alternatives(key),
        model=None if model_planner.is_paper_agent(key) else _model(key),
    )  # fmt: skip


def _alternatives(key: Scenario):
    """``planner_alternatives`` as an array ``[k, 4]`` (None when unset)."""
    alternatives = key.planner_alternatives
    if alternatives is None:
        return None
    A = np.asarray(alternatives, np.float64)
    if A.shape[1] != helicopter.N_ACTION:
        raise ValueError(
            f"planner_alternatives must be action vectors of {helicopter.N_ACTION} entries, "
            f"got {alternatives!r}"
        )
    return A


@lru_cache(maxsize=8)
def _model(key: Scenario):
    """The scenario's model class (one object per program key: the planners compiled for its
    ``dynamics`` are shared)."""
    return model_planner.model_class(key, _setup(key).nominal)


def _mpc(key: Scenario):
    """``planner_kind = "mpc"``: the plant flown by MPC on the seed's learned model
    (:func:`loopid.algorithms.mpc_plant.mpc_plant`, an :class:`MPCPlant`; ``planner_horizon``-step
    plans, default the task horizon, re-planned every ``planner_every`` steps with
    ``planner_iterations`` iLQR iterations, first from Δu = 0, the trim) and the loop's
    controller, the seed's model parameters."""
    from loopid.algorithms.mpc_plant import mpc_plant

    st, model = _setup(key), _model(key)
    return mpc_plant(st.plant, _replanner(key)), lambda state, K: model.params(state)


def _replanner(key: Scenario):
    """The MPC settings of :func:`_mpc` (:func:`loopid.control.replanner`)."""
    from loopid.control import quadratic_cost, replanner

    st, model = _setup(key), _model(key)
    task = st.plant.task
    return replanner(
        model.dynamics, quadratic_cost(task.Q, task.R), np.zeros(helicopter.N_ACTION),
        horizon=key.planner_horizon or st.plant.horizon, every=key.planner_every,
        iterations=key.planner_iterations, alternatives=_alternatives(key),
    )  # fmt: skip


def agent(s: Scenario) -> Agent:
    """The model-based agent of scenario ``s`` (default the paper's: linear offset model, FTRL,
    LQR; else its ``model_*`` model class planned by iLQR)."""
    return _agent(program_key(s))


@lru_cache(maxsize=8)
def _cell(key: Scenario):
    st = _setup(key)
    nus = [
        make_nu(
            kind, st.plant, st.K_expert, state_var=key.nu_state_var, action_var=key.nu_action_var,
            expert_action_var=key.expert_action_var,
        )
        for kind in NU_KINDS
    ]  # fmt: skip
    plant, controller = st.plant, None
    if key.planner_kind == "mpc":
        mpc, controller = _mpc(key)
        plant = mpc.plant
    cell = make_cell(
        plant, _agent(key), nus, samples=key.samples, iterations=key.iterations,
        n_test=key.test_trajectories, mode=key.sampling, gamma=key.gamma,
        test_policy=key.test_policy, controller=controller,
    )  # fmt: skip
    return nus, cell


@lru_cache(maxsize=2)
def _noise(key: Scenario, seeds: tuple[int, ...]):
    """The test noise of ``seeds`` (:class:`loopid.algorithms.loop.EvalNoise`), computed once per
    scenario and seed chunk and shared by every method a process runs on them (a pure function
    of the seeds: each method reads the same arrays it would have drawn itself)."""
    return _cell(key)[1].noise(seed_keys(np.asarray(seeds)))


def cell(s: Scenario):
    """The ν samplers (ν_t, ν_e, ν_en) and the one compiled cell that DAgger, Batch and Abbeel
    share on this scenario, whichever ν they draw from (a traced switch)."""
    return _cell(program_key(s))


def run(method: str, s: Scenario, seeds=None, progress: Progress | None = None) -> Trace:
    """Run ``method`` (:data:`loopid.algorithms.methods.METHODS`) on scenario ``s``.

    ``seeds``: integer seeds (default ``range(s.seeds)``). Returns a :class:`Trace` with one row
    per seed and iteration; ``progress(n, row)`` is called after every iteration.
    """
    M.check_method(method)
    seeds = np.arange(s.seeds) if seeds is None else np.asarray(seeds)
    return at_least(lambda padded: _run(method, s, padded, progress), seeds)


def _run(method: str, s: Scenario, seeds: np.ndarray, progress: Progress | None) -> Trace:
    key = program_key(s)
    st = _setup(key)
    noise = _noise(key, tuple(int(seed) for seed in seeds))
    if method == "expert":
        return run_fixed_policy(
            st.plant, st.K_expert, seeds, iterations=s.iterations, samples=s.samples,
            n_test=s.test_trajectories, progress=progress, noise=noise.test,
        )  # fmt: skip
    if method == "pg":
        # hover: the trim-holding base flies π_1's test trajectories (π_1 never acts from μ);
        # the funnel's π_1 acts, so its gains are the base there (policy_gradient docstring)
        return run_policy_gradient(
            st.plant, _agent(key), seeds, iterations=s.iterations, samples=s.samples,
            n_test=s.test_trajectories, horizon=s.pg_horizon, sigma=s.pg_sigma, step=s.pg_step,
            hold=is_hover(s.task), nu_state_var=s.nu_state_var, cost_cap=s.cost_cap,
            samples_mode=s.pg_samples, update=s.pg_update, progress=progress, noise=noise.test,
        )  # fmt: skip
    return run_lanes((method,), s, seeds, progress, padded=True)[method]


#: The methods that are not learning lanes: the fixed expert and the policy-gradient baseline.
NOT_LANES = ("expert", "pg")


def lane_sets(s: Scenario, methods) -> list[tuple[str, ...]]:
    """The methods of ``methods`` grouped as they can run: the learning methods (DAgger, Batch
    and Abbeel with any ν) as one lane set, the expert and the policy gradient alone."""
    learning = tuple(m for m in methods if m not in NOT_LANES)
    return ([learning] if learning else []) + [(m,) for m in methods if m in NOT_LANES]


def run_lanes(
    methods, s: Scenario, seeds=None, progress: Progress | None = None, *, padded: bool = False
) -> dict[str, Trace]:
    """Learning methods of scenario ``s`` as one lane set
    (:func:`loopid.algorithms.loop.run_lanes`: every (method, seed) pair a lane of one
    compiled program, the ν draws and test noise shared): ``{method: Trace}``, each the same
    numbers as :func:`run` of that method. ``progress(n, row)``: the row's leaves ``[M·S]``.
    ``padded``: the seeds are already at least :data:`~loopid.algorithms.loop.MIN_SEEDS`."""
    for m in methods:
        M.check_method(m)
        if m in NOT_LANES:
            raise ValueError(f"{m} is not a learning method; run it alone")
    seeds = np.arange(s.seeds) if seeds is None else np.asarray(seeds)
    if not padded:
        return at_least(lambda pad: run_lanes(methods, s, pad, progress, padded=True), seeds)
    key = program_key(s)
    st = _setup(key)
    nus, compiled = _cell(key)
    schedules = [
        M.policy_fractions(m, s.iterations, dagger_fraction=s.dagger_fraction) for m in methods
    ]
    traces = run_learning_lanes(
        st.plant, _agent(key), nus, schedules, seeds, samples=s.samples,
        n_test=s.test_trajectories, mode=s.sampling, gamma=s.gamma, test_policy=s.test_policy,
        progress=progress, cell=compiled, which=[NU_KINDS.index(M.nu_kind(m)) for m in methods],
        noise=_noise(key, tuple(int(seed) for seed in seeds)),
    )  # fmt: skip
    return dict(zip(methods, traces, strict=True))


def memory(s: Scenario, method: str | tuple[str, ...], seeds: int) -> int:
    """Peak bytes of the cell's programs for ``seeds`` seeds (of each method of a lane set)
    (:func:`loopid.algorithms.loop.cell_memory`). The expert and the policy-gradient baseline
    run the test-noise program and a test that reads it (plus, for PG, rollouts of one state per
    probe), so the noise program is their peak."""
    if isinstance(method, tuple):  # a lane set (run_lanes)
        return cell_memory(_cell(program_key(s))[1], seeds, methods=len(method))
    M.check_method(method)
    return cell_memory(_cell(program_key(s))[1], seeds, test_only=method in NOT_LANES)


def report(table, configs: dict[str, Scenario]) -> list[str]:
    """The final costs per panel, each with its readings (:mod:`loopid.experiments.readings`),
    and the five findings."""
    notes = {
        name: f"Readings: {readings_line(s)}."
        + ("" if model_planner.is_default(s) else f" {model_planner.describe(s)}")
        for name, s in configs.items()
    }
    hover = {name for name, s in configs.items() if is_hover(s.task)}
    return [*final_cost_sections(table, notes), *findings_section(table, hover)]


def figure(table, path, configs) -> None:
    """The paper's Figure 2 (:func:`loopid.experiments.plots.figure`)."""
    from loopid.experiments.plots import figure as figure2

    figure2(table, path)


def load(s: Scenario, method: str, arrays: dict):
    """One seed's saved model and controller (:mod:`loopid.experiments.saved`): the gains act on
    ``to_error(x_t, x*_t)`` and give the control change Δu (the Gymnasium envs' action); where
    the cell flew MPC, the controller re-plans on the saved model
    (:class:`~loopid.experiments.learned.ReplanningController`)."""
    from loopid.experiments.learned import (
        FeatureModel,
        GainController,
        LinearModel,
        ReplanningController,
    )

    st = setup(s)
    target = np.asarray(st.plant.task.target)
    T = target.shape[0] - 1

    def error(x, t):
        return np.asarray(helicopter.to_error(x, target[min(t, T)]))

    delay = st.plant.task.delay if s.delay_mode == "latency" else 0
    controller = GainController(arrays["K"], error, np.zeros(helicopter.N_ACTION), delay)
    if _flew_mpc(s, arrays):
        key = program_key(s)
        params = _model(key).restore(arrays)
        zero = np.zeros(helicopter.N_ACTION)
        controller = ReplanningController(_replanner(key), params, error, zero, helicopter.N_STATE)
    model = None  # the MLP's network is saved (mlp.*) but not rebuilt here
    if "W" in arrays or "W_features" in arrays:  # the saved nominal, else the scenario's
        A, B = arrays.get("shared.A", st.nominal.A), arrays.get("shared.B", st.nominal.B)
        nominal = LinearOffsetModel(np.asarray(A), np.asarray(B))
        if "W" in arrays:
            model = LinearModel(nominal, arrays["W"])
        else:
            fmap = model_planner.feature_map(s, nominal.n, nominal.m)
            model = FeatureModel(nominal, fmap, arrays["W_features"])
    return model, controller


def shared(s: Scenario, method: str) -> dict:
    """What a learning cell's seeds share: the nominal model ``A``, ``B`` its offsets add to."""
    if method in ("expert", "pg"):
        return {}
    nominal = setup(s).nominal
    return {"A": np.asarray(nominal.A), "B": np.asarray(nominal.B)}


def evaluate(s: Scenario, arrays: dict, seeds, episodes: int, env=None) -> np.ndarray:
    """Capped test costs ``[S, episodes]`` of the saved policies on fresh noise (the stream
    :data:`~loopid.algorithms.keys.EVALUATE`), flown as the run flew them (its delay reading
    included): the gains ``arrays["K"] [S, T, m, n]``, or under ``planner_kind = "mpc"`` MPC
    re-planning on each seed's saved model."""
    if env is not None:
        raise ValueError(f"--env {env!r} applies to gym runs, not to {s.name}")
    plant, policy = setup(s).plant, jax.numpy.asarray(arrays["K"])
    if _flew_mpc(s, arrays):
        from loopid.algorithms.planning_agent import restore_seeds

        plant = _mpc(program_key(s))[0].plant
        policy = restore_seeds(_model(program_key(s)), arrays)
    noise = noise_program(plant, episodes, "last", EVALUATE)(seed_keys(seeds)).test
    costs, _ = jax.jit(plant.eval_seeds)(policy, noise)
    return np.asarray(costs)


def _flew_mpc(s: Scenario, arrays: dict) -> bool:
    """Whether the cell whose saved arrays these are flew MPC: ``planner_kind = "mpc"`` and a
    learned model saved (the expert and the policy-gradient baseline fly gains)."""
    from loopid.algorithms.planning_agent import holds_model

    return s.planner_kind == "mpc" and holds_model(arrays)


def _flights(run_dir, s: Scenario, methods, seed: int) -> dict:
    """``{method: X [T+1, 21]}``: each method's saved final policy at ``seed`` flying the run's
    first test trajectory of that seed (its noise), from the task's start (MPC re-planning on
    the saved model where the run flew MPC)."""
    from loopid.experiments import artifacts
    from loopid.experiments.flights import fly

    plant = setup(s).plant
    key = stream_key(jax.random.key(int(seed)), TEST)  # the loop's test noise
    noise = plant.eval_noise(key, 1)[0]
    flights = {}
    for m in methods:
        _, arrays = artifacts.read(Path(run_dir) / "cells", s.name, m)
        one = artifacts.for_seed(arrays, seed, f"{s.name}/{m}")
        if _flew_mpc(s, one):
            params = _model(program_key(s)).restore(one)
            flights[m] = np.asarray(jax.jit(_mpc(program_key(s))[0].flight)(params, noise)[0])
        else:
            flights[m] = fly(plant.task, one["K"], noise, s.delay_mode)
    return flights


def _saved_methods(run_dir, name: str) -> list[str]:
    found = sorted(
        p.stem.split("__", 1)[1] for p in (Path(run_dir) / "cells").glob(f"{name}__*.json")
    )
    return [m for m in M.METHODS if m in found]


def trajectories(run_dir, configs: dict[str, Scenario], path) -> None:
    """``trajectories.png``: per panel, what each method's final policy flies at the first
    seed (:mod:`loopid.experiments.flights`)."""
    from loopid.experiments import artifacts
    from loopid.experiments.flights import trajectories_figure

    panels = []
    for name, s in configs.items():
        methods = _saved_methods(run_dir, name)
        if methods:
            info, _ = artifacts.read(Path(run_dir) / "cells", name, methods[0])
            seed = info["seeds"][0]
            flights = _flights(run_dir, s, methods, seed)
            panels.append((setup(s).plant.task, flights, f"{name}, seed {seed}"))
    if panels:
        trajectories_figure(panels, path)


def animate(run_dir, s: Scenario, methods, seed: int, path) -> None:
    """An animated GIF of the methods' saved final policies flying scenario ``s`` at ``seed``."""
    from loopid.experiments.flights import animate as animate_flights

    saved = _saved_methods(run_dir, s.name)
    for m in methods:
        if m not in saved:
            raise ValueError(
                f"{s.name} has no saved policy of method {m!r}; it has {', '.join(saved)}"
            )
    animate_flights(setup(s).plant.task, _flights(run_dir, s, methods, seed), path)


#: Names this module offered that live in the core now
#: (:mod:`loopid.algorithms.helicopter_plant`).
_MOVED = {"helicopter_plant": "helicopter_plant", "nominal_model": "helicopter_nominal_model"}


def __getattr__(name: str):
    if name in _MOVED:
        import warnings

        new = f"loopid.algorithms.helicopter_plant.{_MOVED[name]}"
        warnings.warn(
            f"loopid.experiments.families.helicopter.{name} is now {new}; the old name goes in "
            "the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(core, _MOVED[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


FAMILY = Family(
    name="helicopter",
    config=Scenario,
    methods=M.METHODS,
    scenarios=SCENARIOS,
    default_methods=lambda s: M.METHODS,
    build=lambda name, fields: scenario(name, **fields),
    read_file=lambda path: read_flat_file(path, FIELDS, tables=model_planner.TABLES),
    run=run,
    figure=figure,
    report=report,
    shared=shared,
    load=load,
    evaluate=evaluate,
    trajectories=trajectories,
    animate=animate,
    memory=memory,
    lane_sets=lane_sets,
    run_lanes=run_lanes,
)
