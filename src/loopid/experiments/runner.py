"""One entry point for every method: ``run(method, scenario, seeds) -> Trace``.

Builds the plant (real system + task), the linearised expert L, the model-based agent and the
exploration distribution for a :class:`~loopid.experiments.scenarios.Scenario`, then runs the
method on all seeds at once (:mod:`loopid.algorithms.loop`).
"""

from collections.abc import Callable
from functools import lru_cache
from typing import NamedTuple

import jax
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
from loopid.models.linear_offset import LinearOffsetModel, hover_nominal
from loopid.systems import helicopter
from loopid.systems.funnel_nominal import funnel_nominal
from loopid.systems.tasks import make_task


class Setup(NamedTuple):
    """What a scenario's methods share: the plant, the expert's gains, the nominal model."""

    plant: Plant
    K_expert: jax.Array
    nominal: LinearOffsetModel


def nominal_model(plant: Plant, funnel: str = "spec") -> LinearOffsetModel:
    """The initial model every method starts from (SPEC §4.2).

    Time-invariant tasks: A = I, B adds Δu into u_prev and du_prev (the paper's hover model).
    Time-varying tasks: the funnel's nominal of the reading ``funnel`` (SPEC §5.2,
    :func:`loopid.systems.funnel_nominal.funnel_nominal`; ``spec``: the true simulator
    linearised about hover trim, the same at every step, plus the target's own motion
    ``−(x*_{t+1} ⊖ x*_t)``).
    """
    task = plant.task
    if not task.time_varying:
        return hover_nominal(helicopter.N_STATE, helicopter.N_ACTION)
    return funnel_nominal(funnel, task)


@lru_cache(maxsize=8)
def _setup_cached(
    task: str, noise_std, delay, pads: bool, stop_norm, nu_pending, cost_cap, delay_mode,
    funnel: str,
) -> Setup:  # fmt: skip
    t = make_task(task, noise_std=noise_std, delay=delay, pads=pads)
    plant = helicopter_plant(
        t, stop_norm=stop_norm, nu_pending=nu_pending, cost_cap=cost_cap, delay_mode=delay_mode
    )
    return Setup(plant, expert_gains(t), nominal_model(plant, funnel))


def _setup_key(s: Scenario) -> tuple:
    """The scenario fields that determine its :class:`Setup` (hashable)."""
    return (
        s.task, s.noise_std, s.delay, s.pads, s.stop_norm, s.nu_pending, s.cost_cap,
        s.delay_mode, s.funnel_nominal,
    )  # fmt: skip


def setup(s: Scenario) -> Setup:
    """The shared :class:`Setup` of a scenario (cached: the expert is computed once per task)."""
    return _setup_cached(*_setup_key(s))


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
    agent = _agent(s)
    if method == "pg":
        # hover: the trim-holding base flies π_1's test trajectories (π_1 never acts from μ);
        # the funnel's π_1 acts, so its gains are the base there (policy_gradient docstring)
        return run_policy_gradient(
            st.plant, agent, seeds, iterations=s.iterations, samples=s.samples,
            n_test=s.test_trajectories, horizon=s.pg_horizon, sigma=s.pg_sigma, step=s.pg_step,
            hold=s.task in ("hover", "hover-delay"), nu_state_var=s.nu_state_var,
            cost_cap=s.cost_cap, samples_mode=s.pg_samples, progress=progress,
        )  # fmt: skip
    nus, cell = _cell(s)
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


# The agent and the compiled cell are cached on the scenario fields that determine them (bounded,
# like the setups), so every method of a run shares one compilation and nothing is keyed on an
# object's id (which Python may reuse once the object is gone).


def _agent(s: Scenario) -> Agent:
    """The model-based agent of scenario ``s`` (linear offset model, FTRL, LQR)."""
    return _agent_cached(_setup_key(s), s.ftrl_lambda)


@lru_cache(maxsize=8)
def _agent_cached(setup_key: tuple, lam: float) -> Agent:
    st = _setup_cached(*setup_key)
    task = st.plant.task
    return linear_agent(st.nominal, ftrl_least_squares(lam), task.Q, task.R, st.plant.horizon)


def _cell(s: Scenario):
    """The ν samplers (ν_t, ν_e, ν_en) and the one compiled cell that DAgger, Batch and Abbeel
    share on this scenario, whichever ν they draw from (a traced switch)."""
    return _cell_cached(
        _setup_key(s), s.ftrl_lambda, s.nu_state_var, s.nu_action_var, s.expert_action_var,
        s.samples, s.iterations, s.test_trajectories, s.sampling, s.gamma, s.test_policy,
    )  # fmt: skip


@lru_cache(maxsize=8)
def _cell_cached(
    setup_key, lam, nu_state_var, nu_action_var, expert_action_var, samples, iterations,
    test_trajectories, sampling, gamma, test_policy,
):  # fmt: skip
    st = _setup_cached(*setup_key)
    agent = _agent_cached(setup_key, lam)
    nus = [
        make_nu(
            kind, st.plant, st.K_expert, state_var=nu_state_var, action_var=nu_action_var,
            expert_action_var=expert_action_var,
        )
        for kind in NU_KINDS
    ]  # fmt: skip
    cell = make_cell(
        st.plant, agent, nus, samples=samples, iterations=iterations, n_test=test_trajectories,
        mode=sampling, gamma=gamma, test_policy=test_policy,
    )  # fmt: skip
    return nus, cell
