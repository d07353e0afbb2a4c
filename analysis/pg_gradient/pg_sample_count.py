"""Why the policy-gradient baseline's sample count barely matters under ``pg_samples = rollouts``.

The paper's account of its baseline is that 100 samples per iteration give poor gradient
estimates and 500 do better. Ours reaches about the same cost with either. This script walks
the baseline's iterations (:func:`~loopid.algorithms.policy_gradient_step.make_pg_step`, hover, the
trim-holding base) with m = 100 and m = 500 side by side, from the same state and with the same
iteration keys, and prints per iteration the cosine between the two gradient estimates, whether
each accepted its step, and how far apart the two gain offsets θ have drifted.

What it shows: every rollout of an iteration shares one noise draw (common random numbers), and
the draw is the same for both m (it depends on the iteration key and the rollout length H, not
on m). Once the probes P = m − 2 reach the d = 52 free gains, the linear system is determined by
that one draw, so its solution is that draw's gradient whatever m is: more probes add no
information about the expected cost. The step is the normalised direction times a trust radius
that does not depend on m, and it is accepted on the same draw. So m = 100 and m = 500 take
nearly the same steps. Run: ``.venv/bin/python analysis/pg_gradient/pg_sample_count.py`` (~1 min).
"""

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.keys import iteration_key, seed_keys
from loopid.algorithms.policy_gradient import pg_base
from loopid.algorithms.policy_gradient_step import budget, init_state, make_pg_step
from loopid.experiments.families.helicopter import agent as agent_of
from loopid.experiments.families.helicopter import setup
from loopid.experiments.families.helicopter.scenario import scenario

SEEDS = 4
ITERATIONS = 30
SAMPLES = (100, 500)


def main() -> None:
    s = scenario("hover", pg_samples="rollouts")
    plant = setup(s).plant
    agent = agent_of(s)
    K1, _ = agent.policy(agent.init())
    base, free = pg_base(plant, K1, hold=True)
    radius = s.pg_step * s.pg_sigma * np.sqrt(plant.n_action)
    steps, states = {}, {}
    for m in SAMPLES:
        one = make_pg_step(
            plant, base, free, samples=m, horizon=s.pg_horizon, sigma=s.pg_sigma,
            nu_state_var=s.nu_state_var, cost_cap=s.cost_cap, samples_mode="rollouts",
        )  # fmt: skip
        steps[m] = jax.jit(jax.vmap(one))
        _, P = budget(m, s.pg_horizon, plant.horizon, samples_mode="rollouts")
        init = init_state(free, radius, probes=P)
        states[m] = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (SEEDS, *a.shape)), init)
    keys = seed_keys(np.arange(SEEDS))
    print("it  cos(g100, g500) min/median  accepted 100 | 500   |θ100 − θ500| / |θ500|")
    for it in range(2, ITERATIONS + 2):
        k = jax.vmap(lambda key, it=it: iteration_key(key, jnp.int32(it)))(keys)
        out = {}
        for m in SAMPLES:
            states[m], out[m] = steps[m](states[m], k)
        g1, g2 = (np.asarray(out[m].gradient).reshape(SEEDS, -1) for m in SAMPLES)
        cos = np.sum(g1 * g2, 1) / (np.linalg.norm(g1, axis=1) * np.linalg.norm(g2, axis=1))
        t1, t2 = (np.asarray(states[m].theta).reshape(SEEDS, -1) for m in SAMPLES)
        apart = np.linalg.norm(t1 - t2, axis=1) / np.maximum(np.linalg.norm(t2, axis=1), 1e-300)
        acc = [np.asarray(out[m].accepted).astype(int) for m in SAMPLES]
        print(
            f"{it:3d}  {cos.min():.4f} / {np.median(cos):.4f}            "
            f"{''.join(map(str, acc[0]))} | {''.join(map(str, acc[1]))}   "
            f"{' '.join(f'{a:.1e}' for a in apart)}"
        )


if __name__ == "__main__":
    main()
