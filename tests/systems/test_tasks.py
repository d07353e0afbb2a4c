"""Tasks and costs against SPEC §3 (targets) and §4.1 (cost)."""

import jax
import numpy as np
import pytest

from loopid.systems import helicopter as h
from loopid.systems.base import trajectory_cost
from loopid.systems.helicopter.tasks import (
    FUNNEL_WEIGHTS,
    HOVER_WEIGHTS,
    TASK_NAMES,
    cost_matrices,
    make_task,
)

OMEGA = 2 * np.pi / 5


# ----------------------------------------------------------------------------- funnel target
def test_funnel_target_shape_and_pads():
    F = np.asarray(h.funnel_target())
    assert F.shape == (600, 21) and np.asarray(h.funnel_target(pads=False)).shape == (400, 21)
    np.testing.assert_array_equal(F[100:500], h.funnel_target(pads=False))
    rest = np.zeros(21)
    rest[11], rest[20] = -5.0, 1.0
    np.testing.assert_array_equal(F[:100], np.tile(rest, (100, 1)))
    np.testing.assert_array_equal(F[500:], np.tile(rest, (100, 1)))
    np.testing.assert_array_equal(F[:, :8], 0.0)  # u_prev = du_prev = 0 everywhere


def test_funnel_positions_on_circle_nose_at_centre():
    F = np.asarray(h.funnel_target())
    np.testing.assert_allclose(np.linalg.norm(F[:, 11:13], axis=1), 5.0, atol=1e-12)
    np.testing.assert_array_equal(F[:, 13], 0.0)
    nose = np.asarray(jax.vmap(h.quat_to_rotmat)(F[:, h.QUAT]))[:, :, 0]  # body x in world
    np.testing.assert_allclose(nose, -F[:, 11:14] / 5.0, atol=1e-12)
    circle = F[100:500]
    np.testing.assert_allclose(circle[:, 14:17], np.tile([0, 0, OMEGA], (400, 1)), atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(circle[:, 8:11], axis=1), 5 * OMEGA, atol=1e-12)
    # at φ = 0: 5 m south of the centre, flying west at 5ω, nose north (at the centre)
    np.testing.assert_allclose(circle[0, 8:14], [0, -5 * OMEGA, 0, -5, 0, 0], atol=1e-15)


def test_funnel_target_is_continuous_and_self_consistent():
    F = np.asarray(h.funnel_target())
    dq = np.linalg.norm(np.diff(F[:, h.QUAT], axis=0), axis=1)
    assert dq.max() < 0.032  # one step of yaw at most (2 sin(ω dt / 4) = 0.0314), no sign flips
    dpos = np.linalg.norm(np.diff(F[:, 11:14], axis=0), axis=1)
    assert dpos.max() < 5 * OMEGA * h.DT  # chord < arc
    c = F[100:500]
    # central differences of position reproduce the velocity to O((ω dt)²)
    np.testing.assert_allclose((c[2:, 11:14] - c[:-2, 11:14]) / (2 * h.DT), c[1:-1, 8:11],
                               atol=5 * OMEGA * (OMEGA * h.DT) ** 2)  # fmt: skip
    # the attitude advances exactly by the body rate: q_{k+1} = q_k ⊗ rotvec(dt·pqr_k)
    advance = jax.vmap(lambda q, w: h.quat_mul(q, h.rotvec_to_quat(h.DT * w)))
    nxt = advance(c[:-1, 17:], c[:-1, 14:17])
    np.testing.assert_allclose(nxt, c[1:, 17:], atol=1e-12)
    np.testing.assert_allclose(c[399, 17:], [0, 0, np.sin(np.pi * 399 / 100), np.cos(np.pi * 3.99)],
                               atol=1e-12)  # fmt: skip


# ----------------------------------------------------------------------------- cost
def test_cost_matrices_follow_spec():
    Q, R = cost_matrices(HOVER_WEIGHTS)
    expected = np.repeat([0, 1000, 1, 1, 1, 1, 0], [4, 4, 3, 3, 3, 3, 1]) * 0.05
    np.testing.assert_array_equal(np.diag(Q), expected)
    np.testing.assert_array_equal(Q, np.diag(np.diag(Q)))
    np.testing.assert_allclose(R, 0.05e-6 * np.eye(4), rtol=1e-15)
    Qf, _ = cost_matrices(FUNNEL_WEIGHTS)
    np.testing.assert_allclose(np.diag(Qf)[[0, 4, 8, 11, 14, 17, 20]],
                               0.05 * np.array([0, 1000, 0.01, 10, 1, 10, 0]))  # fmt: skip
    with pytest.raises(ValueError, match=r"weights .*\(1, 2\)"):
        cost_matrices((1, 2))


def test_trajectory_cost_equals_explicit_sum(rng):
    Q, R = cost_matrices(FUNNEL_WEIGHTS)
    dX, dU = rng.normal(size=(7, 21)), rng.normal(size=(6, 4))
    Qn, Rn = np.asarray(Q), np.asarray(R)
    ref = sum(x @ Qn @ x for x in dX) + sum(u @ Rn @ u for u in dU)
    np.testing.assert_allclose(trajectory_cost(dX, dU, Q, R), ref, rtol=1e-13)


# ----------------------------------------------------------------------------- tasks
def test_make_task_defaults():
    hover = make_task("hover")
    assert (hover.name, hover.noise_std, hover.delay, hover.horizon) == ("hover", 1.0, 0, 400)
    assert hover.target.shape == (401, 21) and not hover.time_varying
    np.testing.assert_array_equal(hover.target, np.tile(h.hover_target(), (401, 1)))
    np.testing.assert_array_equal(hover.x0, h.hover_target())
    np.testing.assert_array_equal(hover.Q, cost_matrices(HOVER_WEIGHTS)[0])
    delayed = make_task("hover-delay")
    assert (delayed.noise_std, delayed.delay, delayed.horizon) == (1.0, 1, 400)
    funnel = make_task("funnel")
    assert (funnel.noise_std, funnel.delay, funnel.horizon) == (0.1, 0, 599)
    assert funnel.time_varying
    np.testing.assert_array_equal(funnel.x0, funnel.target[0])
    np.testing.assert_array_equal(funnel.x0[8:11], 0.0)  # at rest
    np.testing.assert_array_equal(funnel.x0[14:17], 0.0)
    np.testing.assert_array_equal(funnel.x0[:8], 0.0)  # u_prev = 0, not the hover trim
    np.testing.assert_array_equal(funnel.Q, cost_matrices(FUNNEL_WEIGHTS)[0])
    short = make_task("funnel", pads=False)
    assert short.horizon == 399 and abs(float(short.x0[9]) + 5 * OMEGA) < 1e-12  # on the circle
    assert set(TASK_NAMES) == {"hover", "hover-delay", "funnel"}


def test_make_task_overrides():
    t = make_task("hover", noise_std=0.0, delay=3)
    assert (t.noise_std, t.delay) == (0.0, 3)
    assert make_task("funnel", noise_std=2).noise_std == 2.0


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        (("hoover",), {}, r"'hoover'.*hover, hover-delay, funnel"),
        (("hover",), {"noise_std": -1.0}, r"noise_std .*-1\.0"),
        (("hover",), {"noise_std": float("nan")}, r"noise_std .*nan"),
        (("hover",), {"noise_std": "1"}, r"noise_std .*'1'"),
        (("hover",), {"delay": -2}, r"delay .*-2"),
        (("hover",), {"delay": 1.5}, r"delay .*1\.5"),
    ],
)
def test_make_task_rejects_bad_input(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_task(*args, **kwargs)
