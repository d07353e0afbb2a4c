"""A helicopter run's saved policies and models: loaded, evaluated on fresh noise, flown and
animated."""

from pathlib import Path

import jax
import numpy as np

from loopid.algorithms import agents
from loopid.algorithms.keys import EVALUATE, TEST, seed_keys, stream_key
from loopid.algorithms.loop_program import noise_program
from loopid.experiments.artifacts import tested_gains
from loopid.experiments.families.helicopter import methods as M
from loopid.experiments.families.helicopter.assembly import scenario_plant, setup
from loopid.experiments.families.helicopter.scenario import Scenario
from loopid.models.linear_offset import LinearOffsetModel
from loopid.settings import model_planner
from loopid.systems import helicopter


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
    controller = GainController(tested_gains(arrays), error, np.zeros(helicopter.N_ACTION), delay)
    if _flew_mpc(s, arrays):
        params = st.model.restore(arrays)
        zero = np.zeros(helicopter.N_ACTION)
        controller = ReplanningController(st.replanner, params, error, zero, helicopter.N_STATE)
    model = None  # the MLP's network is saved (mlp.*) but not rebuilt here
    if "W" in arrays or "W_features" in arrays:  # the saved nominal, else the scenario's
        A, B = arrays.get("shared.A", st.nominal.A), arrays.get("shared.B", st.nominal.B)
        nominal = LinearOffsetModel(np.asarray(A), np.asarray(B))
        if "W" in arrays:
            model = LinearModel(nominal, arrays["W"])
        else:
            fmap = agents.feature_map(model_planner.specs(s).model, nominal.n, nominal.m)
            model = FeatureModel(nominal, fmap, arrays["W_features"])
    return model, controller


def evaluate(s: Scenario, arrays: dict, seeds, episodes: int, env=None) -> np.ndarray:
    """Capped test costs ``[S, episodes]`` of the saved policies on fresh noise (the stream
    :data:`~loopid.algorithms.keys.EVALUATE`), flown as the run flew them (its delay reading
    included): the gains the run tested (``best_K [S, T, m, n]`` under ``test_policy =
    "best"``, else ``K``), or under ``planner_kind = "mpc"`` MPC re-planning on each seed's
    saved model."""
    if env is not None:
        raise ValueError(f"--env {env!r} applies to gym runs, not to {s.name}")
    st = setup(s)
    plant, policy = st.plant, jax.numpy.asarray(tested_gains(arrays))
    if _flew_mpc(s, arrays):
        from loopid.algorithms.planning_agent import restore_seeds

        plant = st.mpc.plant
        policy = restore_seeds(st.model, arrays)
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
    from loopid.experiments.families.helicopter.flights import fly

    plant = scenario_plant(s)  # the whole Setup (its expert, model, program) only for MPC
    key = stream_key(jax.random.key(int(seed)), TEST)  # the loop's test noise
    noise = plant.eval_noise(key, 1)[0]
    flights = {}
    for m in methods:
        _, arrays = artifacts.read(Path(run_dir) / "cells", s.name, m)
        one = artifacts.for_seed(arrays, seed, f"{s.name}/{m}")
        if _flew_mpc(s, one):
            st = setup(s)
            params = st.model.restore(one)
            flights[m] = np.asarray(jax.jit(st.mpc.flight)(params, noise)[0])
        else:
            flights[m] = fly(plant.task, tested_gains(one), noise, s.delay_mode)
    return flights


def _saved_methods(run_dir, name: str) -> list[str]:
    found = sorted(
        p.stem.split("__", 1)[1] for p in (Path(run_dir) / "cells").glob(f"{name}__*.json")
    )
    return [m for m in M.METHODS if m in found]


def trajectories(run_dir, configs: dict[str, Scenario], path) -> None:
    """``trajectories.png``: per panel, what each method's final policy flies at the first
    seed (:mod:`loopid.experiments.families.helicopter.flights`)."""
    from loopid.experiments import artifacts
    from loopid.experiments.families.helicopter.flights import trajectories_figure

    panels = []
    for name, s in configs.items():
        methods = _saved_methods(run_dir, name)
        if methods:
            info, _ = artifacts.read(Path(run_dir) / "cells", name, methods[0])
            seed = info["seeds"][0]
            flights = _flights(run_dir, s, methods, seed)
            panels.append((scenario_plant(s).task, flights, f"{name}, seed {seed}"))
    if panels:
        trajectories_figure(panels, path)


def animate(run_dir, s: Scenario, methods, seed: int, path) -> None:
    """An animated GIF of the methods' saved final policies flying scenario ``s`` at ``seed``."""
    from loopid.experiments.families.helicopter.flights import animate as animate_flights

    saved = _saved_methods(run_dir, s.name)
    for m in methods:
        if m not in saved:
            raise ValueError(
                f"{s.name} has no saved policy of method {m!r}; it has {', '.join(saved)}"
            )
    animate_flights(scenario_plant(s).task, _flights(run_dir, s, methods, seed), path)
