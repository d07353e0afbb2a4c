"""Flying a static linear gain on the helicopter and on its hover linearisation.

Helpers of ``analysis/best_linear_gain/best_linear_gain.py``: the column blocks of a gain and the
error-state blocks (:data:`BLOCKS`, :data:`STATE_BLOCKS`), a static gain broadcast over the horizon
(:func:`static`) or without its du_prev columns (:func:`no_du_prev`), held-out costs of gains on
common noise (:func:`held_out`, :func:`mean_se`, :func:`fmt`), the hover linearisation as a plant
(:func:`linearised_plant`), and the states a gain's test-protocol flights visit with the true
noise-free step from each (:func:`visited`, :func:`true_next`). Imported by that script and its
other helpers; run alone it does nothing.
"""

import jax
import jax.numpy as jnp
import numpy as np

import loopid  # noqa: F401  (float64)
from loopid.algorithms.plant import make_plant
from loopid.systems import helicopter
from loopid.systems.linear import linear_dynamics, linear_task

#: Column blocks of a gain / entries of the error state.
BLOCKS = (
    ("u_prev", slice(0, 4)),
    ("du_prev", slice(4, 8)),
    ("velocity", slice(8, 11)),
    ("position", slice(11, 14)),
    ("rates", slice(14, 17)),
    ("attitude", slice(17, 20)),
    ("feedforward", slice(20, 21)),
)
#: The error-state blocks the linearisation can get wrong (u_prev, du_prev are exactly linear).
STATE_BLOCKS = BLOCKS[2:6]
N_Z = 20  # error coordinates without the constant


def static(K: jax.Array, horizon: int) -> jax.Array:
    return jnp.broadcast_to(K, (horizon, *K.shape))


def no_du_prev(K: jax.Array) -> jax.Array:
    """``K`` with its du_prev columns (4-7) set to 0."""
    return K.at[:, 4:8].set(0.0)


def held_out(plant, gains: dict, noise: jax.Array) -> dict:
    """Costs [n] and diverged counts of each gain under ``noise``."""
    run = jax.jit(lambda K: plant.eval_costs(static(K, plant.horizon), noise))
    out = {}
    for name, K in gains.items():
        costs, diverged = run(K)
        out[name] = (np.asarray(costs), int(np.sum(np.asarray(diverged))))
    return out


def mean_se(c: np.ndarray) -> tuple[float, float]:
    return float(c.mean()), float(c.std(ddof=1) / np.sqrt(c.size))


def linearised_plant(task, delay_mode: str):
    """The hover linearisation as a plant: ``z' = A_z z + B_z Δu + G w`` on the 20 error
    coordinates (:func:`loopid.systems.linear.linear_dynamics`), with the helicopter's own
    process noise ``w`` [6] (same keys, same draws) entering the velocity (dt/m) and the rates
    (dt/I) as in the simulator; the task's cost, horizon, start (the trim) and delay."""
    target = task.target
    A, B = (np.asarray(M) for M in helicopter.linearize(target[0], target[1]))
    G = np.zeros((N_Z, helicopter.N_NOISE))
    G[8:11, :3] = helicopter.DT / helicopter.MASS * np.eye(3)
    G[14:17, 3:] = helicopter.DT / helicopter.INERTIA * np.eye(3)
    G = jnp.asarray(G)

    def noise_sequence(key, T, std):
        return helicopter.noise_sequence(key, T, std) @ G.T

    dynamics = linear_dynamics(A[:N_Z, :N_Z], B[:N_Z])._replace(noise_sequence=noise_sequence)
    lin = linear_task(np.asarray(task.Q)[:N_Z, :N_Z], task.R, np.zeros(N_Z), task.horizon,
                      noise_std=task.noise_std, name=f"{task.name}-linearised")  # fmt: skip
    return make_plant(lin._replace(delay=task.delay), dynamics, delay_mode=delay_mode)


# ----------------------------------------------------------------------------- visited states
def visited(plant, K: jax.Array, n_runs: int, key: jax.Array, action_std: float = 0.0):
    """States, error states and applied changes of ``n_runs`` test-protocol flights of the
    static gain ``K`` (the plant's rollout with no safe-region restart; ``action_std``: white
    noise added to the gain's changes): raw x [N, 21], Δx [N, 21], Δu [N, 4]."""
    keys = jax.random.split(key, n_runs)
    fly = jax.vmap(lambda k: plant.rollout(static(K, plant.horizon), k, action_std))
    tr = jax.jit(fly)(keys)
    keep = np.asarray(tr.mask).reshape(-1)
    flat = [np.asarray(a).reshape(-1, a.shape[-1])[keep] for a in (tr.x, tr.dx, tr.du)]
    return flat


def true_next(x: np.ndarray, du: np.ndarray, x_star: jax.Array) -> np.ndarray:
    """Noise-free true step in error coordinates, rows [N, 21]."""
    zero = jnp.zeros((x.shape[0], helicopter.N_NOISE))
    step = jax.jit(jax.vmap(helicopter.step))
    x_next = step(jnp.asarray(x), jnp.asarray(du), zero)
    return np.asarray(jax.vmap(lambda a: helicopter.to_error(a, x_star))(x_next))


def fmt(x: float, se: float | None = None) -> str:
    return f"{x:.3f}" if se is None else f"{x:.3f} ± {se:.3f}"


if __name__ == "__main__":
    print("helpers of analysis/best_linear_gain/best_linear_gain.py: run that script")
