r"""Exact dynamic programming on finite MDPs, batched over leading axes.

Shapes: ``P [..., S, A, S]`` (``P[s, a, s'] = T_sa(s')``), ``C [..., S, A]`` (batch axes
broadcast against P's: one cost for many models), ``gamma`` a scalar or ``[...]``; policies
are probability tables ``pi [..., S, A]`` (a deterministic policy is one-hot; :func:`greedy`
makes one). Costs are minimised.

- :func:`evaluate`: ``V_π = (I − γ P_π)^{-1} C_π`` by a linear solve (exact up to rounding).
- :func:`value_iteration`: ``V ← min_a [C + γ P V]`` in a ``lax.while_loop`` until the sup-norm
  step ``δ`` satisfies ``γ δ / (1 − γ) ≤ tol`` (then ``‖V − V*‖_∞ ≤ tol``: contraction), or
  ``max_iter`` steps (``converged`` False). Batched natively (one einsum per step for all MDPs);
  when the batch's P is larger than the cache, the MDPs are iterated a chunk at a time (below).
- :func:`policy_iteration`: Howard's policy iteration with exact evaluation; terminates in
  finitely many steps with V*.
- :func:`occupancy`: the paper's ``D_{μ,π}(s, a) = (1−γ) Σ_t γ^{t−1} P(s_t = s, a_t = a)``.
"""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "PIResult",
    "VIResult",
    "evaluate",
    "greedy",
    "occupancy",
    "policy_iteration",
    "q_values",
    "value_iteration",
]


class VIResult(NamedTuple):
    """Value iteration's result: ``V [..., S]``, ``Q [..., S, A]`` (one more backup of V),
    the greedy deterministic ``policy [..., S, A]`` (one-hot), ``iterations`` (int32, shared
    by the batch), ``residual [...]`` (the last sup-norm step) and ``converged [...]``."""

    V: jax.Array
    Q: jax.Array
    policy: jax.Array
    iterations: jax.Array
    residual: jax.Array
    converged: jax.Array


class PIResult(NamedTuple):
    """Policy iteration's result: ``V [..., S]`` of the final ``policy [..., S, A]`` (one-hot),
    ``iterations`` and ``converged`` (the policy was stable)."""

    V: jax.Array
    policy: jax.Array
    iterations: jax.Array
    converged: jax.Array


def _check(P, C):
    """Shapes of P and C; C's batch axes may broadcast against P's. Returns the batch shape."""
    if P.ndim < 3 or P.shape[-1] != P.shape[-3]:
        raise ValueError(f"P must have shape [..., S, A, S], got {P.shape}")
    try:
        if C.shape[-2:] != P.shape[-3:-1]:
            raise ValueError
        return np.broadcast_shapes(P.shape[:-3], C.shape[:-2])
    except ValueError:
        raise ValueError(
            f"C must have shape [..., {P.shape[-3]}, {P.shape[-2]}] broadcasting "
            f"with P {P.shape}, got {C.shape}"
        ) from None


def _gamma(gamma, batch):
    g = jnp.asarray(gamma, dtype=jnp.float64)
    if g.ndim and np.broadcast_shapes(g.shape, batch) != batch:
        raise ValueError(f"gamma must be a scalar or have shape {batch}, got {g.shape}")
    return g


def q_values(P, C, V, gamma) -> jax.Array:
    """One Bellman backup ``Q = C + γ P V``: ``[..., S, A]``."""
    g = jnp.asarray(gamma, dtype=jnp.float64)
    return C + g[..., None, None] * jnp.einsum("...sat,...t->...sa", P, V)


def greedy(Q: jax.Array) -> jax.Array:
    """The deterministic policy ``argmin_a Q`` as one-hot ``[..., S, A]`` (lowest index on ties)."""
    return jax.nn.one_hot(jnp.argmin(Q, axis=-1), Q.shape[-1], dtype=jnp.float64)


def _policy_matrices(P, C, pi):
    P_pi = jnp.einsum("...sa,...sat->...st", pi, P)
    C_pi = jnp.sum(pi * C, axis=-1)
    return P_pi, C_pi


def evaluate(P, C, gamma, pi) -> jax.Array:
    """Exact ``V_π [..., S]`` of the (stochastic) policy ``pi [..., S, A]``: the linear solve
    ``(I − γ P_π) V = C_π`` with ``P_π[s, s'] = Σ_a π(a|s) P[s, a, s']``."""
    P, C, pi = (jnp.asarray(x, dtype=jnp.float64) for x in (P, C, pi))
    batch = _check(P, C)
    if pi.shape[-2:] != C.shape[-2:] or np.broadcast_shapes(batch, pi.shape[:-2]) != batch:
        raise ValueError(
            f"pi must have shape {(*batch, *C.shape[-2:])} ([..., S, A]), got {pi.shape}"
        )
    g = _gamma(gamma, batch)
    return _evaluate(P, C, g, pi)


@jax.jit
def _evaluate(P, C, g, pi):
    P_pi, C_pi = _policy_matrices(P, C, pi)
    S = P.shape[-1]
    M = jnp.eye(S, dtype=jnp.float64) - g[..., None, None] * P_pi
    return jnp.linalg.solve(M, C_pi[..., None])[..., 0]


def occupancy(P, mu, gamma, pi) -> jax.Array:
    """The discounted state-action distribution ``D_{μ,π} [..., S, A]`` (sums to 1):
    ``d = (1 − γ) μᵀ (I − γ P_π)^{-1}``, ``D(s, a) = d(s) π(a|s)``."""
    P, mu, pi = (jnp.asarray(x, dtype=jnp.float64) for x in (P, mu, pi))
    if P.ndim < 3 or mu.shape != P.shape[:-3] + P.shape[-1:] or pi.shape != P.shape[:-1]:
        raise ValueError(
            f"occupancy needs P [..., S, A, S], mu [..., S], pi [..., S, A]; got "
            f"{P.shape}, {mu.shape}, {pi.shape}"
        )
    g = _gamma(gamma, P.shape[:-3])
    return _occupancy(P, mu, g, pi)


@jax.jit
def _occupancy(P, mu, g, pi):
    P_pi = jnp.einsum("...sa,...sat->...st", pi, P)
    S = P.shape[-1]
    M = jnp.eye(S, dtype=jnp.float64) - g[..., None, None] * P_pi
    d = jnp.linalg.solve(jnp.swapaxes(M, -1, -2), mu[..., None])[..., 0]
    d = jnp.maximum((1.0 - g[..., None]) * d, 0.0)
    return d[..., None] * pi


def value_iteration(P, C, gamma, *, tol: float = 1e-12, max_iter: int = 100_000, V0=None):
    """Optimal values of every MDP in the batch by value iteration (module doc).

    Every MDP takes the same number of backups ``K`` (``iterations``): the first count at which
    every MDP of the batch meets ``γ δ / (1 − γ) ≤ tol``, or ``max_iter``.

    A backup reads all of P (8·S·A·S bytes per MDP), so it is memory-bound. When the batch's P
    exceeds ``_CACHE_BYTES`` (and P itself carries the batch axes), the MDPs are split into chunks
    that fit in the cache and each chunk is iterated on its own while its P stays cached, instead
    of streaming the whole batch's P from memory at every backup (on the 2-core development
    machine, 32 MiB L3: 20 MDPs with S = 500, A = 8 are 320 MB; one is 16 MB). The chunks are
    brought to a common ``K`` in rounds (each chunk runs until it has reached the largest count
    of the last round and meets the rule; repeat until all counts agree), so ``iterations`` and
    ``converged`` are those of the whole-batch loop, and V and ``residual`` too up to rounding
    (the matrix-vector products differ in shape: 1e-15 on values of order 10).

    Args:
      P: ``[..., S, A, S]``; C: ``[..., S, A]``; gamma: scalar or ``[...]`` in (0, 1).
      tol: target sup-norm error on V* (the stopping rule guarantees it).
      max_iter: cap on the number of backups.
      V0: optional warm start ``[..., S]`` (default zeros).

    Returns:
      :class:`VIResult`.
    """
    P, C = jnp.asarray(P, dtype=jnp.float64), jnp.asarray(C, dtype=jnp.float64)
    batch = _check(P, C)
    if not tol > 0:
        raise ValueError(f"tol must be > 0, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    g = _gamma(gamma, batch)
    S, A = P.shape[-1], P.shape[-2]
    shape = (*batch, S)
    V0 = jnp.zeros(shape, jnp.float64) if V0 is None else jnp.asarray(V0, jnp.float64)
    if V0.shape != shape:
        raise ValueError(f"V0 must have shape {shape}, got {V0.shape}")
    n = math.prod(batch)
    chunk, padded = _chunking(n, 8 * S * A * S)
    if P.shape[:-3] != batch or chunk >= n:
        return _value_iteration(P, C, g, V0, tol, max_iter)
    flat = (
        P.reshape(n, S, A, S),
        jnp.broadcast_to(C, (*batch, S, A)).reshape(n, S, A),
        jnp.broadcast_to(g, batch).reshape(n),
        V0.reshape(n, S),
    )
    V, delta, k = _value_iteration_chunked(*flat, tol, max_iter, chunk, padded)
    V, delta = V.reshape(shape), delta.reshape(batch)
    Q = _q_values(P, C, V, g)
    threshold = tol * (1.0 - g) / g
    return VIResult(V, Q, greedy(Q), k, delta, delta <= threshold)


_CACHE_BYTES = 16 * 2**20
"""The P bytes one chunk of :func:`value_iteration` may hold: half the development machine's
32 MiB L3 (the rest is for V, Q, C and other processes)."""


def _chunking(n: int, mdp_bytes: int) -> tuple[int, int]:
    """(chunk size, padded batch size) for ``n`` MDPs of ``mdp_bytes`` of P each: the whole
    batch when it fits in ``_CACHE_BYTES``; else the largest divisor of ``n`` that fits, or, if
    that is under half of what fits, as many as fit with ``n`` padded up to a multiple."""
    fit = max(1, _CACHE_BYTES // mdp_bytes)
    if n <= fit:
        return n, n
    divisor = max(d for d in range(1, fit + 1) if n % d == 0)
    if 2 * divisor > fit:
        return divisor, n
    return fit, -(-n // fit) * fit


def _backup(P, C, g, V):
    """``V ← min_a C + γ P V`` and the sup-norm step ``δ [...]``."""
    V_new = jnp.min(q_values(P, C, V, g), axis=-1)
    return V_new, jnp.max(jnp.abs(V_new - V), axis=-1)


def _vi_core(P, C, g, V0, tol, max_iter):
    g_b = jnp.broadcast_to(g, V0.shape[:-1])
    threshold = tol * (1.0 - g_b) / g_b  # γδ/(1−γ) ≤ tol

    def cond(carry):
        _, delta, k = carry
        return (k < max_iter) & jnp.any(delta > threshold)

    def body(carry):
        V, _, k = carry
        return *_backup(P, C, g, V), k + 1

    inf = jnp.full(V0.shape[:-1], jnp.inf, jnp.float64)
    V, delta, k = jax.lax.while_loop(cond, body, (V0, inf, jnp.int32(0)))
    Q = q_values(P, C, V, g)
    return VIResult(V, Q, greedy(Q), k, delta, delta <= threshold)


_value_iteration = jax.jit(_vi_core, static_argnums=(4, 5))
_q_values = jax.jit(q_values)


def _vi_chunked_core(P, C, g, V0, tol, max_iter, chunk, padded):
    """The whole-batch loop of :func:`_vi_core` run a chunk at a time (``value_iteration``'s
    doc). ``P [n, S, A, S]``, ``C [n, S, A]``, ``g [n]``, ``V0 [n, S]``; the batch is padded to
    ``padded`` with copies of the last MDP (they meet the rule when it does). Returns
    ``V [n, S]``, ``δ [n]`` and the common count ``K``.

    Chunk ``i`` is rows ``[i·chunk, (i+1)·chunk)`` of P, sliced in place (``lax.dynamic_slice``)
    only when the chunk has work to do: P is never reshaped to ``[m, chunk, ...]`` (that cost a
    layout copy of the whole batch's P, 320 MB in ``benchmarks/mdp.py``, at every call)."""
    n = V0.shape[0]
    if padded > n:
        pad = lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], padded - n, axis=0)])  # noqa: E731
        P, C, g, V0 = pad(P), pad(C), pad(g), pad(V0)
    m = padded // chunk
    threshold = tol * (1.0 - g) / g  # [padded]: γδ/(1−γ) ≤ tol
    rows = lambda x, i: jax.lax.dynamic_slice_in_dim(x, i * chunk, chunk)  # noqa: E731

    def more(K, t, delta, k):
        """A chunk needs another backup: fewer than K, or short of the rule and not capped."""
        return (k < K) | ((k < max_iter) & jnp.any(delta > t))

    def one_chunk(i, state):
        """Bring chunk ``i`` to at least K backups that meet the rule (or are capped)."""
        _, delta, k, K = state
        t_i = rows(threshold, i)

        def run(state):
            V, delta, k, K = state
            P_i, C_i, g_i = rows(P, i), rows(C, i), rows(g, i)

            def body(carry):
                V, _, k = carry
                return *_backup(P_i, C_i, g_i, V), k + 1

            V_i, d_i, k_i = jax.lax.while_loop(
                lambda c: more(K, t_i, c[1], c[2]), body, (rows(V, i), rows(delta, i), k[i])
            )
            V = jax.lax.dynamic_update_slice_in_dim(V, V_i, i * chunk, 0)
            delta = jax.lax.dynamic_update_slice_in_dim(delta, d_i, i * chunk, 0)
            return V, delta, k.at[i].set(k_i), K

        return jax.lax.cond(more(K, t_i, rows(delta, i), k[i]), run, lambda s: s, state)

    def round_cond(carry):
        _, _, k, started = carry
        return ~started | jnp.any(k != jnp.max(k))

    def round_body(carry):
        V, delta, k, _ = carry
        V, delta, k, _ = jax.lax.fori_loop(0, m, one_chunk, (V, delta, k, jnp.max(k)))
        return V, delta, k, jnp.bool_(True)

    init = (V0, jnp.full(padded, jnp.inf, jnp.float64), jnp.zeros(m, jnp.int32), jnp.bool_(False))
    V, delta, k, _ = jax.lax.while_loop(round_cond, round_body, init)
    return V[:n], delta[:n], k[0]


_value_iteration_chunked = jax.jit(_vi_chunked_core, static_argnums=(4, 5, 6, 7))


def policy_iteration(P, C, gamma, *, max_iter: int = 1000) -> PIResult:
    """Howard's policy iteration: exact evaluation (linear solve), greedy improvement, stop when
    the policy is stable (switching only on a strict improvement > 1e-12, so ties cannot
    cycle). Batched over leading axes (stops when every MDP is stable)."""
    P, C = jnp.asarray(P, dtype=jnp.float64), jnp.asarray(C, dtype=jnp.float64)
    batch = _check(P, C)
    g = _gamma(gamma, batch)
    return _policy_iteration(P, jnp.broadcast_to(C, (*batch, *C.shape[-2:])), g, max_iter)


def _pi_core(P, C, g, max_iter):
    def improve(pi, V):
        Q = q_values(P, C, V, g)
        current = jnp.sum(pi * Q, axis=-1)
        better = jnp.min(Q, axis=-1) < current - 1e-12
        return jnp.where(better[..., None], greedy(Q), pi), jnp.any(better)

    def cond(carry):
        _, changed, k = carry
        return changed & (k < max_iter)

    def body(carry):
        pi, _, k = carry
        pi, changed = improve(pi, _evaluate(P, C, g, pi))
        return pi, changed, k + 1

    pi0 = greedy(C)
    pi, changed, k = jax.lax.while_loop(cond, body, (pi0, jnp.bool_(True), jnp.int32(0)))
    return PIResult(_evaluate(P, C, g, pi), pi, k, ~changed)


_policy_iteration = jax.jit(_pi_core, static_argnums=(3,))
