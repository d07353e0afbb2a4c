"""What a helicopter scenario's methods share, built once: the plant, the expert's gains, the
initial model (:class:`Setup`), the agent, the model class, MPC's settings, the compiled loop
program with its ν samplers, and a seed chunk's test noise.

Each is kept in a bounded cache keyed on :func:`program_key` (the scenario itself with the
fields that cannot change a compiled program, its name and seed count, set to fixed values), so
every method of a run shares one compilation and renamed copies of a panel (the readings study)
share it too.
"""

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms import helicopter_plant as core
from loopid.algorithms.expert import expert_gains
from loopid.algorithms.loop import (
    Agent,
    make_loop_program,
    seed_keys,
)
from loopid.algorithms.plant import Plant
from loopid.experiments import model_planner
from loopid.experiments.scenarios import Scenario
from loopid.exploration import NU_KINDS, make_nu
from loopid.models.linear_offset import LinearOffsetModel
from loopid.systems import helicopter
from loopid.systems.tasks import make_task


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
    """The shared :class:`~loopid.experiments.families.helicopter.assembly.Setup` of a
    scenario (cached: the expert is computed once)."""
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
def _program(key: Scenario):
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
    program = make_loop_program(
        plant, _agent(key), nus, samples=key.samples, iterations=key.iterations,
        n_test=key.test_trajectories, mode=key.sampling, gamma=key.gamma,
        test_policy=key.test_policy, controller=controller,
    )  # fmt: skip
    return nus, program


@lru_cache(maxsize=2)
def _noise(key: Scenario, seeds: tuple[int, ...]):
    """The test noise of ``seeds`` (:class:`loopid.algorithms.loop.EvalNoise`), computed once per
    scenario and seed chunk and shared by every method a process runs on them (a pure function
    of the seeds: each method reads the same arrays it would have drawn itself)."""
    return _program(key)[1].noise(seed_keys(np.asarray(seeds)))


def loop_program(s: Scenario):
    """The ν samplers (ν_t, ν_e, ν_en) and the one compiled loop program that DAgger, Batch and
    Abbeel share on this scenario, whichever ν they draw from (a traced switch)."""
    return _program(program_key(s))
