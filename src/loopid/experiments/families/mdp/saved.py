"""A finite-MDP run's saved policies and learned models: reloaded (:func:`load`) and
evaluated exactly (:func:`evaluate`)."""

import jax
import numpy as np

from loopid.experiments.families.mdp.run import mdp_setup
from loopid.experiments.families.mdp.scenario import MDPScenario


def load(s: MDPScenario, method: str, arrays: dict):
    """One seed's saved policy ``K [S, A]`` and learned ``T̂ [S, A, S]``."""
    from loopid.experiments.learned import TableController, TableModel

    return TableModel(arrays["T_hat"]), TableController(arrays["K"])


def evaluate(s: MDPScenario, arrays: dict, seeds, episodes: int, env=None) -> np.ndarray:
    """The exact ``J_μ(π)`` of each saved policy ``arrays["K"] [S, n_states, n_actions]``,
    repeated ``episodes`` times (no sampling: the evaluation is exact)."""
    K = arrays["K"]
    if env is not None:
        raise ValueError(f"--env {env!r} applies to gym runs, not to {s.name}")
    plant = mdp_setup(s).plant
    J = jax.jit(jax.vmap(lambda k: plant.eval_one(k, None)[0]))(jax.numpy.asarray(K))
    return np.repeat(np.asarray(J)[:, None], episodes, axis=1)
