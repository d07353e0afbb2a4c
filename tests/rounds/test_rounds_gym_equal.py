"""Rounds driven by the transitions a ``loopid run gym`` run learned from give that run's models
and gains (to 1e-12).

The run is the gym family's ``run`` (what ``loopid run gym`` executes for each cell), on
Pendulum-v1. Its training rollouts are recorded as they are made; each iteration's batch is the
loop's own draws and mix of them (:func:`loopid.algorithms.transitions.draw`,
:func:`loopid.algorithms.transitions.select`, with the iteration's keys), written out as a round's
file with ``source`` from the mix. Feeding those files to ``loopid.rounds`` one by one must end on
the run's final model ``W`` and gains ``K``. The rounds keep the log's units (``[rounds] scale =
"none"``): the Gymnasium family's regulariser is λ/√n in the env's own units.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from loopid import rounds
from loopid.algorithms import gym_loop
from loopid.algorithms.keys import iteration_keys, seed_keys
from loopid.algorithms.transitions import draw, select
from loopid.experiments.families.gym.run import run
from loopid.experiments.families.gym.scenario import GymScenario
from loopid.rounds.api import controller_arrays
from loopid.systems.from_gymnasium import GymSystem
from loopid.systems.gym_slots import Rollouts

SEED, SAMPLES, ITERATIONS, HORIZON = 3, 30, 4, 20
CONFIG = f"""
[system]
states = ["sin", "thdot"]
actions = ["torque"]
target = [0.0, 0.0]
horizon = {HORIZON}
[cost]
Q = [1.0, 0.1]
R = [0.001]
[model]
lambda = 1e-3
[rounds]
samples = {SAMPLES}
method = "dagger"
scale = "none"
"""


def test_rounds_equal_the_gym_run(tmp_path, monkeypatch):
    s = GymScenario(
        env_id="Pendulum-v1", target=[0.0, 0.0], Q=[1.0, 0.1], R=[0.001], observe=[1, 2],
        reset_options={"x_init": 0.3, "y_init": 0.5}, horizon=HORIZON, num_envs=2,
        gain=[[3.0, 0.5]], action_std=0.5, iterations=ITERATIONS, samples=SAMPLES,
        test_trajectories=1, ftrl_lambda=1e-3,
    )  # fmt: skip
    recorded = []
    rollouts = GymSystem.rollouts

    def recording(self, policies, slots):
        r = rollouts(self, policies, slots)
        if len(policies) == 2:  # a training iteration: the policy's slots, then ν's
            recorded.append(r)
        return r

    monkeypatch.setattr(GymSystem, "rollouts", recording)
    trace = run("dagger", s, seeds=[SEED])
    assert len(recorded) == ITERATIONS - 1

    root = tmp_path / "dir"
    (tmp_path / "c.toml").write_text(CONFIG)
    rounds.init(root, tmp_path / "c.toml")
    key = seed_keys([SEED])[0]
    for n, r in enumerate(recorded, start=2):
        half = r.mask.shape[0] // 2
        pol, nu = (
            jax.tree_util.tree_map(lambda a: a[0], gym_loop._transitions(Rollouts(*part), 1))
            for part in (tuple(a[:half] for a in r), tuple(a[half:] for a in r))
        )
        keys = iteration_keys(key, jnp.int32(n))
        take = jax.random.bernoulli(keys.mix, jnp.float64(s.dagger_fraction), (SAMPLES,))
        batch = select(take, draw(pol, keys.policy, SAMPLES), draw(nu, keys.nu, SAMPLES))
        assert bool(jnp.all(batch.mask))
        dx, du, dxn = (np.asarray(a) for a in (batch.dx, batch.du, batch.dx_next))
        cols = {"sin": dx[:, 0], "thdot": dx[:, 1], "torque": du[:, 0]}
        cols |= {"next_sin": dxn[:, 0], "next_thdot": dxn[:, 1]}
        cols["source"] = np.where(np.asarray(take), "policy", "nu").tolist()
        pq.write_table(pa.table(cols), tmp_path / f"round-{n}.parquet")
        rounds.update(root, tmp_path / f"round-{n}.parquet")
    saved = controller_arrays(root)
    assert int(saved["round"]) == ITERATIONS
    np.testing.assert_allclose(saved["model_W"], trace.final["W"][0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(saved["K"], trace.final["K"][0], rtol=0, atol=1e-12)
    assert np.abs(saved["K"]).max() > 0.1  # a real controller, not the initial zero gain
