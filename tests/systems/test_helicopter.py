"""The helicopter dynamics against SPEC §3: trim, sanity figures, Jacobians, invariants, delay."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from loopid.systems import helicopter as h

ZERO_NOISE = jnp.zeros(h.N_NOISE)
_step = jax.jit(h.step)
_linearize = jax.jit(h.linearize)
_noise = jax.jit(h.noise_sequence, static_argnums=1)


@jax.jit
def _g(dx, du, xs, xn):
    """g(dx, du) = to_error(step(from_error(dx, x*_t), du, 0), x*_{t+1})."""
    return h.to_error(h.step(h.from_error(dx, xs), du, ZERO_NOISE), xn)


def _random_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- trim and hover
def test_hover_trim_matches_spec_figures_and_is_a_fixed_point():
    u, roll = h.hover_trim()
    np.testing.assert_allclose(u, [0.0065152, 0.0016287, 0.0093666, 0.400125], rtol=0, atol=1e-6)
    assert abs(float(roll) - 0.0581367) < 1e-6
    x = h.hover_target()
    assert x.shape == (21,) and x.dtype == jnp.float64
    np.testing.assert_allclose(x[h.QUAT], [np.sin(roll / 2), 0, 0, np.cos(roll / 2)], atol=0)
    # the residual of one noise-free step is round-off: the trim solves the balance exactly
    np.testing.assert_allclose(_step(x, jnp.zeros(4), ZERO_NOISE), x, rtol=0, atol=1e-14)


def test_trim_hover_stays_put_for_400_steps():
    x = h.hover_target()
    X = h.rollout(x, np.zeros((400, 4)), np.zeros((400, 6)))
    assert X.shape == (401, 21)
    assert float(jnp.max(jnp.abs(X - x))) < 1e-9


def test_off_trim_collective_drifts():
    # a wrong trim (or wrong force balance) must not pass the fixed-point test by accident
    x = h.hover_target().at[3].add(1e-3)
    X = h.rollout(x, np.zeros((400, 4)), np.zeros((400, 6)))
    assert float(jnp.max(jnp.abs(X[-1] - x))) > 1.0


# ----------------------------------------------------------------------------- one step from trim
def test_one_step_from_trim_matches_spec_sanity_figures():
    x = h.hover_target()
    x0 = _step(x, jnp.zeros(4), ZERO_NOISE)
    effect = np.stack([np.asarray(_step(x, jnp.eye(4)[i], ZERO_NOISE) - x0) for i in range(4)], 1)
    np.testing.assert_allclose(effect[h.U_PREV], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(effect[h.DU_PREV], np.eye(4), atol=1e-12)
    expected = np.zeros((9, 4))  # rows ned_dot (3), ned (3), pqr (3)
    expected[1, 3], expected[2, 3] = 0.0799, -1.3727
    expected[6, 0], expected[7, 1], expected[8, 2] = 0.66, -0.4605, 0.742
    np.testing.assert_allclose(effect[8:17], expected, atol=5e-5)
    np.testing.assert_allclose(effect[17:21], 0.0, atol=1e-15)


def test_linearize_about_hover_b_rows_and_zero_drift():
    x = h.hover_target()
    A, B = _linearize(x, x)
    assert A.shape == (21, 21) and B.shape == (21, 4)
    np.testing.assert_allclose(B[0:8], np.vstack([np.eye(4), np.eye(4)]), atol=1e-12)
    np.testing.assert_allclose(B[[9, 10, 14, 15, 16], [3, 3, 0, 1, 2]],
                               [0.0799, -1.3727, 0.66, -0.4605, 0.742], atol=5e-5)  # fmt: skip
    np.testing.assert_allclose(A[:20, 20], 0.0, atol=1e-13)  # trim: no drift
    np.testing.assert_allclose(A[20], np.eye(21)[20], atol=0)


@pytest.mark.parametrize("t", [0, 150, 399])
def test_linearize_agrees_with_central_finite_differences(t):
    target = h.funnel_target()
    xs, xn = target[t], target[t + 1]
    A, B = _linearize(xs, xn)
    dx0 = np.eye(21)[20]

    def g(dx, du):
        return np.asarray(_g(dx, du, xs, xn))

    eps = 1e-6
    A_fd = np.stack(
        [(g(dx0 + eps * e, np.zeros(4)) - g(dx0 - eps * e, np.zeros(4))) / (2 * eps)
         for e in np.eye(21)[:20]], axis=1,
    )  # fmt: skip
    B_fd = np.stack([(g(dx0, eps * e) - g(dx0, -eps * e)) / (2 * eps) for e in np.eye(4)], axis=1)
    np.testing.assert_allclose(A[:, :20], A_fd, atol=1e-7)
    np.testing.assert_allclose(B, B_fd, atol=1e-7)
    np.testing.assert_allclose(A[:, 20], g(dx0, np.zeros(4)), atol=1e-14)
    # the affine model reproduces a small perturbed step to second order
    rng = np.random.default_rng(t)
    dx = dx0 + np.concatenate([1e-4 * rng.normal(size=20), [0.0]])
    du = 1e-4 * rng.normal(size=4)
    np.testing.assert_allclose(A @ dx + B @ du, g(dx, du), atol=1e-7)


def test_linearize_vmaps_over_a_trajectory():
    target = h.funnel_target()
    A, B = jax.jit(jax.vmap(h.linearize))(target[:-1], target[1:])
    assert A.shape == (599, 21, 21) and B.shape == (599, 21, 4)
    A1, B1 = _linearize(target[200], target[201])
    np.testing.assert_allclose(A[200], A1, atol=1e-13)
    np.testing.assert_allclose(B[200], B1, atol=1e-13)


# ----------------------------------------------------------------------------- quaternions
def test_quaternion_helpers_match_scipy(rng):
    p, q = _random_quats(rng, 50), _random_quats(rng, 50)
    prod = np.asarray(jax.vmap(h.quat_mul)(p, q))
    ref = (Rotation.from_quat(p) * Rotation.from_quat(q)).as_quat()
    sign = np.sign(np.sum(prod * ref, axis=1, keepdims=True))
    np.testing.assert_allclose(prod, sign * ref, atol=1e-12)
    # Hamilton product on raw components (scipy canonicalises nothing here, but check directly)
    np.testing.assert_allclose(
        h.quat_mul(jnp.array([1.0, 0, 0, 0]), jnp.array([0.0, 1, 0, 0])), [0, 0, 1, 0], atol=0
    )  # fmt: skip  (i·j = k)
    np.testing.assert_allclose(
        jax.vmap(h.quat_to_rotmat)(p), Rotation.from_quat(p).as_matrix(), atol=1e-12
    )
    np.testing.assert_allclose(jax.vmap(h.quat_mul)(p, jax.vmap(h.quat_conj)(p)),
                               np.tile([0, 0, 0, 1.0], (50, 1)), atol=1e-12)  # fmt: skip
    r = rng.normal(size=(50, 3)) * np.array([[1.0]] * 25 + [[1e-5]] * 25)
    np.testing.assert_allclose(
        jax.vmap(h.rotvec_to_quat)(r), Rotation.from_rotvec(r).as_quat(), atol=1e-12
    )


def test_rotvec_to_quat_gradient_is_finite_at_zero():
    J = jax.jacfwd(h.rotvec_to_quat)(jnp.zeros(3))
    np.testing.assert_allclose(J, np.vstack([0.5 * np.eye(3), np.zeros((1, 3))]), atol=0)
    J = jax.jacrev(h.rotvec_to_quat)(jnp.zeros(3))
    assert np.all(np.isfinite(J))


def test_quaternion_stays_unit_over_10000_random_steps():
    rng = np.random.default_rng(1)
    dU = 0.01 * rng.normal(size=(10_000, 4))
    noise = rng.normal(size=(10_000, 6))
    X = np.asarray(h.rollout(h.hover_target(), dU, noise))
    assert np.max(np.abs(X[:, 14:17])) > 1.0  # the rates are large: real rotations happen
    assert np.max(np.abs(np.linalg.norm(X[:, h.QUAT], axis=1) - 1)) < 1e-9


def test_error_coordinates_round_trip(rng):
    target = h.funnel_target()
    xs = target[rng.integers(0, 600, size=200)]
    x = np.asarray(xs).copy()
    x[:, :17] += rng.normal(size=(200, 17))
    dq = _random_quats(rng, 200)
    dq[:, 3] = np.abs(dq[:, 3])  # within the hemisphere where the error coordinates are defined
    x[:, 17:] = np.asarray(jax.vmap(h.quat_mul)(xs[:, 17:], dq))
    dx = jax.vmap(h.to_error)(x, xs)
    np.testing.assert_allclose(dx[:, 17:20], dq[:, :3], atol=1e-12)
    np.testing.assert_allclose(dx[:, 20], 1.0, atol=0)
    np.testing.assert_allclose(jax.vmap(h.from_error)(dx, xs), x, atol=1e-12)
    np.testing.assert_allclose(h.to_error(xs[0], xs[0]), np.eye(21)[20], atol=1e-15)


def test_target_increment():
    target = h.funnel_target(pads=False)
    inc = h.target_increment(target[10], target[11])
    omega_dt = 2 * np.pi / 100
    np.testing.assert_allclose(inc[11:14], target[11, 11:14] - target[10, 11:14], atol=0)
    np.testing.assert_allclose(inc[17:20], [0, 0, np.sin(omega_dt / 2)], atol=1e-15)
    assert inc[20] == 0.0
    np.testing.assert_allclose(h.target_increment(h.hover_target(), h.hover_target()), 0, atol=0)


# ----------------------------------------------------------------------------- delay and noise
@pytest.mark.parametrize("d", [0, 1, 2])
def test_delay_applies_the_change_commanded_d_steps_earlier(d, rng):
    dU = 0.01 * rng.normal(size=(30, 4))
    noise = rng.normal(size=(30, 6))
    X = np.asarray(h.rollout(h.hover_target(), dU, noise, delay=d))
    applied = np.concatenate([np.zeros((d, 4)), dU[: 30 - d]])
    np.testing.assert_allclose(X[1:, h.DU_PREV], applied, atol=0)
    np.testing.assert_allclose(X, h.rollout(h.hover_target(), applied, noise), atol=0)


def test_step_delayed_with_empty_fifo_is_step(rng):
    x = h.hover_target()
    du, n = jnp.asarray(rng.normal(size=4)), jnp.asarray(rng.normal(size=6))
    x1, fifo = h.step_delayed(x, jnp.zeros((0, 4)), du, n)
    assert fifo.shape == (0, 4)
    np.testing.assert_array_equal(x1, h.step(x, du, n))


def test_delayed_data_is_not_linear_in_the_recorded_pair():
    """A linear fit of x_{t+1} on (x_t, Δu_t, 1) is near-exact without delay, poor with delay 1."""
    rng = np.random.default_rng(2)
    dU = 0.01 * rng.normal(size=(300, 10, 4))
    x0 = np.tile(np.asarray(h.hover_target()), (300, 1))
    noise = np.zeros((300, 10, 6))
    rms = {}
    for d in (0, 1):
        X = np.asarray(h.rollout(x0, dU, noise, delay=d))
        Z = np.concatenate([X[:, :-1], dU, np.ones((300, 10, 1))], axis=2).reshape(-1, 26)
        Y = X[:, 1:].reshape(-1, 21)
        W = np.linalg.lstsq(Z, Y, rcond=None)[0]
        rms[d] = np.sqrt(np.mean((Z @ W - Y) ** 2))
    assert rms[1] > 30 * rms[0], rms


def test_vmap_over_1000_states_equals_single_calls(rng):
    X = np.asarray(h.hover_target()) + 0.1 * rng.normal(size=(1000, 21))
    X[:, h.QUAT] = _random_quats(rng, 1000)
    dU, N = rng.normal(size=(1000, 4)), rng.normal(size=(1000, 6))
    batched = np.asarray(jax.jit(jax.vmap(h.step))(X, dU, N))
    single = np.stack([np.asarray(_step(X[i], dU[i], N[i])) for i in range(1000)])
    np.testing.assert_allclose(batched, single, rtol=1e-14, atol=1e-14)


def test_noise_sequence_convention():
    key = jax.random.key(7)
    n = _noise(key, 50, 0.5)
    assert n.shape == (50, 6) and n.dtype == jnp.float64
    np.testing.assert_array_equal(n, _noise(jax.random.key(7), 50, 0.5))
    np.testing.assert_array_equal(n[13], 0.5 * jax.random.normal(jax.random.fold_in(key, 13), (6,)))
    np.testing.assert_array_equal(n[:20], _noise(key, 20, 0.5))  # prefix-stable
    assert not np.allclose(n, _noise(jax.random.key(8), 50, 0.5))
    big = _noise(key, 20_000, 1.0)
    assert abs(float(jnp.std(big)) - 1) < 0.02 and abs(float(jnp.mean(big))) < 0.02


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"x0": np.zeros(20)}, r"x0 .*\(20,\)"),
        ({"dU": np.zeros((5, 3))}, r"dU .*\(5, 3\)"),
        ({"noise": np.zeros((4, 6))}, r"noise .*\(4, 6\)"),
        ({"x0": np.full(21, np.nan)}, r"x0 must be finite"),
        ({"dU": np.full((5, 4), np.inf)}, r"dU must be finite"),
        ({"delay": -1}, r"delay .*-1"),
        ({"delay": 1.5}, r"delay .*1\.5"),
    ],
)
def test_rollout_rejects_bad_input(kwargs, match):
    args = {"x0": np.asarray(h.hover_target()), "dU": np.zeros((5, 4)), "noise": np.zeros((5, 6))}
    delay = kwargs.pop("delay", 0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        h.rollout(args["x0"], args["dU"], args["noise"], delay=delay)


def test_column_batches_equal_vmap(rng):
    """step, to_error and from_error on column batches [21, B] (and [21, S, N]) give vmap's
    numbers: the layout the plant's test rollouts use."""
    X = np.asarray(h.hover_target()) + 0.1 * rng.normal(size=(300, 21))
    X[:, h.QUAT] = _random_quats(rng, 300)
    dU, N = rng.normal(size=(300, 4)), rng.normal(size=(300, 6))
    xs = np.asarray(h.funnel_target()[150])
    rows = np.asarray(jax.vmap(h.step)(X, dU, N))
    np.testing.assert_allclose(h.step(X.T, dU.T, N.T).T, rows, rtol=1e-14, atol=1e-14)
    cube = h.step(X.T.reshape(21, 20, 15), dU.T.reshape(4, 20, 15), N.T.reshape(6, 20, 15))
    np.testing.assert_allclose(np.asarray(cube).reshape(21, 300).T, rows, rtol=1e-14, atol=1e-14)
    err = np.asarray(jax.vmap(h.to_error, in_axes=(0, None))(X, xs))
    np.testing.assert_allclose(h.to_error(X.T, xs).T, err, rtol=1e-14, atol=1e-14)
    back = np.asarray(jax.vmap(h.from_error, in_axes=(0, None))(err, xs))
    np.testing.assert_allclose(h.from_error(err.T, xs).T, back, rtol=1e-14, atol=1e-14)
