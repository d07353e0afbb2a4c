"""Finite-MDP scenarios (:class:`MDPScenario`) and their checks: the named scenarios, and the
MDP, ν and model class each one names. The family's overview is
:mod:`loopid.experiments.families.mdp`.
"""

from dataclasses import asdict, dataclass

import jax
import numpy as np

from loopid.algorithms.schedules import SCHEDULES
from loopid.experiments.families.mdp.agent import (
    classifier_model,
    counts_model,
    explicit_nu,
    policy_nu,
)
from loopid.settings.checks import check_choice, check_int, check_number, replaced
from loopid.systems.mdp import TRAP_WALK, FiniteMDP, random_mdp, trap_mdp

#: Each method follows the schedule of its name (:mod:`loopid.algorithms.schedules`).
MDP_METHODS = SCHEDULES


@dataclass(frozen=True)
class MDPScenario:
    """One finite-MDP experiment (frozen, hashable; checked when built).

    Attributes:
      name: the scenario name.
      system: ``random`` (a random MDP: ``n_states``, ``n_actions``, Dirichlet ``concentration``
        rows, drawn from ``jax.random.key(mdp_seed)``) or ``trap``
        (:func:`loopid.systems.mdp.trap_mdp` of ``length`` with ``slip``).
      gamma: the discount.
      nu: ``uniform`` over state-action pairs, or ``base``: D_{μ,π_ε} of the walk policy with
        action noise ``epsilon``.
      model: ``counts`` (count estimator, pseudo-weight ``alpha``) or ``hinge`` (deterministic
        classifier: step ``eta``, prior margin ``margin``).
      iterations, samples, seeds: N, m per iteration, and the seed count.
      horizon: rollout length (the geometric draw is truncated there: bias <= γ^horizon).
    """

    name: str
    system: str = "random"
    n_states: int = 10
    n_actions: int = 3
    concentration: float = 0.3
    length: int = 6
    slip: float = 0.2
    gamma: float = 0.9
    mdp_seed: int = 0
    nu: str = "uniform"
    epsilon: float = 1e-3
    model: str = "counts"
    alpha: float = 0.1
    eta: float = 1.0
    margin: float = 0.5
    iterations: int = 30
    samples: int = 100
    horizon: int = 150
    seeds: int = 8

    def __post_init__(self) -> None:
        for name in ("iterations", "samples", "seeds", "horizon", "n_states", "n_actions"):
            check_int(name, getattr(self, name))
        check_int("length", self.length)
        check_int("mdp_seed", self.mdp_seed, 0)
        check_choice("system", self.system, ("random", "trap"))
        check_choice("nu", self.nu, ("uniform", "base"))
        check_choice("model", self.model, ("counts", "hinge"))
        check_number("gamma", self.gamma, 0.0, 1.0 - 1e-12)
        check_number("epsilon", self.epsilon, 0.0, 1.0)
        check_number("slip", self.slip, 0.0, 1.0)
        for name in ("concentration", "alpha", "eta"):
            check_number(name, getattr(self, name), 0.0, open_low=True)
        check_number("margin", self.margin, 0.0)

    def replace(self, **changes) -> "MDPScenario":
        """A copy with ``changes``; unknown fields and bad values raise ValueError."""
        return replaced(self, changes, "MDP scenario")

    def to_dict(self) -> dict:
        """The fields as a plain dict (for config.toml)."""
        return asdict(self)


MDP_SCENARIOS = {
    "mdp-random": MDPScenario("mdp-random"),
    "mdp-trap": MDPScenario("mdp-trap", system="trap", nu="base", samples=50),
    "mdp-trap-hinge": MDPScenario(
        "mdp-trap-hinge", system="trap", nu="base", samples=50, model="hinge"
    ),
}


def as_scenario(scenario) -> MDPScenario:
    if isinstance(scenario, MDPScenario):
        return scenario
    if scenario not in MDP_SCENARIOS:
        raise ValueError(f"unknown MDP scenario {scenario!r}; choose from {sorted(MDP_SCENARIOS)}")
    return MDP_SCENARIOS[scenario]


def scenario_mdp(s: MDPScenario) -> FiniteMDP:
    """The scenario's true MDP (a random one is drawn from ``jax.random.key(mdp_seed)``)."""
    if s.system == "random":
        key = jax.random.key(s.mdp_seed)
        return random_mdp(
            key, s.n_states, s.n_actions, gamma=s.gamma, concentration=s.concentration
        )
    if s.system == "trap":
        return trap_mdp(s.length, slip=s.slip, gamma=s.gamma)
    raise ValueError(f"system must be 'random' or 'trap', got {s.system!r}")


def scenario_nu(s: MDPScenario, mdp: FiniteMDP):
    """``(dist [S, A], nu)`` of the scenario's exploration distribution."""
    S, A = mdp.n_states, mdp.n_actions
    if s.nu == "uniform":
        dist = np.full((S, A), 1.0 / (S * A))
        return dist, explicit_nu(mdp, dist)
    if s.nu == "base":
        if not 0.0 <= s.epsilon <= 1.0:
            raise ValueError(f"epsilon must lie in [0, 1], got {s.epsilon!r}")
        pi0 = np.full((S, A), s.epsilon / A)
        pi0[:, TRAP_WALK] += 1.0 - s.epsilon
        dist, nu = policy_nu(mdp, pi0)
        return np.asarray(dist), nu
    raise ValueError(f"nu must be 'uniform' or 'base', got {s.nu!r}")


def scenario_model(s: MDPScenario, mdp: FiniteMDP):
    """The scenario's model class and learner."""
    if s.model == "counts":
        return counts_model(mdp.n_states, mdp.n_actions, alpha=s.alpha)
    if s.model == "hinge":
        return classifier_model(mdp.n_states, mdp.n_actions, eta=s.eta, margin=s.margin)
    raise ValueError(f"model must be 'counts' or 'hinge', got {s.model!r}")


def build(name: str, changes: dict) -> MDPScenario:
    """The named scenario (:data:`MDP_SCENARIOS`) with ``changes``; ValueError on a bad field."""
    return as_scenario(name).replace(**changes)
