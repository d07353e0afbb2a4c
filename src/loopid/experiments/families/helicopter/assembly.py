"""What a helicopter scenario's methods share, built once (:func:`setup`): the plant, the
expert's gains, the initial model, the model class, the agent, the ν samplers, the compiled loop
program, under MPC the plant flown by MPC with its settings, and its seed chunks' test noise.

A Setup is kept in a bounded cache keyed on :func:`program_key` (the scenario itself with the
fields that cannot change a compiled program, its name and seed count, set to fixed values), so
every method of a run shares one compilation and renamed copies of a panel (the readings study)
share it too.
"""

from collections.abc import Callable
from functools import lru_cache
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms import agents
from loopid.algorithms.contracts import Agent, LoopProgram, LoopSpec
from loopid.algorithms.exploration import Centre, make_nus, planned_flight
from loopid.algorithms.keys import seed_keys
from loopid.algorithms.loop_program import make_loop_program
from loopid.algorithms.plant import Plant
from loopid.experiments.families.helicopter.scenario import Scenario
from loopid.models.linear_offset import LinearOffsetModel
from loopid.settings import model_planner
from loopid.systems import helicopter
from loopid.systems.helicopter import plant as core
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.tasks import make_task


class Setup(NamedTuple):
    """What a scenario's methods share, built once from its config (:func:`setup`).

    Attributes:
      plant: the helicopter under the scenario's task (:class:`loopid.algorithms.plant.Plant`).
      K_expert: the expert's gains ``[T, 4, 21]`` (the LQR of the true simulator's
        linearisation about the target,
        :func:`loopid.systems.helicopter.expert.expert_gains`).
      nominal: the initial model every learned offset adds to.
      model: the ``model_*`` model class (:func:`loopid.algorithms.agents.model_class`),
        or None for the paper's linear offset model.
      agent: the model-based agent (:func:`loopid.algorithms.agents.make_agent`).
      nus: the ν samplers ``[ν_t, ν_e, ν_en]`` (:data:`loopid.algorithms.exploration.NU_KINDS`).
      program: the one compiled loop program that DAgger, Batch and Abbeel share, whichever ν
        they draw from (a traced switch).
      mpc: under ``planner_kind = "mpc"``, the plant flown by MPC on the seed's learned model
        (:func:`loopid.algorithms.mpc_plant.mpc_plant`), else None.
      replanner: MPC's settings (:func:`loopid.control.replanner`), else None.
      test_noise: ``test_noise(seeds)``, the test noise of a seed chunk (integer seeds;
        :class:`loopid.algorithms.contracts.EvalNoise`; :func:`_noise`).
      loop: the learning loop the program compiles (:class:`loopid.algorithms.contracts.LoopSpec`:
        the plant flown, the agent, the ν samplers and the scenario's protocol).
    """

    plant: Plant
    K_expert: jax.Array
    nominal: LinearOffsetModel
    model: Any
    agent: Agent
    nus: list
    program: LoopProgram
    mpc: Any
    replanner: Any
    test_noise: Callable[[tuple[int, ...]], Any]
    loop: LoopSpec


def program_key(s: Scenario) -> Scenario:
    """The cache key of ``s``: the scenario with its name and seed count fixed (neither changes
    a compiled program: the seeds are an argument, vmapped)."""
    return s.replace(name="program", seeds=1)


def setup(s: Scenario) -> Setup:
    """The :class:`Setup` of scenario ``s``, built once per :func:`program_key` (cached)."""
    return _setup(program_key(s))


def scenario_plant(s: Scenario) -> Plant:
    """The plant of scenario ``s`` alone: its task and simulator, without the expert, the model
    or the loop program (what flying a saved policy needs; :attr:`Setup.plant` is this one).
    Cached like the Setup."""
    return _plant(program_key(s))


@lru_cache(maxsize=8)
def _plant(key: Scenario) -> Plant:
    task = make_task(key.task, noise_std=key.noise_std, delay=key.delay, pads=key.pads)
    return core.helicopter_plant(
        task, stop_norm=key.stop_norm, nu_pending=key.nu_pending, cost_cap=key.cost_cap,
        delay_mode=key.delay_mode,
    )  # fmt: skip


@lru_cache(maxsize=8)
def _setup(key: Scenario) -> Setup:
    alternatives = _alternatives(key)
    plant = _plant(key)
    task = plant.task
    K_expert = expert_gains(task)
    nominal = core.helicopter_nominal_model(plant, key.funnel_nominal)
    # the agent: the paper's by default; a ``model_*`` model class (one global model for every
    # step; the funnel's time-varying nominal is kept) is planned by iLQR on the task's
    # quadratic cost from the task's start, over the task horizon (under ``mpc`` too: its gains
    # are what the cell saves; MPC flies)
    spec = model_planner.specs(key)
    paper = agents.is_paper_agent(spec)
    model = None if paper else agents.model_class(spec.model, spec.learner, nominal)
    agent = agents.make_agent(
        spec, nominal, task.Q, task.R, plant.horizon,
        start=jax.jit(helicopter.to_error)(jnp.asarray(task.x0), jnp.asarray(task.target)[0]),
        U0=np.zeros((plant.horizon, helicopter.N_ACTION)), model=model,
    )  # fmt: skip
    nus = make_nus(
        plant, K_expert, state_var=key.nu_state_var, action_var=key.nu_action_var,
        expert_action_var=key.expert_action_var,
        centre=nu_t_centre(key.nu_t_center, plant, K_expert),
    )  # fmt: skip
    flown, controller, replan = None, None, None
    if key.planner_kind == "mpc":  # MPC flies the seed's learned model (its parameters)
        from loopid.algorithms.mpc_plant import mpc_plant
        from loopid.control import quadratic_cost, replanner

        # ``planner_horizon``-step plans on the model's dynamics (default the task horizon),
        # re-planned every ``planner_every`` steps, first from Δu = 0, the trim
        replan = replanner(
            model.dynamics, quadratic_cost(task.Q, task.R), np.zeros(helicopter.N_ACTION),
            horizon=key.planner_horizon or plant.horizon, every=key.planner_every,
            iterations=key.planner_iterations, alternatives=alternatives,
        )  # fmt: skip
        flown = mpc_plant(plant, replan)
        controller = lambda state, K: model.params(state)  # noqa: E731
    loop = LoopSpec(
        plant if flown is None else flown.plant, agent, nus, samples=key.samples,
        n_test=key.test_trajectories, mode=key.sampling, gamma=key.gamma,
        test_policy=key.test_policy,
    )  # fmt: skip
    program = make_loop_program(loop, key.iterations, controller=controller)

    def test_noise(seeds):
        return _noise(key, tuple(int(seed) for seed in seeds))  # a hashable cache key

    return Setup(
        plant, K_expert, nominal, model, agent, nus, program, flown, replan, test_noise, loop
    )


def nu_t_centre(reading: str, plant: Plant, K_expert: jax.Array) -> Centre | None:
    """What ν_t draws around under the reading ``nu_t_center``
    (:data:`loopid.experiments.families.helicopter.readings.NU_T_CENTERS`):

    - ``target``: the cost's target with no action (None:
      :func:`loopid.algorithms.exploration.nu_trajectory`'s default). On the funnel that target
      has no collective and a level attitude.
    - ``trim``: the target's states with the hover-trim controls in their previous-action
      entries, no action.
    - ``nominal``: the expert's planned flight, its states and its changes ``Δu``
      (:func:`loopid.algorithms.exploration.planned_flight`): on hover the trim itself, to
      round-off.
    """
    if reading == "target":
        return None
    if reading == "trim":
        target = jnp.asarray(plant.task.target, jnp.float64)
        return Centre(target.at[:, helicopter.U_PREV].set(helicopter.hover_trim().u))
    if reading == "nominal":
        try:
            return planned_flight(plant, K_expert)
        except ValueError as e:
            raise ValueError(f"nu_t_center = nominal: {e} (--set nu_t_center=target)") from None
    raise ValueError(f"unknown nu_t_center {reading!r}")


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


def agent(s: Scenario) -> Agent:
    """The model-based agent of scenario ``s`` (default the paper's: linear offset model, FTRL,
    LQR; else its ``model_*`` model class planned by iLQR)."""
    return setup(s).agent


def loop_program(s: Scenario) -> tuple[list, LoopProgram]:
    """The ν samplers (ν_t, ν_e, ν_en) and the one compiled loop program that DAgger, Batch and
    Abbeel share on this scenario, whichever ν they draw from (a traced switch)."""
    st = setup(s)
    return st.nus, st.program


@lru_cache(maxsize=2)
def _noise(key: Scenario, seeds: tuple[int, ...]):
    """The test noise of ``seeds`` (:class:`loopid.algorithms.contracts.EvalNoise`), computed
    once per scenario and seed chunk and shared by every method a process runs on them (a pure
    function of the seeds: each method reads the same arrays it would have drawn itself)."""
    return _setup(key).program.noise(seed_keys(np.asarray(seeds)))
