r"""The funnel's nominal model: four readings of "the given hover model", which the paper
leaves open.

The paper (Ross & Bagnell 2012, section 6, footnote) fits, per time step t of the funnel,

    Δx_{t+1} = (A + A'_t)Δx_t + (B + B'_t)Δu_t + x*_{t+1} − x*_t,   A, B the given hover model,

and every approach starts from the nominal (A'_t = B'_t = 0). Here Δx_t = x_t ⊖ x*_t [21] are
the error coordinates relative to the target (:func:`loopid.systems.helicopter.to_error`; the
last entry is the constant 1, so the last column of a matrix is its affine offset), Δu_t [4] the
control change, inc_t = x*_{t+1} ⊖ x*_t [21] the target's own increment (constant entry 0;
``target_increment``; the paper's "+" is our "−" because its Δx is target minus state), and
A, B = ``linearize(x_hover, x_hover)`` [21, 21], [21, 4] the true simulator linearised about the
hover trim. Readings (``kind``), each a time-varying model A_t [T, 21, 21], B_t [T, 21, 4],
T = len(target) − 1 (599 with pads, 399 without):

- ``"spec"`` (the paper's formula; the ``literal`` preset): Δx_{t+1} = AΔx_t + BΔu_t − inc_t,
  i.e. A_t = A with inc_t subtracted from its affine column, B_t = B
  (:func:`loopid.models.linear_offset.time_varying_nominal`).
- ``"no-increment"`` (the public reproduction vvanirudh/AgnosticSysID, ``fit_model.py``, which
  centres each step on its target with no increment term): Δx_{t+1} = AΔx_t + BΔu_t; A_t = A,
  B_t = B at every t.
- ``"drift"``: the spec plus the hover model's own drift along the moving target,

      Δx_{t+1} = AΔx_t + BΔu_t − inc_t + (A − I)c_t,   c_t = x*_t ⊖ x_hover (constant entry 0).

  Derivation: in hover-error coordinates e = x ⊖ x_hover the hover model is
  e_{t+1} = Ae_t + BΔu_t. Write the state relative to the target as Δx_t ≈ e_t − c_t (exact
  outside the attitude entries, first order in them). Then
  Δx_{t+1} ≈ e_{t+1} − c_{t+1} = A(Δx_t + c_t) + BΔu_t − c_{t+1}
  = AΔx_t + BΔu_t − (c_{t+1} − c_t) + (A − I)c_t, and c_{t+1} − c_t ≈ x*_{t+1} ⊖ x*_t = inc_t.
  The spec drops (A − I)c_t, i.e. it applies the hover model to the offset from the target as if
  the target were the hover trim: e.g. Δx's u_prev entries hold the whole trim (the funnel
  target has u_prev = 0), which the spec reads as 0.4 of extra collective. The attitude part is
  first order only: c_t's attitude entry is the target's whole yaw (``|e|`` up to 1 at ψ = π), far
  outside where the hover linearisation holds, which is what "heading" repairs.
- ``"heading"``: the same construction about the hover trim turned to the target's yaw ψ_t, so
  that the velocity-attitude coupling (Δx's attitude entries live in the target's body frame,
  velocity in the world frame) points the right way on the circle:

      h_t = hover trim with q = q_yaw(ψ_t) ⊗ q_hover, position = x*_t's, velocity = rates = 0,
      A_t, B_t = linearize(h_t, h_t),
      Δx_{t+1} = A_tΔx_t + B_tΔu_t − inc_t + (A_t − I)c_t,   c_t = x*_t ⊖ h_t.

  q_yaw(ψ_t) = ``[0, 0, q*_z, q*_w] / |·|`` (the yaw part of q*_t; exactly q*_t on the level funnel
  target, and continuous in sign like the target, so c_t's attitude entry stays the small
  conj(q_hover) part, −sin(φ_hover/2) about x, at every turn). h_t is an exact trim (a yaw turns
  the balanced force about the vertical), so linearize's own drift column is ≈ 0. The position
  is irrelevant to the result (the step is translation-equivariant, so A_t does not depend on it
  and (A_t − I) has zero position columns); taking x*_t's leaves c_t no position entry. The
  velocity and rates stay at the trim's 0 ("the hover model", and a trim): the target's velocity
  and yaw rate enter through c_t (drag and rate damping are linear in them). The derivation is
  the drift one with e = x ⊖ h_t and x*_{t+1} ⊖ h_t ≈ c_t + inc_t. This reading rests on
  inference, not on a source; checked numerically on the expert's padded flight (velocity RMS, see
  :func:`prediction_errors`): 0.0714 as defined; 0.0714 also with linearize(h_t, h_{t+1}) and
  the exact x*_{t+1} ⊖ h_{t+1} in place of c_t + inc_t; 0.0721 linearised at the target's
  velocity and rates instead; 0.375 without the (A_t − I)c_t term.

:func:`prediction_errors` measures a nominal's one-step prediction error along the expert's
flight (the figures the readings are compared by).
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.models.linear_offset import LinearOffsetModel, time_varying_nominal
from loopid.systems import helicopter
from loopid.systems.base import Task

__all__ = [
    "FUNNEL_NOMINALS",
    "PredictionErrors",
    "funnel_nominal",
    "heading_states",
    "prediction_errors",
]

#: The readings of the funnel's nominal model, the literal one first.
FUNNEL_NOMINALS = ("spec", "no-increment", "drift", "heading")
VELOCITY = helicopter.NED_DOT  # indices 8:11 of the error coordinates


def _increments(target: jax.Array) -> jax.Array:
    """inc_t = x*_{t+1} ⊖ x*_t [T, 21] (constant entry 0): the target's own motion."""
    return jax.vmap(helicopter.target_increment)(target[:-1], target[1:])


def _offsets(x_ref: jax.Array, target: jax.Array) -> jax.Array:
    """c_t = x*_t ⊖ x_ref [T, 21] (constant entry 0) for x_ref [21] or [T, 21], target [T, 21]."""
    x_ref = jnp.broadcast_to(x_ref, target.shape)
    return jax.vmap(lambda xs, xr: helicopter.to_error(xs, xr).at[20].set(0.0))(target, x_ref)


def heading_states(target: jax.Array) -> jax.Array:
    """h_t [T, 21]: the hover trim turned to the yaw of x*_t, at x*_t's position (module docstring).

    ``target`` [T, 21]; q(h_t) = q_yaw(ψ_t) ⊗ q_hover with q_yaw = ``[0, 0, q*_z, q*_w] / |·|``.
    """
    hover = helicopter.hover_target()
    qz, qw = target[:, 19], target[:, 20]
    norm = jnp.sqrt(qz * qz + qw * qw)
    zero = jnp.zeros_like(qz)
    q_yaw = jnp.stack([zero, zero, qz / norm, qw / norm])  # [4, T]
    q = helicopter.quat_mul(q_yaw, hover[helicopter.QUAT][:, None]).T  # [T, 4]
    base = jnp.broadcast_to(hover, target.shape)
    return base.at[:, helicopter.NED].set(target[:, helicopter.NED]).at[:, helicopter.QUAT].set(q)


@jax.jit
def _drift_increments(A: jax.Array, target: jax.Array) -> jax.Array:
    """inc_t − (A − I)c_t [T, 21] with c_t = x*_t ⊖ x_hover: the drift reading's increment."""
    c = _offsets(helicopter.hover_target(), target[:-1])
    n = A.shape[0]
    return _increments(target) - c @ (A - jnp.eye(n)).T


@jax.jit
def _heading_model(target: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(A_t [T, 21, 21], B_t [T, 21, 4]) of the heading reading."""
    H = heading_states(target[:-1])
    A, B = jax.vmap(helicopter.linearize)(H, H)
    n = A.shape[-1]
    c = _offsets(H, target[:-1])
    drift = jnp.einsum("tij,tj->ti", A - jnp.eye(n), c)
    offset = (_increments(target) - drift).at[:, -1].set(0.0)
    return A.at[:, :, -1].add(-offset), B


def funnel_nominal(kind: str, task: Task) -> LinearOffsetModel:
    """The funnel's nominal model of reading ``kind`` (module docstring), for ``task`` (its target).

    Returns a time-varying :class:`LinearOffsetModel`: A [T, 21, 21], B [T, 21, 4] with
    T = ``task.horizon`` = len(target) − 1 (the funnel's initial model in
    :func:`loopid.systems.helicopter.plant.helicopter_nominal_model`). Raises
    ValueError for an unknown ``kind``.
    """
    if kind not in FUNNEL_NOMINALS:
        raise ValueError(
            f"funnel_nominal must be one of {', '.join(FUNNEL_NOMINALS)}, got {kind!r}"
        )
    target = jnp.asarray(task.target, dtype=jnp.float64)
    if target.ndim != 2 or target.shape[0] < 2 or target.shape[1] != helicopter.N_STATE:
        raise ValueError(f"task.target must have shape [T+1, 21] with T >= 1, got {target.shape}")
    if kind == "heading":
        return LinearOffsetModel(*_heading_model(target))
    hover = helicopter.hover_target()
    A, B = helicopter.linearize(hover, hover)
    if kind == "spec":
        inc = _increments(target)
    elif kind == "no-increment":
        inc = jnp.zeros((target.shape[0] - 1, helicopter.N_STATE))
    else:  # drift
        inc = _drift_increments(A, target)
    return time_varying_nominal(A, B, inc)


# ----------------------------------------------------------------------------- prediction errors
class PredictionErrors(NamedTuple):
    """One-step prediction errors of a nominal along the expert's flight.

    Every field is an RMS over time steps t (and seeds) and the three velocity entries (error
    coordinates 8:11, m/s) together, i.e. sqrt(mean over t, seed, entry of v²):

    - ``prediction``: v = (A_tΔx_t + B_tΔu_t) − Δx_{t+1}, the nominal's one-step error.
    - ``true_step``: v = x_{t+1} − x_t, the velocity change the helicopter actually makes in one
      step (= Δx_{t+1} − Δx_t + x*_{t+1} − x*_t on these entries): the scale to compare with.
    - ``error_step``: v = Δx_{t+1} − Δx_t, the change of the tracking error (with pads dominated
      by the target's two velocity jumps of 5ω ≈ 6.3 m/s where the circles start and stop).
    """

    prediction: float
    true_step: float
    error_step: float


@jax.jit
def _fly(K, target, x0, noise):
    """The expert u_t = −K_tΔx_t on the true simulator: (Δx [T+1, 21], Δu [T, 4], X [T+1, 21])."""

    def body(x, inp):
        Kt, xs, n = inp
        dx = helicopter.to_error(x, xs)
        du = -Kt @ dx
        return helicopter.step(x, du, n), (x, dx, du)

    xT, (X, dX, dU) = jax.lax.scan(body, x0, (K, target[:-1], noise))
    dX = jnp.concatenate([dX, helicopter.to_error(xT, target[-1])[None]])
    return dX, dU, jnp.concatenate([X, xT[None]])


@jax.jit
def _velocity_residuals(A, B, K, target, x0, noise):
    """Per seed (noise [S, T, 6]): the three velocity residuals [S, 3, T', 3] (module docstring)."""

    def one(n):
        dX, dU, X = _fly(K, target, x0, n)
        pred = jnp.einsum("tij,tj->ti", A, dX[:-1]) + jnp.einsum("tij,tj->ti", B, dU)
        v = VELOCITY
        return jnp.stack([(pred - dX[1:])[:, v], (X[1:] - X[:-1])[:, v], (dX[1:] - dX[:-1])[:, v]])

    return jax.vmap(one)(noise)


def prediction_errors(
    model: LinearOffsetModel,
    task: Task,
    K_expert,
    *,
    seeds=tuple(range(10)),
    noise: bool = True,
    steps=None,
) -> PredictionErrors:
    """One-step prediction error of a time-varying nominal along the expert's flight.

    Flies the expert ``u_t = −K_t Δx_t`` (``K_expert`` [T, 4, 21]) from ``task.x0`` on the true
    simulator (:func:`loopid.systems.helicopter.step`) over the whole target, once per seed with
    the task's process noise (std ``task.noise_std``, row t from ``noise_sequence(key(seed))``),
    or once without noise (``noise=False``; ``seeds`` is then ignored), and scores the model's
    prediction of each recorded transition (Δx_t, Δu_t) -> Δx_{t+1}; see
    :class:`PredictionErrors`. ``steps`` (an index or slice over t = 0..T−1; default all)
    restricts the RMS to some time steps, e.g. ``slice(100, 500)`` for the circles of the padded
    funnel.

    Measured (the iLQR expert; noise std 0.1 or none moves no figure by more than 0.001), as
    spec / no-increment / drift / heading, true step; an independent computation gave
    0.49 / 0.47 / 0.31 / 0.09, 0.18:

    - padded funnel, all 599 steps: 0.445 / 0.454 / 0.251 / 0.071, 0.186;
    - padded funnel, the circles (``slice(100, 499)``): 0.495 / 0.438 / 0.307 / 0.087, 0.224;
    - ``pads=False`` (399 steps): 0.505 / 0.447 / 0.319 / 0.103, 0.239.

    That computation's true step of 0.18 is the raw velocity change x_{t+1} − x_t over the whole
    padded flight (``error_step``, Δx_{t+1} − Δx_t, is 0.207 there: the target's two velocity
    jumps).
    """
    A = jnp.asarray(model.A, dtype=jnp.float64)
    B = jnp.asarray(model.B, dtype=jnp.float64)
    target = jnp.asarray(task.target, dtype=jnp.float64)
    T = target.shape[0] - 1
    n, m = helicopter.N_STATE, helicopter.N_ACTION
    if A.shape != (T, n, n) or B.shape != (T, n, m):
        raise ValueError(f"model must be time-varying over T = {T}, got A {A.shape}, B {B.shape}")
    K = jnp.asarray(K_expert, dtype=jnp.float64)
    if K.shape != (T, m, n):
        raise ValueError(f"K_expert must have shape {(T, m, n)}, got {K.shape}")
    if noise:
        seeds = [int(s) for s in np.atleast_1d(np.asarray(seeds))]
        if not seeds:
            raise ValueError("seeds must name at least one seed")
        keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
        W = jax.vmap(lambda k: helicopter.noise_sequence(k, T, task.noise_std))(keys)
    else:
        W = jnp.zeros((1, T, helicopter.N_NOISE))
    V = _velocity_residuals(A, B, K, target, jnp.asarray(task.x0, dtype=jnp.float64), W)
    t = np.atleast_1d(np.arange(T)[steps if steps is not None else slice(None)])
    V = np.asarray(V)[:, :, t]  # [S, 3, T', 3]
    rms = np.sqrt(np.mean(V**2, axis=(0, 2, 3)))
    return PredictionErrors(*(float(r) for r in rms))
