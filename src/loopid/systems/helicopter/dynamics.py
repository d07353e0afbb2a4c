"""Abbeel & Coates' 21-state helicopter: dynamics, quaternions, targets, error coords.

Pure JAX in float64; every function is jittable and vmappable over any batch (``jax.vmap``).

State ``x`` [21], in this order: ``u_prev`` [4] (aileron, elevator, rudder, collective applied in
the last step), ``du_prev`` [4] (the change applied in the last step), ``ned_dot`` [3] (m/s,
world North-East-Down), ``ned`` [3] (m, down positive), ``pqr`` [3] (rad/s, body rates; body x
forward, y right, z down), ``q`` [4] (attitude, scalar last ``[x, y, z, w]``, body to world).
Action: the control change ``du`` [4]. Noise ``n`` [6] = (world force n_F [N], body torque
n_τ [N·m]), added to the force and torques of the step.

One explicit Euler step (dt = 0.05 s), every right-hand side evaluated at the old state:

    c' = u_prev + du;  ned' = ned + dt·ned_dot;  q' = q ⊗ rotvec_to_quat(dt·pqr)
    (u, v, w) = R(q)ᵀ ned_dot
    F_b = m·(−0.048 u, −0.57 − 0.12 v, 1.21 − 0.0005 w − 27.5 c'_4)
    ned_dot' = ned_dot + dt·(R(q) F_b + (0, 0, m g) + n_F)/m
    pqr' = pqr + dt·(I·(b + D·pqr + G·c'_{1:3}) + n_τ)/I

with m = 5 kg, g = 9.81 m/s², I = 0.3 kg·m² about each axis, b = (−0.086, 0.015, −0.139),
D = (−3.47, −3.06, −2.58), G = (13.20, −9.21, 14.84). No saturation, no gyroscopic term.
The quaternion is never normalised or sign-flipped, so q and the target stay continuous, and the
error coordinates' round trip keeps the scalar part of conj(q*) ⊗ q positive.

Error coordinates relative to a target x* (what models and controllers see), ``dx`` [21]:
dx[0:17] = x[0:17] − x*[0:17]; dx[17:20] = vector part of conj(q*) ⊗ q; dx[20] = 1.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.systems.base import Dynamics

DT = 0.05
N_STATE = 21
N_ACTION = 4
N_NOISE = 6

U_PREV = slice(0, 4)
DU_PREV = slice(4, 8)
NED_DOT = slice(8, 11)
NED = slice(11, 14)
PQR = slice(14, 17)
QUAT = slice(17, 21)

GRAVITY = 9.81  # m/s²
MASS = 5.0  # kg
INERTIA = 0.3  # kg·m², each body axis
# Body force per unit mass (m/s²):
#   (DRAG_U·u, SIDE_FORCE + DRAG_V·v, LIFT + DRAG_W·w + COLLECTIVE·c4)
DRAG_U, DRAG_V, DRAG_W = -0.048, -0.12, -0.0005
SIDE_FORCE = -0.57
LIFT = 1.21
COLLECTIVE = -27.5
# Torque per unit inertia (rad/s²): TORQUE_BIAS + RATE_DAMPING·pqr + CONTROL_GAIN·(c1, c2, c3)
TORQUE_BIAS = np.array([-0.086, 0.015, -0.139])
RATE_DAMPING = np.array([-3.47, -3.06, -2.58])
CONTROL_GAIN = np.array([13.20, -9.21, 14.84])

FUNNEL_RADIUS = 5.0  # m
FUNNEL_STEPS_PER_CIRCLE = 100
FUNNEL_CIRCLES = 4
FUNNEL_PAD = 100


# ----------------------------------------------------------------------------- quaternions
# Every function below takes its vectors along the leading axis and broadcasts over any trailing
# batch axes (``q [4, *B]``): a single state is ``[21]``; a column batch ``[21, B]`` keeps each
# component contiguous over the batch, which is how the test rollouts of all seeds run at once
# (:mod:`loopid.algorithms.plant`). ``jax.vmap`` over a leading batch axis works as usual.


def _column(v, like: jax.Array) -> jax.Array:
    """The constant vector ``v [k]`` shaped ``[k, 1, …]`` to broadcast against ``like [*, *B]``."""
    v = jnp.asarray(v)
    return v.reshape(v.shape + (1,) * (like.ndim - 1))


def quat_mul(p: jax.Array, q: jax.Array) -> jax.Array:
    """Hamilton product p ⊗ q of quaternions stored scalar last ``[x, y, z, w]``; ``[4, *B]``."""
    px, py, pz, pw = p[0], p[1], p[2], p[3]
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    return jnp.stack(
        [
            pw * qx + qw * px + (py * qz - pz * qy),
            pw * qy + qw * py + (pz * qx - px * qz),
            pw * qz + qw * pz + (px * qy - py * qx),
            pw * qw - (px * qx + py * qy + pz * qz),
        ]
    )


def quat_conj(q: jax.Array) -> jax.Array:
    """Conjugate ``[−x, −y, −z, w]`` (the inverse of a unit quaternion); ``[4, *B]``."""
    return jnp.concatenate([-q[:3], q[3:]])


def rotvec_to_quat(r: jax.Array) -> jax.Array:
    """Unit quaternion ``[4, *B]`` of the rotation vector r ``[3, *B]`` (rad), for
    the attitude update of :func:`step`.

    Vector part sin(``|r|``/2)·r/``|r|`` (r/2 when ``|r|`` < 1e-4), scalar part
    sqrt(1 − ``|vec|²``). The small-angle branch uses a safe norm inside ``jnp.where``, so
    gradients are finite at r = 0.
    """
    n2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    small = n2 < 1e-8  # |r| < 1e-4
    n = jnp.sqrt(jnp.where(small, 1.0, n2))
    vec = jnp.where(small, 0.5, jnp.sin(0.5 * n) / n) * r
    w = jnp.sqrt(1.0 - (vec[0] * vec[0] + vec[1] * vec[1] + vec[2] * vec[2]))
    return jnp.concatenate([vec, w[None]])


def quat_to_rotmat(q: jax.Array) -> jax.Array:
    """Rotation matrix ``[3, 3, *B]`` of the unit quaternion q ``[4, *B]`` (scalar last), body to
    world."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)]),
            jnp.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)]),
            jnp.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]),
        ]
    )


# ----------------------------------------------------------------------------- dynamics
def step(x: jax.Array, du: jax.Array, noise: jax.Array) -> jax.Array:
    """One explicit Euler step (written out in the module docstring): x ``[21, *B]``,
    du ``[4, *B]``, noise ``[6, *B]`` -> x_next ``[21, *B]`` (trailing batch axes optional; see
    "quaternions" above).

    ``noise`` = (world force n_F [N], body torque n_τ [N·m]), already scaled by the task's std.
    """
    u = x[U_PREV] + du
    ned_dot, ned, pqr, q = x[NED_DOT], x[NED], x[PQR], x[QUAT]
    q_next = quat_mul(q, rotvec_to_quat(DT * pqr))
    Rm = quat_to_rotmat(q)
    uvw = [Rm[0, i] * ned_dot[0] + Rm[1, i] * ned_dot[1] + Rm[2, i] * ned_dot[2] for i in range(3)]
    f_body = MASS * jnp.stack(
        [
            DRAG_U * uvw[0],
            SIDE_FORCE + DRAG_V * uvw[1],
            LIFT + DRAG_W * uvw[2] + COLLECTIVE * u[3],
        ]
    )
    gravity = _column(np.array([0.0, 0.0, MASS * GRAVITY]), x)
    Rf = [Rm[i, 0] * f_body[0] + Rm[i, 1] * f_body[1] + Rm[i, 2] * f_body[2] for i in range(3)]
    force = jnp.stack(Rf) + gravity + noise[:3]  # R f_body + gravity + n_F
    torque = INERTIA * (
        _column(TORQUE_BIAS, x) + _column(RATE_DAMPING, x) * pqr + _column(CONTROL_GAIN, x) * u[:3]
    )
    ned_dot_next = ned_dot + (DT / MASS) * force
    pqr_next = pqr + (DT / INERTIA) * (torque + noise[3:])
    return jnp.concatenate([u, du, ned_dot_next, ned + DT * ned_dot, pqr_next, q_next])


def step_delayed(
    x: jax.Array, fifo: jax.Array, du: jax.Array, noise: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """One step with actuation delay d = ``fifo.shape[0]`` (d may be 0: fifo ``[0, 4, *B]``).

    The queue is concat(fifo, du[None]) ``[d+1, 4, *B]``; the change applied (and recorded in x's
    ``u_prev``/``du_prev``) is queue[0], commanded d steps ago; the new fifo is queue[1:].
    Returns ``(x_next [21, *B], fifo_next [d, 4, *B])``.
    """
    queue = jnp.concatenate([fifo, du[None]], axis=0)
    return step(x, queue[0], noise), queue[1:]


def noise_sequence(key: jax.Array, T: int, std) -> jax.Array:
    """Process noise [T, 6]: row t = std · N(0, I_6) drawn with ``jax.random.fold_in(key, t)``.

    The one convention shared by the Gymnasium env and the JAX rollouts (same key, same noise).
    """
    rows = jax.vmap(lambda t: jax.random.normal(jax.random.fold_in(key, t), (N_NOISE,)))
    return std * rows(jnp.arange(T))


# ----------------------------------------------------------------------------- targets
class HoverTrim(NamedTuple):
    """Hover trim: controls ``u`` [4] and roll angle ``roll`` (rad) that hold the helicopter."""

    u: jax.Array
    roll: jax.Array


@jax.jit  # one compiled program, not one per operation, when called outside a trace
def hover_trim() -> HoverTrim:
    """Solve the hover force/torque balance in closed form from the model coefficients.

    Torques: TORQUE_BIAS + CONTROL_GAIN·c = 0. Forces at rest: R_x(φ)·(0, SIDE_FORCE, f_z) +
    (0, 0, g) = 0, so ``|(SIDE_FORCE, f_z)|`` = g with f_z = −sqrt(g² − SIDE_FORCE²) (lift up) and
    φ = atan2(−SIDE_FORCE, −f_z); the collective gives f_z = LIFT + COLLECTIVE·c4.
    """
    c_rot = -jnp.asarray(TORQUE_BIAS) / jnp.asarray(CONTROL_GAIN)
    f_z = -jnp.sqrt(jnp.asarray(GRAVITY**2 - SIDE_FORCE**2))
    c4 = (f_z - LIFT) / COLLECTIVE
    roll = jnp.arctan2(jnp.asarray(-SIDE_FORCE), -f_z)
    return HoverTrim(u=jnp.concatenate([c_rot, c4[None]]), roll=roll)


@jax.jit
def hover_target() -> jax.Array:
    """Hover target [21]: trim controls, du_prev = velocity = position = rates = 0, rolled by φ."""
    u, roll = hover_trim()
    q = jnp.stack([jnp.sin(roll / 2), 0.0 * roll, 0.0 * roll, jnp.cos(roll / 2)])
    return jnp.concatenate([u, jnp.zeros(13), q])


def funnel_target(pads: bool = True) -> jax.Array:
    """Nose-in funnel target: [600, 21] with pads, [400, 21] without.

    Circle step k = 0..399: φ = 2πk/100, ω = 2π/5 rad/s; ned = (−5 cos φ, −5 sin φ, 0),
    ned_dot = (5ω sin φ, −5ω cos φ, 0), pqr = (0, 0, ω), q = [0, 0, sin(φ/2), cos(φ/2)] (yaw φ,
    nose at the centre). Pads (100 steps before and after): at rest at ned = (−5, 0, 0), level,
    facing North (q = [0, 0, 0, 1], the closing pad's φ = 8π). u_prev = du_prev = 0 throughout.

    Computed operation by operation, not as one compiled program: XLA fuses the sines and
    cosines of a compiled program differently, which moved the target by up to 2.2e-14, and the
    policy-gradient baseline's random search on the funnel amplified that into 11 of 20 seeds
    with a diverged test trajectory against 9.
    """
    k = jnp.arange(FUNNEL_CIRCLES * FUNNEL_STEPS_PER_CIRCLE, dtype=jnp.float64)
    phi = 2 * jnp.pi * k / FUNNEL_STEPS_PER_CIRCLE
    omega = 2 * jnp.pi / (FUNNEL_STEPS_PER_CIRCLE * DT)
    r, zero, one = FUNNEL_RADIUS, jnp.zeros_like(phi), jnp.ones_like(phi)
    circle = jnp.concatenate(
        [
            jnp.zeros((phi.shape[0], 8)),
            jnp.stack([r * omega * jnp.sin(phi), -r * omega * jnp.cos(phi), zero], axis=1),
            jnp.stack([-r * jnp.cos(phi), -r * jnp.sin(phi), zero], axis=1),
            jnp.stack([zero, zero, omega * one], axis=1),
            jnp.stack([zero, zero, jnp.sin(phi / 2), jnp.cos(phi / 2)], axis=1),
        ],
        axis=1,
    )
    if not pads:
        return circle
    pad = jnp.zeros((FUNNEL_PAD, N_STATE)).at[:, 11].set(-r).at[:, 20].set(1.0)
    return jnp.concatenate([pad, circle, pad], axis=0)


# ----------------------------------------------------------------------------- error coordinates
def to_error(x: jax.Array, x_star: jax.Array) -> jax.Array:
    """Error coordinates dx ``[21, *B]`` of x ``[21, *B]`` relative to x* ``[21]`` or
    ``[21, *B]`` (module docstring)."""
    xs = x_star.reshape(x_star.shape + (1,) * (x.ndim - x_star.ndim))
    e = quat_mul(quat_conj(xs[QUAT]), x[QUAT])[:3]
    return jnp.concatenate([x[:17] - xs[:17], e, jnp.ones((1, *x.shape[1:]), x.dtype)])


def from_error(dx: jax.Array, x_star: jax.Array) -> jax.Array:
    """Inverse of :func:`to_error`: x ``[21, *B]`` with q = q* ⊗ [e, sqrt(1 − ``|e|²``)] (dx[20]
    ignored). For ``|e|`` > 1 (not a rotation) the scalar part is clamped to 0 instead of NaN.
    """
    xs = x_star.reshape(x_star.shape + (1,) * (dx.ndim - x_star.ndim))
    e = dx[17:20]
    w = jnp.sqrt(jnp.maximum(1.0 - (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]), 0.0))
    return jnp.concatenate([xs[:17] + dx[:17], quat_mul(xs[QUAT], jnp.concatenate([e, w[None]]))])


def target_increment(x_star: jax.Array, x_star_next: jax.Array) -> jax.Array:
    """x*_{t+1} ⊖ x*_t [21]: error coordinates of x*_{t+1} relative to x*_t, constant entry 0."""
    return to_error(x_star_next, x_star).at[20].set(0.0)


def _error_step(dx: jax.Array, du: jax.Array, x_star: jax.Array, x_star_next: jax.Array):
    x = from_error(dx, x_star)
    return to_error(step(x, du, jnp.zeros(N_NOISE)), x_star_next)


def linearize(x_star: jax.Array, x_star_next: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Affine linearisation of the noise-free model in error coordinates: (A [21, 21], B [21, 4]).

    g(dx, du) = to_error(step(from_error(dx, x*_t), du, 0), x*_{t+1}) ≈ A dx + B du about
    dx = e_20 (zeros, constant 1), du = 0: A[:, :20], B by forward-mode Jacobians; the constant
    column A[:, 20] = g(e_20, 0) (the drift; A[20, 20] = 1, A[20, :20] = 0). vmap over a
    trajectory for x_star [T, 21], x_star_next [T, 21].
    """
    dx0 = jnp.zeros(N_STATE).at[20].set(1.0)
    du0 = jnp.zeros(N_ACTION)
    A, B = jax.jacfwd(_error_step, argnums=(0, 1))(dx0, du0, x_star, x_star_next)
    drift = _error_step(dx0, du0, x_star, x_star_next)
    return A.at[:, 20].set(drift), B


# ----------------------------------------------------------------------------- open-loop rollout
@jax.jit
def _rollout(x0: jax.Array, fifo0: jax.Array, dU: jax.Array, noise: jax.Array) -> jax.Array:
    def body(carry, inputs):
        x, fifo = step_delayed(*carry, *inputs)
        return (x, fifo), x

    _, X = jax.lax.scan(body, (x0, fifo0), (dU, noise))
    return jnp.concatenate([x0[None], X], axis=0)


def rollout(x0, dU, noise, *, delay: int = 0) -> jax.Array:
    """Open-loop trajectory X ``[*B, T+1, 21]`` from x0 ``[*B, 21]`` under dU ``[*B, T, 4]``,
    noise ``[*B, T, 6]``.

    Checked wrapper (ValueError naming the bad argument) around a jitted ``lax.scan`` of
    :func:`step_delayed` with an initially empty (zero) FIFO of ``delay`` steps. Leading batch
    axes ``*B`` must agree between the three arrays.
    """
    x0, dU, noise = (np.asarray(a, dtype=np.float64) for a in (x0, dU, noise))
    if isinstance(delay, bool) or not isinstance(delay, int | np.integer) or delay < 0:
        raise ValueError(f"delay must be an integer >= 0, got {delay!r}")
    if x0.ndim < 1 or x0.shape[-1] != N_STATE:
        raise ValueError(f"x0 must have shape [*B, {N_STATE}], got shape {x0.shape}")
    batch = x0.shape[:-1]
    if dU.ndim != len(batch) + 2 or dU.shape[: len(batch)] != batch or dU.shape[-1] != N_ACTION:
        raise ValueError(f"dU must have shape [*B, T, {N_ACTION}] with B = {batch}, got {dU.shape}")
    if noise.shape != (*dU.shape[:-1], N_NOISE):
        raise ValueError(f"noise must have shape {(*dU.shape[:-1], N_NOISE)}, got {noise.shape}")
    for label, a in (("x0", x0), ("dU", dU), ("noise", noise)):
        if not np.all(np.isfinite(a)):
            bad = int(np.sum(~np.isfinite(a)))
            raise ValueError(f"{label} must be finite, got {bad} non-finite entries ({a.shape})")
    T = dU.shape[-2]
    flat = int(np.prod(batch, dtype=np.int64))
    fifo0 = jnp.zeros((flat, delay, N_ACTION))
    X = jax.vmap(_rollout)(
        jnp.asarray(x0.reshape(flat, N_STATE)),
        fifo0,
        jnp.asarray(dU.reshape(flat, T, N_ACTION)),
        jnp.asarray(noise.reshape(flat, T, N_NOISE)),
    )
    return X.reshape(*batch, T + 1, N_STATE)


#: The helicopter as the plant runs it (:func:`loopid.algorithms.plant.make_plant`): its delayed
#: step, error coordinates and noise, all of which also take column batches.
DYNAMICS = Dynamics(step_delayed, to_error, from_error, noise_sequence, N_STATE, N_ACTION, True)
