"""The receding-horizon pieces of model-predictive control, pure and jittable: one plan on a
learned model (:func:`plan_core`), the cheapest of several (:func:`best_plan`), the warm start
from the previous plan (:func:`warm_start`), a plan's local feedback (:func:`local_feedback`),
and a whole MPC episode as one ``lax.scan`` (:func:`mpc_episode` -> :class:`MPCRollout`). Their
public faces are :mod:`loopid.control.mpc` and :func:`loopid.control.plan`, whose seed runs an
episode on the model itself; problem and conventions: :mod:`loopid.control.plan`.

MPC (receding horizon; e.g. Tassa, Erez & Todorov 2012): every ``every`` steps, plan over the
next H steps from the current state, warm-started from the previous plan's policy shifted by
s = ``every`` steps, its last action repeated open loop::

    U0_j = U_{j+s} + K_{j+s} X_{j+s},  K0_j = K_{j+s}     (j + s < H)
    U0_j = U_{H-1},                    K0_j = 0           (otherwise)

(the closed loop ``u_j = U0_j − K0_j x`` iLQR starts from), and between re-plans apply the plan's
local feedback ``u = U_τ − K_τ(x − X_τ) − α k_τ`` (τ = steps since the plan). Shapes: ``x [n]``;
a plan ``X [H+1, n]``, ``U [H, m]``, ``K [H, m, n]``, ``k [H, m]``; alternatives
``U_alt [A, H, m]``, planned besides the warm start, the cheapest plan on the model kept.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from loopid.control.ilqr import ILQRSolution, ilqr_core
from loopid.control.plan_settings import Settings

__all__ = [
    "MPCRollout",
    "best_plan",
    "local_feedback",
    "mpc_episode",
    "plan_core",
    "warm_start",
]


def plan_core(dynamics, cost, iterations, params, x0, U0, K0, t0, s: Settings) -> ILQRSolution:
    """Jittable core of :func:`loopid.control.plan`: iLQR on ``dynamics(params, ·)`` with the
    clock started at ``t0`` (no checks)."""
    dyn = lambda x, u, t: dynamics(params, x, u, t0 + t)  # noqa: E731
    stage = lambda x, u, t: cost(x, u, t0 + t)  # noqa: E731
    return ilqr_core(dyn, stage, x0, U0, K0, s.alphas, iterations, s.tol, s.atol, *s[3:])


def best_plan(model, cost, iterations, params, x, U_init, K_init, t0, s, U_alt):
    """The plan from (U_init, K_init) or, with ``U_alt [A, H, m]``, the cheapest of it and the
    A plans from the open-loop actions ``U_alt`` (all planned at once, vmapped)."""
    if U_alt is None:
        return plan_core(model, cost, iterations, params, x, U_init, K_init, t0, s)
    U0 = jnp.concatenate([U_init[None], U_alt])
    K0 = jnp.concatenate([K_init[None], jnp.zeros((U_alt.shape[0], *K_init.shape))])
    one = lambda U0, K0: plan_core(model, cost, iterations, params, x, U0, K0, t0, s)  # noqa: E731
    sols = jax.vmap(one)(U0, K0)
    i = jnp.argmin(jnp.where(jnp.isfinite(sols.cost), sols.cost, jnp.inf))
    return jax.tree.map(lambda a: a[i], sols)


def warm_start(X, U, K, shift):
    """The previous plan's policy (X [H+1, n], U [H, m], K [H, m, n]) advanced by ``shift``
    steps as iLQR's initial closed loop ``u_j = U0_j − K0_j x``: U0_j = U_{j+s} + K_{j+s} X_{j+s}
    and K0_j = K_{j+s} while j + s < H, then U_{H-1} open loop (K0 = 0). ``shift`` may be traced.
    """
    H = U.shape[0]
    j = jnp.arange(H) + shift
    inside = j < H
    i = jnp.minimum(j, H - 1)
    U0 = jnp.where(inside[:, None], U[i] + jnp.einsum("hmn,hn->hm", K[i], X[i]), U[H - 1])
    K0 = jnp.where(inside[:, None, None], K[i], 0.0)
    return U0, K0


def local_feedback(sol: ILQRSolution, x, tau, alpha):
    """The plan's local feedback ``u = U_τ − K_τ(x − X_τ) − α k_τ`` at ``x [n]``, τ = ``tau``
    steps since the plan was made."""
    return sol.U[tau] - sol.K[tau] @ (x - sol.X[tau]) - alpha * sol.k[tau]


class MPCRollout(NamedTuple):
    """Result of :func:`~loopid.control.mpc.mpc_rollout`.

    Attributes:
        X: ``[T+1, n]`` states of the true system.
        U: ``[T, m]`` actions applied.
        costs: ``[T]`` stage costs ``cost(X_t, U_t, t)``.
        iterations: ``[P]`` iLQR iterations of each of the P = ⌈T / every⌉ plans.
        converged: ``[P]`` whether each plan converged within its ``iterations``.
    """

    X: Array
    U: Array
    costs: Array
    iterations: Array
    converged: Array


def mpc_episode(
    true, model, cost, T, every, iterations, params, x0, U0, alpha, s, start=0, U_alt=None
):
    """Jittable core of :func:`~loopid.control.mpc.mpc_rollout` (``true=None``: fly the model
    itself); the clock starts at ``start``."""
    H, m = U0.shape
    n = x0.shape[0]
    blocks = -(-T // every)
    if true is None:
        true = lambda x, u, t: model(params, x, u, t)  # noqa: E731

    def block(carry, b):
        x, U_init, K_init = carry
        t0 = start + b * every
        sol = best_plan(model, cost, iterations, params, x, U_init, K_init, t0, s, U_alt)

        def inner(x, j):
            u = local_feedback(sol, x, j, alpha)
            return true(x, u, t0 + j), (x, u)

        x_end, (Xs, Us) = jax.lax.scan(inner, x, jnp.arange(every))
        U_next, K_next = warm_start(sol.X, sol.U, sol.K, every)
        return (x_end, U_next, K_next), (Xs, Us, sol.iterations, sol.converged)

    K0 = jnp.zeros((H, m, n), jnp.float64)
    (x_end, _, _), (Xs, Us, its, conv) = jax.lax.scan(block, (x0, U0, K0), jnp.arange(blocks))
    Xs = Xs.reshape(blocks * every, n)
    Us = Us.reshape(blocks * every, m)
    X = jnp.concatenate([Xs, x_end[None]])[: T + 1]  # blocks·every >= T steps were run
    U = Us[:T]
    costs = jax.vmap(cost)(X[:-1], U, start + jnp.arange(T))
    return MPCRollout(X, U, costs, its, conv)
