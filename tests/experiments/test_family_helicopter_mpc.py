"""``[planner] kind = "mpc"`` through the helicopter family: each row's test cost is MPC flying
the seed's learned model, and ``loopid evaluate`` and ``loopid.load`` fly the same MPC again
(moved here from ``tests/algorithms/test_mpc_plant.py``, which tests the MPC plant itself)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.keys import EVALUATE, seed_keys
from loopid.algorithms.loop_program import trajectory_mean
from loopid.algorithms.plant import quadratic_form
from loopid.experiments.families import helicopter as family
from loopid.experiments.families.helicopter import assembly
from loopid.experiments.families.helicopter.scenario import scenario
from loopid.systems import helicopter


@pytest.mark.slow
def test_the_cell_flies_mpc_on_each_seeds_model():
    """``planner_kind = "mpc"`` on the hover through the family: DAgger, 3 seeds, 3 iterations.
    Each row's test cost is MPC flying the seed's model (the final iteration's, re-flown here from
    the saved ``W_features`` by the same MPC plant on the same test noise); the saved ``K`` are
    the task-horizon iLQR gains of that model."""
    s = scenario(
        "hover", model_kind="features", model_degree=1, planner_kind="mpc", planner_horizon=10,
        planner_every=5, planner_iterations=3, seeds=3, iterations=3, test_trajectories=2,
    )  # fmt: skip
    trace = family.run("dagger-t", s)
    assert np.all(np.isfinite(trace.rows.test_cost))
    assert trace.final["K"].shape == (3, 400, 4, 21)
    key = family.program_key(s)
    plant = assembly._setup(key).mpc.plant
    noise = assembly._setup(key).program.noise(seed_keys(np.arange(3))).test
    costs, _ = jax.jit(plant.eval_seeds)(jnp.asarray(trace.final["W_features"]), noise)
    np.testing.assert_allclose(trajectory_mean(costs), trace.rows.test_cost[:, -1], rtol=1e-9)

    # loopid evaluate's path: MPC re-planning on each seed's saved model, on fresh noise (key
    # stream 4); its first episode is the flight of the seed's restored model under that noise,
    # and flying the saved gains instead costs something else
    saved = {k: np.asarray(v) for k, v in trace.final.items()}
    evaluated = family.evaluate(s, saved, np.arange(3), 2)
    w = plant.eval_noise(jax.random.fold_in(jax.random.key(0), EVALUATE), 2)[0]
    W0 = assembly._setup(key).model.restore({"W_features": saved["W_features"][0]})
    X, total = jax.jit(assembly._setup(key).mpc.flight)(W0, w)
    assert X.shape == (401, 21)
    np.testing.assert_allclose(evaluated[0, 0], min(float(total), s.cost_cap), rtol=1e-9)
    gains = family.evaluate(s, {"K": saved["K"]}, np.arange(3), 2)
    assert not np.allclose(gains, evaluated)

    # loopid.load's controller (ReplanningController), called once a step from Python on seed
    # 0's first test noise, flies the trajectory the cell's plant flew and charged
    one = {k: v[0] for k, v in saved.items()} | {f"shared.{k}": v for k, v in
                                                  family.shared(s, "dagger-t").items()}  # fmt: skip
    _, controller = family.load(s, "dagger-t", one)
    task, w = plant.task, np.asarray(noise[:, :, 0, 0])
    qQ, qR = quadratic_form(task.Q), quadratic_form(task.R)
    x, total = np.asarray(task.x0), 0.0
    for t in range(400):
        du = controller(x, t)
        total += float(qQ(helicopter.to_error(x, task.target[t])) + qR(du))
        x = np.asarray(helicopter.step(x, du, w[t]))
    total += float(qQ(helicopter.to_error(x, task.target[400])))
    np.testing.assert_allclose(total, costs[0, 0], rtol=1e-9)
