r"""A neural model: the nominal plus a small MLP, trained online with optax (Adam).

In error coordinates Δx [n] (the last entry is the constant 1) and control changes Δu [m]::

    Δx' ≈ AΔx + BΔu + [g_θ(v); 0],      v = [Δx_{:-1}; Δu]  [k = n−1+m],
    g_θ(v) = μ_y + σ_y ⊙ (L_θ ∘ tanh ∘ ... ∘ tanh ∘ L_θ)((v − μ_v)/σ_v)  [n−1],

with the nominal (A, B) of a :class:`~loopid.models.linear_offset.LinearOffsetModel` and the
constant coordinate's residual fixed to 0. μ, σ are the mean and standard deviation of the
buffered inputs and residual targets, recomputed at every update. Hidden layers start from
LeCun-normal weights, the output layer from zero, so before any data the model is the nominal.

Online learning (optax style, pure functions of a fixed-shape :class:`MLPState`): ``update``
appends a batch of rows to a ring buffer of ``capacity`` rows (masked rows are not written; the
oldest rows are overwritten once it is full), then runs ``steps`` Adam steps in one
``lax.scan``, each on ``batch`` rows drawn uniformly with replacement from the filled slots
(``batch=None``: the whole buffer, masked). Training minimises the mean over rows of
||(y − g_θ(v))/σ_y||², y = Δx' − (AΔx + BΔu) without its last entry. Everything jits and vmaps
over seeds (``jax.vmap(learner.init)(seeds)``).

No regret claim: the loss is non-convex in θ and Adam on a replay buffer is not a no-regret
algorithm, so the paper's guarantee (Ross & Bagnell 2012, section 4) does not apply. The loop
still reports the online loss, :attr:`MLPLearner.loss` of the current model on each new batch
before it is learned from, so it can be compared with the convex model classes.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from loopid.models.linear_offset import (
    LinearOffsetModel,
    _check_model,
    _nominal,
    residual_targets,
    sum_last,
)

__all__ = ["MLPLearner", "MLPState", "Normalizer", "mlp_learner"]


class Normalizer(NamedTuple):
    """Input and target statistics of the buffered rows: v_mean, v_std [k]; y_mean, y_std [n−1]."""

    v_mean: jax.Array
    v_std: jax.Array
    y_mean: jax.Array
    y_std: jax.Array


class MLPState(NamedTuple):
    """The online MLP learner's state (fixed shapes; ``capacity`` rows of buffer).

    Attributes:
      params: ((W₁ [k, h₁], b₁ [h₁]), ..., (W_L [h, n−1], b_L [n−1])).
      opt: optax Adam state of ``params``.
      norm: :class:`Normalizer` of the buffer at the last update.
      v: buffered inputs [capacity, k]; y: buffered residual targets [capacity, n−1].
      size: filled slots (slots 0..size−1 hold data), int32; head: next slot written, int32.
      seen: rows learned from in total, float64.
      key: PRNG key for the minibatches.
      train_loss: mean training loss (normalised units) of the last update's last step.
    """

    params: Any
    opt: Any
    norm: Normalizer
    v: jax.Array
    y: jax.Array
    size: jax.Array
    head: jax.Array
    seen: jax.Array
    key: jax.Array
    train_loss: jax.Array


class MLPLearner(NamedTuple):
    """``init(seed_or_key) -> MLPState``; ``update(state, dx, du, dx_next, mask=None, t=None)``;
    ``loss(state, dx, du, dx_next, t=None) -> [b]`` (||Δx' − prediction||² per row);
    ``predict(state, dx, du, t=None) -> [b, n]``; ``dynamics(state) -> f(dx [n], du [m], t)``;
    ``params(state) -> dict``."""

    init: Callable[..., MLPState]
    update: Callable[..., MLPState]
    loss: Callable[..., jax.Array]
    predict: Callable[..., jax.Array]
    dynamics: Callable[[MLPState], Callable]
    params: Callable[[MLPState], dict]
    name: str = "mlp"


def _positive_int(name: str, v) -> int:
    if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
        raise ValueError(f"{name} must be a positive integer, got {v!r}")
    return int(v)


def _forward(params, norm: Normalizer, v):
    """g_θ(v): v [..., k] -> [..., n−1]."""
    h = (v - norm.v_mean) / norm.v_std
    for W, b in params[:-1]:
        h = jnp.tanh(h @ W + b)
    W, b = params[-1]
    return norm.y_mean + norm.y_std * (h @ W + b)


def _inputs(dx, du):
    return jnp.concatenate([dx[..., :-1], du], axis=-1)


def _statistics(v, y, filled, size) -> Normalizer:
    w = filled.astype(jnp.float64)[:, None]
    count = jnp.maximum(size, 1).astype(jnp.float64)

    def mean_std(a):
        mean = (w * a).sum(0) / count
        var = (w * (a - mean) ** 2).sum(0) / count
        std = jnp.where(size > 0, jnp.maximum(jnp.sqrt(var), 1e-6), 1.0)
        return mean, std

    (vm, vs), (ym, ys) = mean_std(v), mean_std(y)
    return Normalizer(vm, vs, ym, ys)


def mlp_learner(
    model: LinearOffsetModel,
    hidden: Sequence[int] = (64, 64),
    lr: float = 1e-3,
    steps: int = 200,
    capacity: int = 10_000,
    batch: int | None = 256,
) -> MLPLearner:
    """The online MLP learner around a time-invariant or time-varying nominal ``model``.

    Args:
      model: the nominal (A [(T,) n, n], B [(T,) n, m]); rows carry ``t`` [b] when time-varying.
      hidden: hidden layer widths (tanh), each >= 1; ``()`` is an affine residual.
      lr: Adam's learning rate, > 0.
      steps: Adam steps per update, >= 1.
      capacity: ring-buffer rows, >= 1.
      batch: rows per Adam step, >= 1, or ``None`` for the whole (masked) buffer.
    """
    _check_model(model)
    if isinstance(hidden, str | bytes) or not isinstance(hidden, Sequence):
        raise ValueError(f"hidden must be a sequence of positive integers, got {hidden!r}")
    hidden = tuple(_positive_int("hidden size", h) for h in hidden)
    try:
        lr = float(lr)
    except (TypeError, ValueError):
        raise ValueError(f"lr must be a real number > 0, got {lr!r}") from None
    if not (lr > 0 and math.isfinite(lr)):
        raise ValueError(f"lr must be a finite number > 0, got {lr!r}")
    steps = _positive_int("steps", steps)
    capacity = _positive_int("capacity", capacity)
    if batch is not None:
        batch = _positive_int("batch", batch)
    n, m = model.n, model.m
    k = n - 1 + m
    tv = model.time_varying
    A = jnp.asarray(model.A, dtype=jnp.float64)
    B = jnp.asarray(model.B, dtype=jnp.float64)
    optimizer = optax.adam(lr)
    widths = (k, *hidden, n - 1)

    @jax.jit
    def init(seed) -> MLPState:
        """A fresh state from an integer seed or a typed PRNG key (jitted; vmap over seeds)."""
        key = jnp.asarray(seed) if isinstance(seed, jax.Array) else seed
        if not (isinstance(key, jax.Array) and jnp.issubdtype(key.dtype, jax.dtypes.prng_key)):
            key = jax.random.key(seed)
        keys = jax.random.split(key, len(widths))
        params = []
        for i, (a, b) in enumerate(itertools.pairwise(widths)):
            last = i == len(widths) - 2
            W = jax.random.normal(keys[i], (a, b), jnp.float64) / math.sqrt(a)
            params.append((jnp.zeros((a, b)) if last else W, jnp.zeros((b,))))
        params = tuple(params)
        norm = Normalizer(jnp.zeros(k), jnp.ones(k), jnp.zeros(n - 1), jnp.ones(n - 1))
        return MLPState(
            params=params,
            opt=optimizer.init(params),
            norm=norm,
            v=jnp.zeros((capacity, k)),
            y=jnp.zeros((capacity, n - 1)),
            size=jnp.zeros((), jnp.int32),
            head=jnp.zeros((), jnp.int32),
            seen=jnp.zeros((), jnp.float64),
            key=keys[-1],
            train_loss=jnp.zeros((), jnp.float64),
        )

    def _check(dx, du, dx_next=None, mask=None, t=None):
        dx = jnp.asarray(dx, dtype=jnp.float64)
        du = jnp.asarray(du, dtype=jnp.float64)
        if dx.ndim != 2 or dx.shape[1] != n or du.shape != (dx.shape[0], m):
            raise ValueError(f"dx, du must be [b, {n}], [b, {m}], got {dx.shape}, {du.shape}")
        b = dx.shape[0]
        if dx_next is not None:
            dx_next = jnp.asarray(dx_next, dtype=jnp.float64)
            if dx_next.shape != (b, n):
                raise ValueError(f"dx_next must have shape [{b}, {n}], got {dx_next.shape}")
        if mask is None:
            keep = jnp.ones((b,), bool)
        else:
            keep = jnp.asarray(mask)
            if keep.shape != (b,):
                raise ValueError(f"mask must have shape [{b}], got {keep.shape}")
            keep = keep if keep.dtype == jnp.bool_ else keep != 0
        if tv:
            if t is None:
                raise ValueError(
                    "t [b] (each row's time step) is required for a time-varying model"
                )
            t = jnp.asarray(t)
            if t.shape != (b,) or not jnp.issubdtype(t.dtype, jnp.integer):
                raise ValueError(f"t must be an integer array of shape [{b}], got {t.shape}")
        else:
            t = None
        return dx, du, dx_next, keep, t

    def _batch_loss(params, norm, v, y, w):
        err = (y - _forward(params, norm, v)) / norm.y_std
        return (w * sum_last(err**2)).sum() / jnp.maximum(w.sum(), 1.0)

    @jax.jit
    def _update(state: MLPState, v_new, y_new, keep):
        # ring buffer: kept row j goes to slot (head + rank_j) mod capacity; only the last
        # `capacity` kept rows of the batch are written, so no slot is written twice
        rank = jnp.cumsum(keep, dtype=jnp.int32) - 1
        kept = keep.sum(dtype=jnp.int32)
        write = keep & (rank >= kept - capacity)
        slot = jnp.where(write, (state.head + rank) % capacity, capacity)
        v = state.v.at[slot].set(v_new, mode="drop")
        y = state.y.at[slot].set(y_new, mode="drop")
        size = jnp.minimum(state.size + kept, capacity)
        head = (state.head + kept) % capacity
        filled = jnp.arange(capacity, dtype=jnp.int32) < size
        norm = _statistics(v, y, filled, size)

        def step(carry, key):
            params, opt = carry
            if batch is None:
                vb, yb, w = v, y, filled.astype(jnp.float64)
            else:
                idx = jax.random.randint(key, (batch,), 0, jnp.maximum(size, 1))
                vb, yb = v[idx], y[idx]
                w = jnp.broadcast_to((size > 0).astype(jnp.float64), (batch,))
            value, grads = jax.value_and_grad(_batch_loss)(params, norm, vb, yb, w)
            with jax.numpy_dtype_promotion("standard"):  # optax mixes weak floats and int32
                updates, opt = optimizer.update(grads, opt, params)
            return (optax.apply_updates(params, updates), opt), value

        key, sub = jax.random.split(state.key)
        (params, opt), losses = jax.lax.scan(
            step, (state.params, state.opt), jax.random.split(sub, steps)
        )
        return MLPState(
            params,
            opt,
            norm,
            v,
            y,
            size,
            head,
            state.seen + kept.astype(jnp.float64),
            key,
            losses[-1],
        )

    def update(state: MLPState, dx, du, dx_next, mask=None, t=None) -> MLPState:
        dx, du, dx_next, keep, t = _check(dx, du, dx_next, mask, t)
        y = residual_targets(model, dx, du, dx_next, t)[:, :-1]
        return _update(state, _inputs(dx, du), y, keep)

    @jax.jit
    def _predict_rows(state, dx, du, t):
        g = _forward(state.params, state.norm, _inputs(dx, du))
        offset = jnp.concatenate([g, jnp.zeros((*g.shape[:-1], 1))], axis=-1)
        return _nominal(A, B, dx, du, t) + offset

    def predict(state: MLPState, dx, du, t=None) -> jax.Array:
        dx, du, _, _, t = _check(dx, du, t=t)
        return _predict_rows(state, dx, du, t)

    def loss(state: MLPState, dx, du, dx_next, t=None) -> jax.Array:
        dx, du, dx_next, _, t = _check(dx, du, dx_next, t=t)
        return sum_last((dx_next - _predict_rows(state, dx, du, t)) ** 2)

    def dynamics(state: MLPState) -> Callable:
        """f(Δx [n], Δu [m], t) = A_t Δx + B_t Δu + [g_θ(v); 0] with the last entry set to 1."""

        def f(dx, du, t=0):
            At, Bt = (A[t], B[t]) if tv else (A, B)
            g = _forward(state.params, state.norm, _inputs(dx, du))
            out = At @ dx + Bt @ du + jnp.concatenate([g, jnp.zeros((1,))])
            return out.at[-1].set(1.0)

        return f

    def params(state: MLPState) -> dict:
        return {"params": state.params, "norm": state.norm}

    name = f"mlp(hidden={hidden}, lr={lr:g}, steps={steps}, capacity={capacity}, batch={batch})"
    return MLPLearner(init, update, loss, predict, dynamics, params, name)
