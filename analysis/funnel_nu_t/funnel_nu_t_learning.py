"""D_t's learning on the funnel with each ν_t centre, one lane set driven step by step.

Helpers of ``analysis/funnel_nu_t/funnel_nu_t.py`` (its section 1): the funnel scenario at a centre
(:func:`scenario`), the loop program with the centres' ν_t samplers as the methods of one lane set
(:func:`run_centres`), the training flight of each iteration's policy recomputed beside the loop's
rows (:func:`flight_program`, checked by :func:`check_rows`), the comparison with each centre's own
scenario program (:func:`check_against_scenarios`), and the per-iteration and summary tables
(:func:`learning_table`, :func:`learning_summary`). Imported by that script; run alone it does
nothing.
"""

import jax
import jax.numpy as jnp
import numpy as np
from funnel_nu_t_fit import CIRCLES, centre_of  # beside this script

import loopid  # noqa: F401  (float64)
from loopid.algorithms.contracts import LoopSpec
from loopid.algorithms.exploration import nu_trajectory
from loopid.algorithms.keys import iteration_keys, seed_keys
from loopid.algorithms.loop import run_learning
from loopid.algorithms.loop_program import lane_noise, make_loop_program
from loopid.algorithms.transitions import draw, flatten
from loopid.experiments.families.helicopter import assembly
from loopid.experiments.families.helicopter.methods import policy_fractions
from loopid.experiments.families.helicopter.scenario import SCENARIOS

#: The loop's row fields kept per seed and iteration.
ROW_FIELDS = (
    "test_cost", "test_cost_median", "diverged", "loss_nu", "loss_policy", "valid_samples",
    "policy_samples",
)  # fmt: skip


# ----------------------------------------------------------------------------- setup
def scenario(centre: str, iterations: int, n_test: int):
    return SCENARIOS["funnel"].replace(
        nu_t_center=centre, iterations=iterations, test_trajectories=n_test
    )


# ----------------------------------------------------------------------------- 1. learning
def flight_program(plant, samples: int):
    """Jitted ``(K [L, T, m, n], lane keys [L], n, p [L]) -> stats``: each lane's training
    rollout of iteration n (its policy's draws, as :func:`loopid.algorithms.collect.
    policy_samples` makes them under ``trajectory`` sampling, same keys) and its batch's mix."""
    horizon, runs = plant.horizon, -(-samples // plant.horizon)

    def one(K, key, n, p):
        keys = iteration_keys(key, n)
        k_roll, k_draw = jax.random.split(keys.policy)
        tr = jax.vmap(lambda k: plant.rollout(K, k))(jax.random.split(k_roll, runs))
        first = tr.mask[0]  # the first run: τ = 0, 1, ... until its first restart
        reach = jnp.where(jnp.all(first), horizon, tr.t[0][jnp.argmin(first)])
        flat = flatten(tr)
        on_circles = flat.mask & (flat.t >= CIRCLES[0]) & (flat.t < CIRCLES[1])
        drawn = draw(flat, k_draw, samples)
        take = jax.random.bernoulli(keys.mix, p, (samples,))
        return {
            "reach": reach,
            "valid_steps": jnp.sum(flat.mask),
            "circle_steps": jnp.sum(on_circles),
            "policy_samples": jnp.sum(take & drawn.mask),
            "nu_slots": jnp.sum(~take),
        }

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None, 0)))


def run_centres(st, centres, seeds, iterations: int, n_test: int, samples: int):
    """D_t with each centre's ν_t, one lane set; returns per centre a dict of ``[S, N]`` arrays
    and the last carry's learner per centre (``W [S, T, 25, 21]``, step counts ``[S, T]``)."""
    sc = scenario("nominal", iterations, n_test)
    nus = [
        nu_trajectory(
            st.plant,
            state_var=sc.nu_state_var,
            action_var=sc.nu_action_var,
            centre=centre_of(c, st.plant, st.K_expert),
        )
        for c in centres
    ]
    loop = LoopSpec(
        st.plant, st.agent, nus, samples=samples, n_test=n_test, mode=sc.sampling, gamma=sc.gamma
    )
    program = make_loop_program(loop, iterations)
    M, S = len(centres), len(seeds)
    keys = seed_keys(np.asarray(seeds))
    lane_keys = jnp.concatenate([keys] * M)
    noise = lane_noise(program.noise(keys), M)
    which = jnp.arange(M, dtype=jnp.int32)
    p = jnp.full(M, sc.dagger_fraction)
    fly = flight_program(st.plant, samples)
    rows, flights = [], []
    carry, row = program.start(keys, noise, M)
    rows.append(jax.device_get(row))
    for n in range(2, iterations + 1):
        f = jax.device_get(fly(carry.K, lane_keys, jnp.int32(n), jnp.repeat(p, S)))
        flights.append(f)  # read before the step: the step donates the carry
        carry, row = program.step(carry, keys, noise, jnp.int32(n), p, which)
        rows.append(jax.device_get(row))
        print(f"  iteration {n}/{iterations}", end="\r", flush=True)
    print()
    learner = jax.device_get(carry.learner)
    out = []
    for m in range(M):
        lanes = slice(m * S, (m + 1) * S)
        r = {k: np.stack([getattr(x, k)[lanes] for x in rows], 1) for k in ROW_FIELDS}
        for k in flights[0]:
            first = np.full((S, 1), np.nan)  # iteration 1 flies nothing
            r["fly_" + k] = np.concatenate([first, np.stack([f[k][lanes] for f in flights], 1)], 1)
        out.append(r)
    finals = [
        {"W": np.asarray(learner.W[m * S : (m + 1) * S]),
         "count": np.asarray(learner.learner.n[m * S : (m + 1) * S])}
        for m in range(M)
    ]  # fmt: skip
    return out, finals, program


def check_rows(results) -> list[str]:
    """The recomputed policy draws must be the rows' (the rollouts are the loop's)."""
    problems = []
    for c, r in results.items():
        pol = r["fly_policy_samples"][:, 1:]
        if not np.array_equal(pol, r["policy_samples"][:, 1:]):
            problems.append(f"{c}: recomputed policy_samples differ from the rows'")
        valid = pol + r["fly_nu_slots"][:, 1:]  # every ν_t draw is a valid row
        if not np.array_equal(valid, r["valid_samples"][:, 1:]):
            problems.append(f"{c}: policy + ν slots differ from the rows' valid_samples")
    return problems


def check_against_scenarios(st, centres, seeds, iterations, n_test, samples, lane_program):
    """Each centre's own scenario program (``dagger-t``, which = 0) against the lane set's lane
    for ``iterations`` iterations: rows and last policies, bit for bit."""
    lanes = run_lanes_short(lane_program, centres, seeds, iterations)
    lines = []
    for m, c in enumerate(centres):
        sc = scenario(c, iterations, n_test)
        own = assembly.setup(sc)
        fr = policy_fractions("dagger-t", iterations, dagger_fraction=sc.dagger_fraction)
        own_loop = own.loop._replace(samples=samples, n_test=n_test)
        tr = run_learning(
            own_loop, fr, seeds, which=0, program=own.program, noise=own.test_noise(seeds)
        )
        same = all(
            np.array_equal(np.asarray(getattr(tr.rows, k)), lanes[m][k], equal_nan=True)
            for k in ROW_FIELDS
        )
        same_K = np.array_equal(np.asarray(tr.final["K"]), lanes[m]["K"])
        lines.append(
            f"{c}: {iterations} iterations x {len(seeds)} seeds, rows "
            f"{'identical' if same else 'DIFFER'}, last policies "
            f"{'identical' if same_K else 'DIFFER'}"
        )
    return lines


def run_lanes_short(program, centres, seeds, iterations):
    """The lane set's first ``iterations`` iterations (rows ``[S, n]`` per centre, last K)."""
    M, S = len(centres), len(seeds)
    keys = seed_keys(np.asarray(seeds))
    noise = lane_noise(program.noise(keys), M)
    which = jnp.arange(M, dtype=jnp.int32)
    p = jnp.full(M, SCENARIOS["funnel"].dagger_fraction)
    carry, row = program.start(keys, noise, M)
    rows = [jax.device_get(row)]
    for n in range(2, iterations + 1):
        carry, row = program.step(carry, keys, noise, jnp.int32(n), p, which)
        rows.append(jax.device_get(row))
    K = np.asarray(carry.K)
    out = []
    for m in range(M):
        lanes = slice(m * S, (m + 1) * S)
        r = {k: np.stack([getattr(x, k)[lanes] for x in rows], 1) for k in ROW_FIELDS}
        r["K"] = K[lanes]
        out.append(r)
    return out


# ----------------------------------------------------------------------------- output
def per_seed(a) -> str:
    return "/".join("-" if np.isnan(v) else f"{v:.0f}" for v in a)


def learning_table(c, r, seeds, n_test) -> list[str]:
    lines = [
        f"#### ν_t centred on `{c}` (seeds {seeds[0]}-{seeds[-1]})",
        "",
        "| n | test cost, median over seeds (capped mean of " + f"{n_test}) | diverged "
        "| τ of 1st restart, per seed | valid rollout steps, per seed | circle steps, per seed "
        "| valid_samples (median) | policy_samples (median) | loss_nu (median) "
        "| loss_policy (median) | loss_policy / loss_nu |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    N = r["test_cost"].shape[1]
    for i in range(N):
        ln, lp = np.median(r["loss_nu"][:, i]), np.median(r["loss_policy"][:, i])
        ratio = "-" if i == 0 else f"{lp / ln:.2f}"
        lines.append(
            f"| {i + 1} | {np.median(r['test_cost'][:, i]):.4g} "
            f"| {int(np.sum(r['diverged'][:, i]))}/{r['diverged'].shape[0] * n_test} "
            f"| {per_seed(r['fly_reach'][:, i])} | {per_seed(r['fly_valid_steps'][:, i])} "
            f"| {per_seed(r['fly_circle_steps'][:, i])} "
            f"| {np.median(r['valid_samples'][:, i]):.0f} "
            f"| {np.median(r['policy_samples'][:, i]):.0f} | {ln:.4g} | {lp:.4g} | {ratio} |"
        )
    return lines


def learning_summary(results, seeds) -> list[str]:
    lines = [
        "| ν_t centre | seeds x iterations | τ of 1st restart: median over seeds and it. 2..N "
        "(min-max) | rollouts with no restart | valid rollout steps (median) "
        "| loss_nu (median) | loss_policy (median) | median of loss_policy / loss_nu "
        "| test cost at N (median) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c, r in results.items():
        reach = r["fly_reach"][:, 1:]
        full = int(np.sum(reach >= 599))
        ratio = np.median(r["loss_policy"][:, 1:] / r["loss_nu"][:, 1:])
        lines.append(
            f"| `{c}` | {len(seeds)} x {r['test_cost'].shape[1]} | {np.median(reach):.0f} "
            f"({np.min(reach):.0f}-{np.max(reach):.0f}) | {full}/{reach.size} "
            f"| {np.median(r['fly_valid_steps'][:, 1:]):.0f} "
            f"| {np.median(r['loss_nu'][:, 1:]):.3g} | {np.median(r['loss_policy'][:, 1:]):.3g} "
            f"| {ratio:.2f} | {np.median(r['test_cost'][:, -1]):.4g} |"
        )
    return lines


if __name__ == "__main__":
    print("helpers of analysis/funnel_nu_t/funnel_nu_t.py: run that script")
