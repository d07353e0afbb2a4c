"""The agent factory: a model class × an online learner × an optimal-control planner, built from
three small frozen specs; the one place every family assembles its agent.

Ross & Bagnell (2012), Algorithm 1, needs three things of an agent: a model class, a no-regret
online learner for it and an optimal-control solver; its guarantee holds for any such pair. A
family builds the specs once from its configuration and calls :func:`make_agent`:

- :class:`ModelSpec`: the model class: ``linear`` (the linear offset model), ``features``
  (``Δx' = AΔx + BΔu + Wᵀφ(Δx, Δu)``, a polynomial or random Fourier map φ,
  :mod:`loopid.models.feature_model`) or ``mlp`` (an online MLP residual,
  :mod:`loopid.models.mlp`);
- :class:`LearnerSpec`: its learner: FTRL least squares with regulariser λ (the linear and
  feature models: convex, the regret guarantee holds), or the MLP's Adam steps on a replay
  buffer (non-convex: no regret claim);
- :class:`PlannerSpec`: the solver: ``lqr`` (a Riccati recursion on (Â, B̂), the paper's),
  ``ilqr`` (iLQR over the task horizon by autodiff through the model) or ``mpc`` (iLQR plans
  of a shorter window re-planned every few steps; the loop's gains are the task-horizon plan's).

``linear`` + ``lqr`` is the paper's agent (:func:`loopid.algorithms.model_based.linear_agent`);
any other pair is a :class:`~loopid.algorithms.planning_agent.ModelClass` planned by iLQR
(:func:`loopid.algorithms.planning_agent.planning_agent`). The specs are frozen and hashable, so
a family may key its caches of compiled programs on them.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from loopid.algorithms import planning_agent as P
from loopid.algorithms.model_based import linear_agent
from loopid.control import quadratic_cost
from loopid.learners import ftrl_least_squares
from loopid.models import feature_maps as F
from loopid.models.mlp import mlp_learner


@dataclass(frozen=True, kw_only=True)
class ModelSpec:
    """The model class.

    Attributes:
      kind: ``linear``, ``features`` or ``mlp``.
      features: the feature map of ``features``: ``polynomial`` or ``fourier``.
      degree: the polynomial's highest degree.
      count, bandwidth: random Fourier features: how many, and their bandwidth σ (in the error
        coordinates' units).
      seed: the seed of the Fourier features' draw and of the MLP's initial weights.
      hidden, layers: the MLP's hidden width and number of hidden layers (tanh).
    """

    kind: str
    features: str
    degree: int
    count: int
    bandwidth: float
    seed: int
    hidden: int
    layers: int


@dataclass(frozen=True, kw_only=True)
class LearnerSpec:
    """The model's online learner.

    Attributes:
      ftrl_lambda: FTRL's regulariser λ (the linear and feature models).
      learning_rate, steps, buffer: the MLP's Adam step size, Adam steps per update and replay
        buffer rows.
    """

    ftrl_lambda: float
    learning_rate: float
    steps: int
    buffer: int


@dataclass(frozen=True, kw_only=True)
class PlannerSpec:
    """The optimal-control solver.

    Attributes:
      kind: ``lqr``, ``ilqr`` or ``mpc``.
      horizon: mpc: the re-planning window in steps; ilqr: the window of an MPC episode on the
        model that gives the task-horizon plan its initial actions (None: no such episode).
      iterations: iLQR iterations per plan (per re-plan under mpc).
      every: mpc: steps between re-plans.
      alternatives: constant actions ``Δu [k, m]`` (a tuple of tuples, or None) also tried at
        every re-plan, the cheapest plan kept; the caller checks that each has ``m`` entries.
    """

    kind: str
    horizon: int | None
    iterations: int
    every: int
    alternatives: Any


@dataclass(frozen=True)
class AgentSpec:
    """The three specs of one agent."""

    model: ModelSpec
    learner: LearnerSpec
    planner: PlannerSpec


def is_paper_agent(spec: AgentSpec) -> bool:
    """Whether ``spec`` is the paper's agent: the linear offset model learned by FTRL, solved by
    LQR (the other model and planner settings then do not matter)."""
    return spec.model.kind == "linear" and spec.planner.kind == "lqr"


def feature_map(model: ModelSpec, n: int, m: int) -> F.FeatureMap:
    """The feature map φ of ``model`` for ``n`` error coordinates and ``m`` actions (``linear``:
    the degree-1 map): what a saved ``W_features [p, n]`` multiplies."""
    if model.kind == "linear":
        return F.polynomial(n, m, 1)
    if model.features == "polynomial":
        return F.polynomial(n, m, model.degree)
    return F.random_fourier(n, m, model.count, model.bandwidth, model.seed)


def model_class(model: ModelSpec, learner: LearnerSpec, nominal) -> P.ModelClass:
    """The :class:`~loopid.algorithms.planning_agent.ModelClass` of ``model`` around the nominal
    linear offset model (``A [(T,) n, n]``, ``B [(T,) n, m]``): ``linear`` is the feature model
    of degree 1 (the linear offset model, planned on by iLQR), ``features`` a polynomial or
    random Fourier map learned by FTRL (λ = ``learner.ftrl_lambda``), ``mlp`` the online MLP
    (``layers`` hidden layers of ``hidden`` units, Adam)."""
    n, m = nominal.n, nominal.m
    if model.kind == "mlp":
        fit = mlp_learner(
            nominal, hidden=(model.hidden,) * model.layers, lr=learner.learning_rate,
            steps=learner.steps, capacity=learner.buffer,
        )  # fmt: skip
        return P.mlp_model(nominal, fit, seed=model.seed)
    fmap = feature_map(model, n, m)
    return P.feature_model(nominal, fmap, ftrl_least_squares(learner.ftrl_lambda))


def paper_agent(nominal, ftrl_lambda: float, Q, R, horizon: int):
    """The paper's agent: the linear offset model ``nominal`` (``A [(T,) n, n]``,
    ``B [(T,) n, m]``) learned by FTRL least squares with regulariser ``ftrl_lambda`` and solved
    by (time-varying) LQR on ``Q [n, n]``, ``R [m, m]`` over ``horizon`` steps
    (:func:`loopid.algorithms.model_based.linear_agent`)."""
    return linear_agent(nominal, ftrl_least_squares(ftrl_lambda), Q, R, horizon)


def make_agent(spec: AgentSpec, nominal, Q, R, horizon: int, *, start=None, U0=None,
               plan_cost=None, model=None):  # fmt: skip
    """The agent of ``spec`` (:class:`loopid.algorithms.contracts.Agent`).

    - the paper's (:func:`is_paper_agent`): the linear offset model ``nominal`` learned by FTRL
      (λ = ``spec.learner.ftrl_lambda``) and solved by (time-varying) LQR on ``Q [n, n]``,
      ``R [m, m]`` over ``horizon`` steps (:func:`loopid.algorithms.model_based.linear_agent`);
      the planning arguments are not used.
    - otherwise: the model class of ``spec`` (:func:`model_class`; ``model``: one already made
      from it, so that programs compiled for it are shared) planned by iLQR over ``horizon``
      steps from the error state ``start [n]``, first from the actions ``U0 [horizon, m]``, on
      ``plan_cost(Δx, Δu, t)`` (default the quadratic cost of ``Q``, ``R``); with planner kind
      ``ilqr`` and a planner horizon, the plan starts from an MPC episode of that window on the
      model, which also tries the planner's constant ``alternatives [k, m]``
      (:func:`loopid.algorithms.planning_agent.ilqr_plan`).
    """
    if is_paper_agent(spec):
        return paper_agent(nominal, spec.learner.ftrl_lambda, Q, R, horizon)
    planner = spec.planner
    if planner.horizon is not None and planner.horizon > horizon:
        raise ValueError(
            f"planner_horizon {planner.horizon} is longer than the task's horizon {horizon}"
        )
    mc = model_class(spec.model, spec.learner, nominal) if model is None else model
    seed_horizon = planner.horizon if planner.kind == "ilqr" else None
    alternatives = None
    if seed_horizon is not None and planner.alternatives is not None:
        alternatives = np.asarray(planner.alternatives, np.float64)
    plan = P.ilqr_plan(
        mc, quadratic_cost(Q, R) if plan_cost is None else plan_cost, start, U0,
        iterations=planner.iterations, seed_horizon=seed_horizon, seed_alternatives=alternatives,
    )  # fmt: skip
    return P.planning_agent(mc, plan)
