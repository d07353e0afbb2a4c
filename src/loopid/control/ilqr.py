"""Iterative LQR (Gauss-Newton trajectory optimisation) with LM regularisation and a line search.

Problem::

    minimise_U  J(U) = Σ_{t=0}^{T-1} cost(x_t, u_t, t) + cost(x_T, 0, T)
    subject to  x_{t+1} = dynamics(x_t, u_t, t),   x_0 given,

with ``dynamics(x, u, t) -> [n]``, ``cost(x, u, t) -> scalar`` (the terminal cost is the stage
cost at t = T with u = 0), ``X [T+1, n]``, ``U [T, m]``.

One iteration (Li & Todorov 2004; Tassa, Erez & Todorov 2012):

1. Quadratise about the nominal (X, U): A_t = ∂f/∂x, B_t = ∂f/∂u by ``jax.jacfwd``; gradients and
   Hessians of the cost by ``jax.grad``/``jax.hessian`` (:func:`quadratize`). Second derivatives
   of the dynamics are dropped (Gauss-Newton).
2. Backward pass: :mod:`loopid.control.tvlqr`'s recursion on the deviations (δx, δu) with
   Q = ½ℓ_xx, q = ½ℓ_x, R = ½ℓ_uu, r = ½ℓ_u, M = ½ℓ_xu and μI added to H_uu
   (Levenberg-Marquardt). A failed Cholesky of H_uu + μI counts as a failed iteration.
3. Forward pass for every α in ``alphas`` at once (``vmap``):
   u_t = U_t - K_t(x_t - X_t) - α k_t, x_{t+1} = f(x_t, u_t, t). The α with the lowest finite
   cost is taken if that cost is below J; otherwise the iteration fails.
4. μ: on success μ ← μ / ``mu_factor`` (0 once below ``mu_min``); on failure
   μ ← max(μ·``mu_factor``, ``mu_min``).

Stopping rules (``lax.while_loop``, at most ``max_iter`` iterations):

* converged when, with μ = 0, the predicted decrease of the full step, 2Σh_uᵀk - Σkᵀ H_uu k, is
  at most ``tol``·``|J|`` + ``atol`` (with a positive definite H_uu), or when an accepted step
  lowers J by at most ``tol``·``|J|`` + ``atol``;
* not converged when μ exceeds ``mu_max`` (no descent found) or after ``max_iter`` iterations.

The cost never increases between iterations (only decreasing steps are accepted). After the loop
one more backward pass with μ = 0 at the returned (X, U) gives the gains: the local policy is
u_t = U_t - K_t(x_t - X_t) - k_t, in the coordinates the dynamics use (k ≈ 0 at convergence).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from loopid.control._checks import check_finite, shape_of
from loopid.control.tvlqr import backward_recursion

__all__ = ["ILQRSolution", "Quadratization", "ilqr", "quadratize", "trajectory_cost"]

DEFAULT_ALPHAS = tuple(0.5**i for i in range(11))


class ILQRSolution(NamedTuple):
    """Result of :func:`ilqr`.

    Attributes:
        X: ``[T+1, n]`` optimised states.
        U: ``[T, m]`` optimised actions.
        K: ``[T, m, n]`` feedback gains of the final backward pass (policy above).
        k: ``[T, m]`` feedforward of the final backward pass (≈ 0 at convergence).
        cost: scalar, J at (X, U).
        iterations: int, iterations run (accepted or not).
        converged: bool, a convergence rule of the module docstring fired.
        cost_history: ``[max_iter + 1]`` J after each iteration (entry 0 = initial cost); entries
            after the stop repeat the final cost.
    """

    X: Array
    U: Array
    K: Array
    k: Array
    cost: Array
    iterations: Array
    converged: Array
    cost_history: Array


class Quadratization(NamedTuple):
    """Local model along (X, U): ``A [T, n, n]``, ``B [T, n, m]``, cost gradients ``lx [T, n]``,
    ``lu [T, m]``, Hessians ``lxx [T, n, n]``, ``luu [T, m, m]``, ``lxu [T, n, m]``, and the
    terminal ``lx_T [n]``, ``lxx_T [n, n]``."""

    A: Array
    B: Array
    lx: Array
    lu: Array
    lxx: Array
    luu: Array
    lxu: Array
    lx_T: Array
    lxx_T: Array


def trajectory_cost(cost, X: Array, U: Array) -> Array:
    """J = Σ_t cost(X_t, U_t, t) + cost(X_T, 0, T) for ``X [T+1, n]``, ``U [T, m]``."""
    T = U.shape[0]
    stage = jax.vmap(cost)(X[:-1], U, jnp.arange(T))
    return jnp.sum(stage) + cost(X[-1], jnp.zeros_like(U[0]), jnp.asarray(T))


def quadratize(dynamics, cost, X: Array, U: Array) -> Quadratization:
    """Jacobians of the dynamics and gradients/Hessians of the cost along (X, U) (autodiff)."""
    T = U.shape[0]
    ts = jnp.arange(T)
    A, B = jax.vmap(jax.jacfwd(dynamics, argnums=(0, 1)))(X[:-1], U, ts)
    lx, lu = jax.vmap(jax.grad(cost, argnums=(0, 1)))(X[:-1], U, ts)
    (lxx, lxu), (_, luu) = jax.vmap(jax.hessian(cost, argnums=(0, 1)))(X[:-1], U, ts)
    u0 = jnp.zeros_like(U[0])
    lx_T = jax.grad(cost)(X[-1], u0, jnp.asarray(T))
    lxx_T = jax.hessian(cost)(X[-1], u0, jnp.asarray(T))
    return Quadratization(A, B, lx, lu, lxx, luu, lxu, lx_T, lxx_T)


def _backward_pass(quad: Quadratization, mu):
    T, n, _ = quad.A.shape
    c = jnp.zeros((T, n), quad.A.dtype)
    return backward_recursion(
        quad.A,
        quad.B,
        c,
        0.5 * quad.lxx,
        0.5 * quad.lx,
        0.5 * quad.luu,
        0.5 * quad.lu,
        0.5 * quad.lxu,
        0.5 * quad.lxx_T,
        0.5 * quad.lx_T,
        mu,
    )


def _forward(dynamics, cost, x0, X, U, K, k, alpha):
    T = U.shape[0]

    def body(x, inputs):
        x_ref, u_ref, K_t, k_t, t = inputs
        u = u_ref - K_t @ (x - x_ref) - alpha * k_t
        x_next = dynamics(x, u, t)
        return x_next, (x_next, u)

    _, (Xn, Un) = jax.lax.scan(body, x0, (X[:-1], U, K, k, jnp.arange(T)))
    Xn = jnp.concatenate([x0[None], Xn], axis=0)
    J = trajectory_cost(cost, Xn, Un)
    return Xn, Un, jnp.where(jnp.isfinite(J), J, jnp.inf)


def _initial_rollout(dynamics, x0, U0, K0):
    """Closed loop u_t = U0_t - K0_t x_t (K0 = 0: open loop); returns (X, U applied)."""
    T = U0.shape[0]

    def body(x, inputs):
        u0, K_t, t = inputs
        u = u0 - K_t @ x
        x_next = dynamics(x, u, t)
        return x_next, (x_next, u)

    _, (X, U) = jax.lax.scan(body, x0, (U0, K0, jnp.arange(T)))
    return jnp.concatenate([x0[None], X], axis=0), U


class _State(NamedTuple):
    X: Array
    U: Array
    J: Array
    mu: Array
    it: Array
    done: Array
    converged: Array
    history: Array


def ilqr_core(
    dynamics, cost, x0, U0, K0, alphas, max_iter, tol, atol, mu_init, mu_min, mu_max, mu_factor
):
    """Jittable core of :func:`ilqr` (no checks; the settings as arrays, ``K0 [T, m, n]`` given);
    ``dynamics``/``cost`` are Python callables closed over. Returns :class:`ILQRSolution`."""
    X0, U0 = _initial_rollout(dynamics, x0, U0, K0)
    J0 = trajectory_cost(cost, X0, U0)
    forward = jax.vmap(partial(_forward, dynamics, cost, x0), in_axes=(None, None, None, None, 0))

    def body(s: _State) -> _State:
        quad = quadratize(dynamics, cost, s.X, s.U)
        sol, aux = _backward_pass(quad, s.mu)
        predicted = 2.0 * aux.hu_k - aux.kHk  # decrease of the full step under the local model
        small = aux.ok & (predicted <= tol * jnp.abs(s.J) + atol)
        Xs, Us, Js = forward(s.X, s.U, sol.K, sol.k, alphas)
        i = jnp.argmin(Js)
        J_new = Js[i]
        at_optimum = small & (s.mu == 0.0)  # a damped (μ > 0) step proves nothing: lower μ
        accept = aux.ok & (J_new < s.J) & ~at_optimum
        tiny_gain = accept & (s.J - J_new <= tol * jnp.abs(s.J) + atol)
        converged = at_optimum | tiny_gain
        mu_up = jnp.maximum(s.mu * mu_factor, mu_min)
        mu_down = jnp.where(s.mu / mu_factor < mu_min, 0.0, s.mu / mu_factor)
        mu = jnp.where(accept | small, mu_down, mu_up)
        X = jnp.where(accept, Xs[i], s.X)
        U = jnp.where(accept, Us[i], s.U)
        J = jnp.where(accept, J_new, s.J)
        it = s.it + 1
        done = converged | (mu > mu_max)
        history = jax.lax.dynamic_update_index_in_dim(s.history, J, it, 0)
        return _State(X, U, J, mu, it, done, converged, history)

    def cond(s: _State):
        return (~s.done) & (s.it < max_iter)

    history0 = jnp.full((max_iter + 1,), J0)
    init = _State(
        X0,
        U0,
        J0,
        jnp.asarray(mu_init, jnp.float64),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(False),
        jnp.asarray(False),
        history0,
    )
    s = jax.lax.while_loop(cond, body, init)
    # entries after the stop repeat the final cost
    idx = jnp.arange(max_iter + 1, dtype=jnp.int32)
    history = jnp.where(idx <= s.it, s.history, s.J)
    final, _ = _backward_pass(quadratize(dynamics, cost, s.X, s.U), 0.0)
    return ILQRSolution(s.X, s.U, final.K, final.k, s.J, s.it, s.converged, history)


def check_settings(alphas, mu_init, mu_min, mu_max, mu_factor) -> Array:
    """The line search's step sizes as a float64 vector, and the Levenberg-Marquardt schedule
    checked: one-line ``ValueError`` naming a bad value (also for :func:`loopid.control.plan`)."""
    alphas = jnp.asarray(alphas, jnp.float64)
    if alphas.ndim != 1 or alphas.shape[0] < 1:
        raise ValueError(f"alphas must be a non-empty 1-D sequence, got shape {alphas.shape}")
    if not (mu_factor > 1.0 and 0.0 <= mu_init and 0.0 < mu_min < mu_max):
        raise ValueError(
            f"need mu_factor > 1, mu_init >= 0, 0 < mu_min < mu_max; got mu_factor={mu_factor}, "
            f"mu_init={mu_init}, mu_min={mu_min}, mu_max={mu_max}"
        )
    return alphas


_ilqr_jit = jax.jit(ilqr_core, static_argnames=("dynamics", "cost", "max_iter"))


def ilqr(
    dynamics,
    cost,
    x0,
    U0,
    *,
    K0=None,
    max_iter: int = 100,
    tol: float = 1e-9,
    atol: float = 0.0,
    alphas=DEFAULT_ALPHAS,
    mu_init: float = 0.0,
    mu_min: float = 1e-6,
    mu_max: float = 1e10,
    mu_factor: float = 10.0,
) -> ILQRSolution:
    """iLQR from the initial actions ``U0``; see the module docstring for the method and stops.

    Args:
        dynamics: ``dynamics(x [n], u [m], t) -> [n]``, JAX-differentiable.
        cost: ``cost(x [n], u [m], t) -> scalar``; at t = T it is called with u = 0.
        x0: ``[n]`` start state.
        U0: ``[T, m]`` initial actions.
        K0: optional ``[T, m, n]`` initial feedback: the first nominal is the closed loop
            u_t = U0_t - K0_t x_t (default: open loop). Start from a stabilising policy (e.g. a
            :func:`tvlqr` on the linearisation about the target) when the open loop diverges.
        max_iter: iteration cap.
        tol, atol: relative / absolute decrease below which the iteration stops as converged.
        alphas: line-search step sizes, all tried at once (default 1, 1/2, ..., 1/1024).
        mu_init, mu_min, mu_max, mu_factor: Levenberg-Marquardt schedule for μ (added to H_uu).

    Returns:
        :class:`ILQRSolution`.

    ``dynamics`` and ``cost`` are static for ``jit``: pass the same function objects to reuse the
    compiled code. Checks (shapes through ``jax.eval_shape``) also run on tracers, so the
    function can be called inside ``jit``/``vmap``/``scan``.
    """
    sx = shape_of("x0", x0)
    sU = shape_of("U0", U0)
    if len(sx) != 1:
        raise ValueError(f"x0 must have shape [n], got shape {sx}")
    if len(sU) != 2 or sU[0] < 1:
        raise ValueError(f"U0 must have shape [T, m] with T >= 1, got shape {sU}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive int, got {max_iter!r}")
    alphas = check_settings(alphas, mu_init, mu_min, mu_max, mu_factor)
    if K0 is not None and shape_of("K0", K0) != (sU[0], sU[1], sx[0]):
        raise ValueError(f"K0 must have shape {(sU[0], sU[1], sx[0])}, got {shape_of('K0', K0)}")
    check_finite("x0", x0)
    check_finite("U0", U0)
    check_finite("K0", K0)
    x0 = jnp.asarray(x0, jnp.float64)
    U0 = jnp.asarray(U0, jnp.float64)
    if K0 is None:
        K0 = jnp.zeros((sU[0], sU[1], sx[0]), jnp.float64)
    K0 = jnp.asarray(K0, jnp.float64)
    t0 = jnp.asarray(0)
    x_next = jax.eval_shape(dynamics, x0, U0[0], t0)
    if x_next.shape != sx:
        raise ValueError(f"dynamics(x0, U0[0], 0) must have shape {sx}, got {x_next.shape}")
    c = jax.eval_shape(cost, x0, U0[0], t0)
    if c.shape != ():
        raise ValueError(f"cost(x0, U0[0], 0) must be a scalar, got shape {c.shape}")
    return _ilqr_jit(
        dynamics,
        cost,
        x0,
        U0,
        K0,
        alphas,
        max_iter,
        tol,
        atol,
        mu_init,
        mu_min,
        mu_max,
        mu_factor,
    )
