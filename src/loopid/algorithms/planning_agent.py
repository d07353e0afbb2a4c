"""The model-based agent for any model class: a learned model, its online learner and a planner.

Algorithm 1 of Ross & Bagnell (2012) needs three things of an agent: a model class, a no-regret
online learner for it, and an optimal-control solver. :func:`planning_agent`
makes an :class:`~loopid.algorithms.contracts.Agent` of any :class:`ModelClass` and any planner, so
the JAX loop and the host loop run nonlinear models unchanged:

- :func:`feature_model`: Δx' = AΔx + BΔu + Wᵀφ(Δx, Δu) (:mod:`loopid.models.feature_model`),
  W fitted by an existing convex online learner (FTRL least squares, OGD) on the rows (φ, y = Δx' −
  (AΔx + BΔu)). Convex online learning: the regret tracking and the paper's guarantee carry over.
  A polynomial map of degree 1 is the linear offset model, which is how the linear model is
  planned on by iLQR.
- :func:`mlp_model`: Δx' = AΔx + BΔu + MLP_θ(Δx, Δu) (:mod:`loopid.models.mlp`), trained online
  with optax. Non-convex: its rows report the online loss, and no regret bound is claimed.

The planner (:func:`loopid.control.plan`) maps the learned dynamics ``f(Δx [n], Δu [m], t)`` to
the loop's policy form, time-varying affine gains ``K [horizon, m, n]`` (u_t = −K_t Δx_t, the last
column of K_t the feedforward: the plan's own actions and its local feedback about the planned
trajectory). Everything is a pure function of the learner state, so ``policy`` runs inside the
loop's one compiled step, vmapped over seeds, and nothing retraces between iterations.
"""

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from loopid import control
from loopid.algorithms.contracts import Agent, SolverInfo, Transitions
from loopid.learners import Learner
from loopid.models import feature_model as F
from loopid.models.feature_maps import FeatureMap
from loopid.models.linear_offset import LinearOffsetModel, residual_targets
from loopid.models.mlp import MLPLearner


class ModelClass(NamedTuple):
    """A learned dynamics model and its online learner, as pure functions of a fixed-shape state.

    - ``init() -> state``; ``update(state, batch: Transitions) -> state`` (masked rows ignored);
    - ``loss(state, batch) -> [b]``: per-row squared prediction error ‖Δx' − f(Δx, Δu, t)‖²;
    - ``params(state) -> P``: the model's parameters (a pytree), and ``dynamics(P, dx [n],
      du [m], t) -> dx' [n]``, the model as a pure, differentiable function of them. ``dynamics``
      is one function object per model class, so a planner compiled for it serves every
      iteration and every seed (the parameters are traced);
    - ``saved(state) -> {name: array}``: what a run keeps of the model (:attr:`Trace.final`),
      and ``restore(saved) -> P``: the parameters again from one seed's saved arrays (what
      ``loopid evaluate`` flies a saved MPC with);
    - ``convex``: whether the learner solves a convex online problem (the regret guarantee).
    """

    init: Callable[[], Any]
    update: Callable[[Any, Transitions], Any]
    loss: Callable[[Any, Transitions], jax.Array]
    params: Callable[[Any], Any]
    dynamics: Callable[..., jax.Array]
    saved: Callable[[Any], dict]
    restore: Callable[[dict], Any]
    convex: bool = True


class FeatureState(NamedTuple):
    """The learner's state and the weights it implies, ``W [F, n]`` (solved once per update:
    the loss and the planner share it)."""

    learner: Any
    W: jax.Array


def feature_model(nominal: LinearOffsetModel, fmap: FeatureMap, learner: Learner) -> ModelClass:
    """Feature model (:mod:`loopid.models.feature_model`) with one global ``W [F, n]`` learned by
    ``learner`` on (φ(Δx, Δu) [b, F], Δx' − (A_tΔx + B_tΔu) [b, n]); a time-varying nominal is
    taken at each row's step. Saved as ``W_features``."""
    tv = nominal.time_varying

    def fitted(state) -> FeatureState:
        return FeatureState(state, learner.weights(state))

    def init():
        return fitted(learner.init(fmap.size, nominal.n))

    def update(state: FeatureState, batch: Transitions) -> FeatureState:
        t = batch.t if tv else None
        y = residual_targets(nominal, batch.dx, batch.du, batch.dx_next, t)
        return fitted(learner.update(state.learner, fmap(batch.dx, batch.du), y, batch.mask))

    def loss(state: FeatureState, batch: Transitions):
        t = batch.t if tv else None
        return F.per_sample_loss(nominal, fmap, state.W, batch.dx, batch.du, batch.dx_next, t)

    def dynamics(W, dx, du, t):
        return F.dynamics(nominal, fmap, W)(dx, du, t)

    return ModelClass(
        init, update, loss, params=lambda state: state.W, dynamics=dynamics,
        saved=lambda state: {"W_features": state.W},
        restore=lambda saved: jnp.asarray(saved["W_features"]), convex=True,
    )  # fmt: skip


def mlp_model(nominal: LinearOffsetModel, learner: MLPLearner, seed: int = 0) -> ModelClass:
    """The online MLP model (:mod:`loopid.models.mlp`). Every seed of a run starts from the same
    network (``learner.init(seed)``: :class:`~loopid.algorithms.contracts.Agent` ``init`` takes no
    key) and sees its own data. Non-convex: no regret claim. Saved as ``mlp.*`` arrays (the
    layers' weights and biases and the input/target normalisation)."""
    tv = nominal.time_varying

    def update(state, batch: Transitions):
        t = batch.t if tv else None
        return learner.update(state, batch.dx, batch.du, batch.dx_next, batch.mask, t)

    def loss(state, batch: Transitions):
        t = batch.t if tv else None
        return learner.loss(state, batch.dx, batch.du, batch.dx_next, t)

    def dynamics(state, dx, du, t):
        return learner.dynamics(state)(dx, du, t)

    def saved(state) -> dict:
        out = {}
        for i, (W, b) in enumerate(state.params):
            out[f"mlp.{i}.W"], out[f"mlp.{i}.b"] = W, b
        return out | {f"mlp.norm.{k}": v for k, v in state.norm._asdict().items()}

    def restore(arrays: dict):
        """A state whose network and normalisation are the saved ones (the rest, which the
        dynamics do not read, that of a fresh state)."""
        state = learner.init(seed)
        layers = tuple(
            (jnp.asarray(arrays[f"mlp.{i}.W"]), jnp.asarray(arrays[f"mlp.{i}.b"]))
            for i in range(len(state.params))
        )
        norm = type(state.norm)(*(jnp.asarray(arrays[f"mlp.norm.{k}"]) for k in state.norm._fields))
        return state._replace(params=layers, norm=norm)

    return ModelClass(
        lambda: learner.init(seed), update, loss, params=lambda state: state,
        dynamics=dynamics, saved=saved, restore=restore, convex=False,
    )  # fmt: skip


def holds_model(arrays: dict) -> bool:
    """Whether a cell's saved arrays hold a learned feature model or MLP (what
    :attr:`ModelClass.saved` writes: ``W_features``, ``mlp.*``); the expert's and the
    policy-gradient baseline's hold gains only."""
    return any(k == "W_features" or k.startswith("mlp.") for k in arrays)


def restore_seeds(model: ModelClass, arrays: dict):
    """Every seed's parameters, leaves ``[S, ...]``, from the seeds' saved arrays ``{name:
    [S, ...]}`` (:attr:`ModelClass.restore` seed by seed; ``shared.*`` and ``seeds`` skipped)."""
    own = {k: v for k, v in arrays.items() if not k.startswith("shared.") and k != "seeds"}
    S = len(next(iter(own.values())))
    one = [model.restore({k: v[i] for k, v in own.items()}) for i in range(S)]
    return jax.tree.map(lambda *a: jnp.stack(a), *one)


def planning_agent(model: ModelClass, plan: Callable[[Any], tuple[jax.Array, jax.Array]]) -> Agent:
    """An :class:`~loopid.algorithms.contracts.Agent` of ``model`` solved by ``plan``.

    ``plan(params) -> (K [horizon, m, n], converged)``: the policy of the model
    ``model.dynamics(params, ·)`` (:func:`ilqr_plan`). A non-finite plan gives zero gains and
    ``converged`` False (never a NaN policy); the spectral radius column is 0 (a finite-horizon
    plan has none).
    """

    def policy(state):
        K, converged = plan(model.params(state))
        ok = jnp.all(jnp.isfinite(K))
        K = jnp.where(ok, K, 0.0)
        return K, SolverInfo(converged & ok, jnp.float64(0.0))

    return Agent(
        init=model.init,
        update=model.update,
        policy=policy,
        loss=model.loss,
        policies=jax.vmap(policy),
        params=model.saved,
    )


def ilqr_plan(
    model: ModelClass,
    cost,
    x0,
    U0,
    *,
    iterations: int,
    seed_horizon: int | None = None,
    seed_alternatives=None,
) -> Callable[[Any], tuple[jax.Array, jax.Array]]:
    """``plan(params) -> (K [T, m, n], converged)`` for :func:`planning_agent`: iLQR on
    ``model.dynamics(params, ·)`` from ``x0 [n]`` over ``T`` steps from the actions ``U0 [T, m]``
    (:func:`loopid.control.plan`, at most ``iterations`` iterations; ``seed_horizon``: first an
    MPC episode of that window on the model itself gives the initial actions, trying also the
    constant actions ``seed_alternatives [k, m]`` at each re-plan), its local policy as the
    loop's gains (:func:`loopid.control.as_gains`). ``cost(Δx, Δu,
    t)`` is static (keep the same object); the parameters are traced, so one compilation serves
    every iteration and seed."""
    x0 = jnp.asarray(x0, jnp.float64)
    U0 = jnp.asarray(U0, jnp.float64)

    def plan(params):
        sol = control.plan(
            model.dynamics, cost, x0, U0, params=params, iterations=iterations,
            seed_horizon=seed_horizon, seed_alternatives=seed_alternatives,
        )  # fmt: skip
        return control.as_gains(sol), sol.converged

    return plan
