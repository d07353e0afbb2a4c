"""One entry point for every method: ``run(method, scenario, seeds) -> Trace``.

Builds the plant (real system + task), the linearised expert L, the model-based agent and the
exploration distribution for a :class:`~loopid.experiments.scenarios.Scenario`, then runs the
method on all seeds at once (:mod:`loopid.algorithms.loop`).
"""

from collections.abc import Callable
from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms import methods as M
from loopid.algorithms.expert import expert_gains
from loopid.algorithms.loop import Agent, Row, Trace, make_cell, run_fixed_policy, run_learning
from loopid.algorithms.model_based import linear_agent
from loopid.algorithms.plant import Plant, helicopter_plant
from loopid.algorithms.policy_gradient import run_policy_gradient
from loopid.experiments.scenarios import Scenario
from loopid.exploration import NU_KINDS, make_nu
from loopid.learners import ftrl_least_squares
from loopid.models.linear_offset import LinearOffsetModel, hover_nominal, time_varying_nominal
from loopid.systems import helicopter
from loopid.systems.tasks import make_task


class Setup(NamedTuple):
    """What a scenario's methods share: the plant, the expert's gains, the nominal model."""

    plant: Plant
    K_expert: jax.Array
    nominal: LinearOffsetModel


def nominal_model(plant: Plant) -> LinearOffsetModel:
    """The initial model every method starts from (SPEC §4.2).

    Time-invariant tasks: A = I, B adds Δu into u_prev and du_prev (the paper's hover model).
    Time-varying tasks: the true simulator linearised about hover trim, the same at every step,
    plus the target's own motion ``−(x*_{t+1} ⊖ x*_t)``.
    """
    task = plant.task
    if not task.time_varying:
        return hover_nominal(helicopter.N_STATE, helicopter.N_ACTION)
    hover = helicopter.hover_target()
    A, B = helicopter.linearize(hover, hover)
    target = jnp.asarray(task.target)
    inc = jax.vmap(helicopter.target_increment)(target[:-1], target[1:])
    return time_varying_nominal(A, B, inc)


@lru_cache(maxsize=8)
def _setup_cached(
    task: str, noise_std, delay, pads: bool, stop_norm, nu_pending, cost_cap
) -> Setup:
    t = make_task(task, noise_std=noise_std, delay=delay, pads=pads)
    plant = helicopter_plant(t, stop_norm=stop_norm, nu_pending=nu_pending, cost_cap=cost_cap)
    return Setup(plant, expert_gains(t), nominal_model(plant))


def setup(s: Scenario) -> Setup:
    """The shared :class:`Setup` of a scenario (cached: the expert is computed once per task)."""
    return _setup_cached(
        s.task, s.noise_std, s.delay, s.pads, s.stop_norm, s.nu_pending, s.cost_cap
    )


def run(
    method: str,
    s: Scenario,
    seeds=None,
    *,
    progress: Callable[[int, Row], None] | None = None,
) -> Trace:
    """Run ``method`` (:data:`loopid.algorithms.methods.METHODS`) on scenario ``s``.

    ``seeds``: integer seeds (default ``range(s.seeds)``). Returns a :class:`Trace` with one row
    per seed and iteration; ``progress(n, row)`` is called after every iteration.
    """
    if is_mdp(s):
        from loopid.experiments.mdp import run_mdp

        return run_mdp(method, s, seeds, progress=progress)
    M.check_method(method)
    seeds = np.arange(s.seeds) if seeds is None else np.asarray(seeds)
    st = setup(s)
    if method == "expert":
        return run_fixed_policy(
            st.plant,
            st.K_expert,
            seeds,
            iterations=s.iterations,
            samples=s.samples,
            n_test=s.test_trajectories,
            progress=progress,
        )
    agent = _agent(s, st)
    if method == "pg":
        # hover: the trim-holding base flies π_1's test trajectories (π_1 never acts from μ);
        # the funnel's π_1 acts, so its gains are the base there (policy_gradient docstring)
        return run_policy_gradient(
            st.plant, agent, seeds, iterations=s.iterations, samples=s.samples,
            n_test=s.test_trajectories, horizon=s.pg_horizon, sigma=s.pg_sigma, step=s.pg_step,
            hold=s.task in ("hover", "hover-delay"), nu_state_var=s.nu_state_var,
            cost_cap=s.cost_cap, progress=progress,
        )  # fmt: skip
    nus, cell = _cell(s, st, agent)
    fractions = M.policy_fractions(method, s.iterations, dagger_fraction=s.dagger_fraction)
    return run_learning(
        st.plant, agent, nus, fractions, seeds, samples=s.samples, n_test=s.test_trajectories,
        mode=s.sampling, gamma=s.gamma, test_policy=s.test_policy, progress=progress, cell=cell,
        which=NU_KINDS.index(M.nu_kind(method)),
    )  # fmt: skip


def is_mdp(s) -> bool:
    """Whether ``s`` is a finite-MDP scenario (:class:`loopid.experiments.mdp.MDPScenario`)."""
    from loopid.experiments.mdp import MDPScenario

    return isinstance(s, MDPScenario)


def scenario_methods(s) -> tuple[str, ...]:
    """The methods a scenario offers: the paper's nine for the helicopter, DAgger, Batch and
    Abbeel for finite MDPs."""
    if is_mdp(s):
        from loopid.experiments.mdp import MDP_METHODS

        return MDP_METHODS
    return M.METHODS


def check_methods(s, methods) -> None:
    """Raise ``ValueError`` naming the first method ``s`` does not offer."""
    allowed = scenario_methods(s)
    for m in methods:
        if m not in allowed:
            raise ValueError(f"unknown method {m!r} for {s.name}; choose from {', '.join(allowed)}")


_AGENTS: dict = {}
_CELLS: dict = {}


def _agent(s: Scenario, st: Setup) -> Agent:
    key = (id(st), s.ftrl_lambda)
    if key not in _AGENTS:
        learner = ftrl_least_squares(s.ftrl_lambda)
        task = st.plant.task
        _AGENTS[key] = linear_agent(st.nominal, learner, task.Q, task.R, st.plant.horizon)
    return _AGENTS[key]


def _cell(s: Scenario, st: Setup, agent: Agent):
    """The ν samplers (ν_t, ν_e, ν_en) and the one compiled cell that DAgger, Batch and Abbeel
    share on this scenario, whichever ν they draw from (a traced switch)."""
    key = (id(st), id(agent), s.nu_state_var, s.nu_action_var, s.expert_action_var)
    key += (s.samples, s.iterations, s.test_trajectories, s.sampling, s.gamma, s.test_policy)
    if key not in _CELLS:
        nus = [
            make_nu(
                kind, st.plant, st.K_expert, state_var=s.nu_state_var,
                action_var=s.nu_action_var, expert_action_var=s.expert_action_var,
            )
            for kind in NU_KINDS
        ]  # fmt: skip
        cell = make_cell(
            st.plant, agent, nus, samples=s.samples, iterations=s.iterations,
            n_test=s.test_trajectories, mode=s.sampling, gamma=s.gamma, test_policy=s.test_policy,
        )  # fmt: skip
        _CELLS[key] = (nus, cell)
    return _CELLS[key]
