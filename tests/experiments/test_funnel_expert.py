"""The funnel's expert (iLQR from the helicopter family's initial actions) converges and tracks
the funnel within a metre, pitched nose-down on the circles."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.control import ilqr, tracking_rollout
from loopid.experiments.families.helicopter.expert import funnel_initial_actions
from loopid.systems import helicopter, tasks


def funnel_expert_problem():
    """The funnel task (SPEC §2 "Linearised expert"): raw-state helicopter, noise-free."""
    task = tasks.make_task("funnel")
    Q, R, target = task.Q, task.R, task.target

    def dynamics(x, u, t):
        return helicopter.step(x, u, jnp.zeros(6))

    def cost(x, u, t):
        dx = helicopter.to_error(x, target[t])
        return dx @ Q @ dx + u @ R @ u

    # the library's initial guess (trim, then the circle's yaw rate): see its docstring
    U0 = funnel_initial_actions(task)
    return task, dynamics, cost, U0


@pytest.mark.slow
def test_funnel_expert_converges_and_tracks_within_a_metre():
    task, dynamics, cost, U0 = funnel_expert_problem()
    sol = ilqr(dynamics, cost, task.x0, U0, max_iter=100)
    assert bool(sol.converged)
    assert np.all(np.diff(np.asarray(sol.cost_history)) <= 0.0)
    dX = jax.vmap(helicopter.to_error)(sol.X, task.target)
    pos_err = np.linalg.norm(np.asarray(dX[:, 11:14]), axis=1)
    assert pos_err.max() < 1.0  # SPEC sanity figure: about 0.82 m
    assert 40.0 < float(sol.cost) < 60.0  # SPEC sanity figure: about 48 without noise
    # nose-down pitch on the circles, about 37° (SPEC): |e_y| = sin(θ/2)
    pitch = np.degrees(2 * np.arcsin(np.abs(np.asarray(dX[150:450, 18]))))
    assert 30.0 < np.median(pitch) < 45.0
    # the returned policy u_t = U_t - K_t (x_t - X_t) replays the trajectory on the simulator
    replay = tracking_rollout(dynamics, task.x0, sol.X, sol.U, sol.K)
    np.testing.assert_allclose(replay.X, sol.X, atol=1e-8)
