"""The model-based agent of the helicopter experiments: linear offset model + learner + LQR.

The model class is :class:`loopid.models.LinearOffsetModel` in error coordinates,
features ``z = [Δx; Δu]`` and residual targets ``y = Δx' − (AΔx + BΔu)``; any online learner
(:mod:`loopid.learners`) fits ``W = [A' B']ᵀ``. The optimal-control solver:

- time-invariant model: steady-state LQR for the affine model (:func:`loopid.control.dlqr_affine`);
  when it does not converge (the initial hover model is not stabilisable) the policy is the first
  gain of the finite-horizon LQR over the task horizon, and ``converged`` is False.
- time-varying model: finite-horizon time-varying LQR (:func:`loopid.control.tvlqr`) with the
  task's Q at every step and as the terminal cost.

Policies are ``K: [horizon, m, n]`` with ``u_t = −K_t Δx_t``.
"""

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from loopid.algorithms.contracts import Agent, SolverInfo, Transitions
from loopid.control.lqr_affine import dlqr_affine_unchecked
from loopid.control.tvlqr import tvlqr
from loopid.learners import Learner, indexed, touched_weights
from loopid.models.linear_offset import (
    LinearOffsetModel,
    features,
    per_sample_loss,
    residual_targets,
    to_matrices,
)


def finite_horizon_gains(A, B, Q, R, horizon: int) -> jax.Array:
    """Gains ``K [horizon, m, n]`` of the finite-horizon LQR on ``A [(T,) n, n]``,
    ``B [(T,) n, m]`` (no time axis: the same at every step), stage cost ``xᵀQx + uᵀRu`` and
    terminal cost ``xᵀQx`` (u_t = −K_t x_t)."""
    return tvlqr(A, B, Q, R, Q_T=Q, T=horizon).K


def solve_in_batch() -> bool:
    """Whether the time-invariant LQR of every seed is solved as one batch
    (:func:`batched_gains`): on an accelerator, where a seed-by-seed loop syncs with the host on
    every ``while`` trip of every seed; not on a CPU, where the loop runs the finite-horizon
    fallback only for the seeds that need it and is faster (7x at hover's first iteration)."""
    return jax.default_backend() != "cpu"


def batched_gains(A, B, Q, R, horizon: int) -> tuple[jax.Array, SolverInfo]:
    """The time-invariant solve of every lane at once: ``A [S, n, n]``, ``B [S, n, m]`` (affine
    models, the constant last), ``Q``, ``R`` shared; returns ``K [S, m, n]`` and the lanes'
    :class:`SolverInfo` (``[S]`` leaves).

    Each lane's gain is the steady-state LQR (:func:`loopid.control.dlqr_affine`, batched: its
    doubling and refinement loops take one convergence test per trip for the whole batch), and
    where that did not converge the first gain of the finite-horizon LQR over ``horizon`` steps,
    as :func:`linear_agent`'s ``policy`` gives one lane. The fallback runs, for every lane and
    then selected, only when some lane needs it (``lax.cond`` on ``any``); a non-finite gain
    becomes 0."""
    sol = dlqr_affine_unchecked(A, B, Q, R)
    failed = ~sol.converged

    def with_fallback():
        first = jax.vmap(lambda a, b: finite_horizon_gains(a, b, Q, R, horizon)[0])(A, B)
        return jnp.where(failed[:, None, None], first, sol.K)

    K = jax.lax.cond(jnp.any(failed), with_fallback, lambda: sol.K)
    K = jnp.where(jnp.all(jnp.isfinite(K), axis=(1, 2))[:, None, None], K, 0.0)
    return K, SolverInfo(sol.converged, sol.spectral_radius)


class LinearAgentState(NamedTuple):
    """The learner's state and the model it implies, ``W = learner.weights(learner)``, solved once
    per update (a time-varying model: one ridge solve per step the update's rows reached,
    :func:`loopid.learners.touched_weights`; the loss and the policy share it)."""

    learner: Any
    W: jax.Array


def linear_agent(
    model: LinearOffsetModel, learner: Learner, Q: jax.Array, R: jax.Array, horizon: int
) -> Agent:
    """An :class:`~loopid.algorithms.contracts.Agent` for a (time-varying) linear offset model.

    ``model.A``: ``[n, n]`` (time-invariant) or ``[horizon, n, n]`` (time-varying: one offset pair
    per step, the learner is :func:`loopid.learners.indexed` over the steps).
    """
    tv = model.time_varying
    if tv and model.A.shape[0] != horizon:
        raise ValueError(
            f"time-varying model has {model.A.shape[0]} steps, the horizon is {horizon}"
        )
    n, m = model.n, model.m
    fitter = indexed(learner, horizon) if tv else learner
    Q = jnp.asarray(Q, jnp.float64)
    R = jnp.asarray(R, jnp.float64)

    def data(batch: Transitions):
        t = batch.t if tv else None
        z = features(batch.dx, batch.du)
        y = residual_targets(model, batch.dx, batch.du, batch.dx_next, t)
        return z, y, t

    def fitted(learner_state) -> LinearAgentState:
        return LinearAgentState(learner_state, fitter.weights(learner_state))

    def init():
        return fitted(fitter.init(n + m, n))

    def update(state: LinearAgentState, batch: Transitions) -> LinearAgentState:
        z, y, t = data(batch)
        if tv:  # only the steps this batch reached change: solve those again, keep the rest
            new = fitter.update(state.learner, z, y, batch.mask, index=t)
            return LinearAgentState(new, touched_weights(learner, new, state.W, t, batch.mask))
        return fitted(fitter.update(state.learner, z, y, batch.mask))

    def loss(state: LinearAgentState, batch: Transitions):
        t = batch.t if tv else None
        return per_sample_loss(model, state.W, batch.dx, batch.du, batch.dx_next, t)

    def policy(state: LinearAgentState):
        A, B = to_matrices(model, state.W)
        if tv:
            K = finite_horizon_gains(A, B, Q, R, horizon)
            ok = jnp.all(jnp.isfinite(K))
            K = jnp.where(ok, K, 0.0)
            return K, SolverInfo(ok, jnp.float64(0.0))
        sol = dlqr_affine_unchecked(A, B, Q, R)
        K = jax.lax.cond(  # the fallback is solved only where dlqr failed (both under vmap)
            sol.converged, lambda: sol.K, lambda: finite_horizon_gains(A, B, Q, R, horizon)[0]
        )
        K = jnp.where(jnp.all(jnp.isfinite(K)), K, 0.0)
        return jnp.broadcast_to(K, (horizon, m, n)), SolverInfo(sol.converged, sol.spectral_radius)

    def policies(states: LinearAgentState):
        # time-varying: no branch to skip, so one batched tvlqr. Time-invariant: on a CPU seed
        # by seed, so the fallback's cond runs only for the seeds whose dlqr failed; on an
        # accelerator all seeds at once (a loop over seeds would sync with the host on every
        # while trip of every seed)
        if tv:
            return jax.vmap(policy)(states)
        if not solve_in_batch():
            return jax.lax.map(policy, states)
        A, B = jax.vmap(lambda W: to_matrices(model, W))(states.W)
        K, info = batched_gains(A, B, Q, R, horizon)
        return jnp.broadcast_to(K[:, None], (K.shape[0], horizon, m, n)), info

    def params(state: LinearAgentState) -> dict:
        """The learned offsets ``W = [A' B']ᵀ`` (the model is the nominal plus them)."""
        return {"W": state.W}

    return Agent(init, update, policy, loss, policies, params)
