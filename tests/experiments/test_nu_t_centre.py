"""Where ν_t is centred (loopid.algorithms.exploration.Centre, planned_flight; the helicopter
family's ``nu_t_center`` reading): noise around the expert's planned flight is noise around *that*
flight, computed here independently by stepping the simulator with the expert's gain; on hover
the planned flight is the trim itself, to the trim's own round-off drift."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.exploration import Centre, nu_trajectory, planned_flight
from loopid.experiments.families.helicopter.assembly import nu_t_centre
from loopid.systems import helicopter
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task

DRAWS = 20_000
STATE_STD, ACTION_STD = 0.05, 0.01  # ν_t's defaults: variances 0.0025 and 0.0001


def fly(task, K):
    """The expert's noise-free flight, stepped here: x_{t+1} = f(x_t, −K_t Δx_t, 0) (delay 0)."""
    target = jnp.asarray(task.target)
    zero = jnp.zeros(helicopter.N_NOISE)

    def body(x, t):
        du = -K[t] @ helicopter.to_error(x, target[t])
        return helicopter.step(x, du, zero), (x, du)

    _, (X, dU) = jax.lax.scan(body, jnp.asarray(task.x0), jnp.arange(target.shape[0] - 1))
    return np.asarray(X), np.asarray(dU)


@pytest.fixture(scope="module")
def short_funnel():
    """The 400-step funnel (no pads), its expert and the expert's flight stepped here."""
    task = make_task("funnel", pads=False)
    K = expert_gains(task)
    return helicopter_plant(task), K, fly(task, K)


def test_planned_flight_is_the_expert_flown_without_noise(short_funnel):
    plant, K, (X, dU) = short_funnel
    flight = planned_flight(plant, K)
    np.testing.assert_allclose(np.asarray(flight.states), X, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(flight.actions), dU, rtol=0, atol=1e-9)
    # and it is not the target: the circles are flown with collective and tilted
    assert X[:, helicopter.U_PREV][:, 3].mean() > 0.3
    assert np.asarray(plant.task.target)[:, helicopter.U_PREV].max() == 0.0


def test_nominal_samples_are_centred_on_the_flight_not_the_target(short_funnel):
    plant, K, (X, dU) = short_funnel
    centre = nu_t_centre("nominal", plant, K)
    draw = jax.jit(lambda key: nu_trajectory(plant, centre=centre)(key, DRAWS))
    tr = draw(jax.random.key(7))
    t = np.asarray(tr.t)
    around_flight = np.asarray(jax.vmap(helicopter.to_error)(tr.x, jnp.asarray(X)[t]))[:, :20]
    action_noise = np.asarray(tr.du) - dU[t]
    for name, v, std in (("state", around_flight, STATE_STD), ("action", action_noise, ACTION_STD)):
        se = v.std(axis=0) / np.sqrt(DRAWS)
        assert np.all(np.abs(v.mean(axis=0)) < 4 * se), name  # zero to the standard error
        np.testing.assert_allclose(v.std(axis=0), std, rtol=0.03, err_msg=name)
    # around the target instead, the collective's previous-action entry is far from zero
    around_target = np.asarray(tr.dx)[:, helicopter.U_PREV][:, 3]
    assert around_target.mean() > 100 * STATE_STD / np.sqrt(DRAWS)


@pytest.mark.parametrize("task_name, delay_mode", [
    ("hover", "latency"), ("hover-delay", "latency"), ("hover-delay", "fifo"),
])  # fmt: skip
def test_on_hover_the_planned_flight_is_the_trim_to_its_own_drift(task_name, delay_mode):
    task = make_task(task_name)
    plant = helicopter_plant(task, delay_mode=delay_mode)
    K = expert_gains(task)
    flight = planned_flight(plant, K)
    target = jnp.asarray(task.target)
    # the noise-free trim's own drift over the horizon: no action at all
    _, X = jax.lax.scan(
        lambda x, _: (helicopter.step(x, jnp.zeros(4), jnp.zeros(6)), x),
        target[0], None, length=plant.horizon,
    )  # fmt: skip
    drift = np.abs(np.asarray(jax.vmap(helicopter.to_error)(X, target[:-1]))[:, :20]).max()
    away = np.abs(np.asarray(jax.vmap(helicopter.to_error)(flight.states, target[:-1])))
    assert drift < 1e-13
    assert away[:, :20].max() <= max(2 * drift, 1e-15)
    assert np.abs(np.asarray(flight.actions)).max() <= 2 * drift


def test_trim_keeps_the_targets_states_with_the_trim_controls():
    task = make_task("funnel")
    plant = helicopter_plant(task)
    centre = nu_t_centre("trim", plant, None)
    target = np.asarray(task.target)
    states = np.asarray(centre.states)
    assert centre.actions is None
    np.testing.assert_array_equal(states[:, 4:], target[:, 4:])
    np.testing.assert_array_equal(
        states[:, :4], np.broadcast_to(helicopter.hover_trim().u, (len(target), 4))
    )
    assert nu_t_centre("target", plant, None) is None
    # on hover the target holds the trim controls: trim is the target, bit for bit (the readings
    # study takes the hover cells of nu_t_center = trim from those of target)
    hover = helicopter_plant(make_task("hover"))
    trim = np.asarray(nu_t_centre("trim", hover, None).states)
    np.testing.assert_array_equal(trim, np.asarray(hover.task.target))


def test_a_failed_planned_flight_names_the_reading():
    task = make_task("hover")
    plant = helicopter_plant(task, stop_norm=1e-6)
    with pytest.raises(ValueError, match=r"nu_t_center = nominal: .*\(--set nu_t_center=target\)"):
        nu_t_centre("nominal", plant, jnp.asarray(expert_gains(task)) + 1.0)


def test_a_flight_that_leaves_the_safe_region_is_refused():
    task = make_task("hover")
    plant = helicopter_plant(task, stop_norm=1e-6)
    K = expert_gains(task)
    with pytest.raises(ValueError, match="leaves the safe region at step 0"):
        planned_flight(plant, jnp.asarray(K) + 1.0)
    assert isinstance(planned_flight(helicopter_plant(task), K), Centre)
