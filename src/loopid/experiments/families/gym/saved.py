"""A gym run's saved policies flown again: reloaded (``loopid.load``), tested on fresh episodes
(``loopid evaluate``) and filmed (``loopid animate``).

A cell saves, per seed, the final gains ``K [T, m, n]`` (``a = a_op − K_t [o[observe] − o*; 1]``),
the learned model's arrays and, shared by the seeds, the nominal ``A``, ``B``
(:mod:`loopid.experiments.artifacts`). Where the cell flew MPC (``[planner] kind = "mpc"`` and a
learned model saved) the saved policy is MPC again, re-planning on each seed's saved model
(:func:`saved_policy`); otherwise it is the gains. Each entry point builds the scenario's
:class:`~.setup.Setup` once.
"""

from pathlib import Path

import numpy as np

from loopid.algorithms import agents
from loopid.algorithms.gym_loop import EVALUATE, test_episodes
from loopid.experiments.artifacts import tested_gains
from loopid.experiments.families.gym.scenario import GymScenario
from loopid.experiments.families.gym.setup import Setup, gym_setup
from loopid.models.linear_offset import LinearOffsetModel
from loopid.settings import model_planner


def saved_controller(setup: Setup, arrays: dict):
    """One seed's saved model and controller in the env's coordinates (``arrays``: that seed's
    saved arrays, the ``shared.*`` ones included): ``(model or None, GainController)``; the
    MLP's network is saved (``mlp.*``) but not rebuilt here."""
    from loopid.experiments.learned import FeatureModel, GainController, LinearModel

    target, observe = np.asarray(setup.shape.target), setup.system.observe

    def error(obs, t):
        o = obs if observe is None else obs[np.asarray(observe)]
        return np.concatenate([o - target, [1.0]])

    model = None
    if "W" in arrays or "W_features" in arrays:  # the nominal the cell kept (shared.A, .B)
        nominal = LinearOffsetModel(np.asarray(arrays["shared.A"]), np.asarray(arrays["shared.B"]))
        if "W" in arrays:
            model = LinearModel(nominal, arrays["W"])
        else:
            spec = model_planner.specs(setup.scenario).model
            fmap = agents.feature_map(spec, nominal.n, nominal.m)
            model = FeatureModel(nominal, fmap, arrays["W_features"])
    return model, GainController(tested_gains(arrays), error, np.asarray(setup.shape.a_op))


def load(s: GymScenario, method: str, arrays: dict):
    """One seed's saved model and controller (:func:`saved_controller`)."""
    with gym_setup(s) as setup:
        return saved_controller(setup, arrays)


def saved_policy(setup: Setup, arrays: dict):
    """What the seeds' saved arrays ``{name: [S, ...]}`` fly on ``setup``'s env: MPC re-planning
    on each seed's saved model where the cell flew MPC, else the gains the run tested
    (``best_K [S, T, m, n]`` under ``test_policy = "best"``, else ``K``)."""
    from loopid.algorithms.planning_agent import holds_model, restore_seeds

    if setup.compiled.mpc is None or not holds_model(arrays):
        return setup.system.linear_policy(np.asarray(tested_gains(arrays)))
    return setup.compiled.mpc(restore_seeds(setup.compiled.model, arrays))


def evaluate(s: GymScenario, arrays: dict, seeds, episodes: int, env=None) -> np.ndarray:
    """Capped test costs ``[S, episodes]`` of the saved policies (:func:`saved_policy`) on fresh
    episodes (slot stream 4: noise the run never saw); ``env``: fly them on another Gymnasium
    id (transfer) with the same observation indices, target and costs."""
    if env is not None:
        s = s.replace(env_id=env)
    with gym_setup(s) as setup:
        costs, _ = test_episodes(
            setup.system, saved_policy(setup, arrays), [int(x) for x in seeds], episodes,
            setup.test_cost, s.termination, s.cost_cap, stream=EVALUATE,
        )  # fmt: skip
    return costs


def animate(run_dir, s: GymScenario, methods, seed: int, path, every: int = 2) -> None:
    """An animated GIF of the env's own ``rgb_array`` frames: each method's saved final policy
    at ``seed`` flying one episode (reset with ``seed`` and the scenario's reset options), the
    methods side by side; ``every``: keep one frame in that many (40 ms each)."""
    import gymnasium
    from PIL import Image

    from loopid.experiments import artifacts
    from loopid.experiments.families.gym.env import rendering_env

    with gym_setup(s) as setup:
        policies = []
        for m in methods:
            _, arrays = artifacts.read(Path(run_dir) / "cells", s.name, m)
            one = artifacts.for_seed(arrays, seed, f"{s.name}/{m}")
            policies.append(saved_controller(setup, one)[1])
    reset_options = setup.values["reset_options"] or None
    films = []
    for controller in policies:
        env = None
        try:  # any failure of the env's own renderer (a missing pygame, say) is one line
            env = rendering_env(s)
            policy = controller.as_gymnasium_policy(env.action_space)
            obs, _ = env.reset(seed=int(seed), options=reset_options)
            policy.reset()
            frames = [env.render()]
            for _ in range(s.horizon or env.spec.max_episode_steps or 200):
                obs, _, terminated, truncated, _ = env.step(policy(obs))
                frames.append(env.render())
                if terminated or truncated:
                    break
        except (gymnasium.error.Error, ImportError, TypeError) as e:
            what = " ".join(str(e).split())
            raise ValueError(f"{s.env_id} cannot render rgb_array frames ({what})") from None
        finally:
            if env is not None:
                env.close()
        if frames[0] is None:
            raise ValueError(f"{s.env_id} renders no rgb_array frames")
        films.append(frames)
    T = max(len(f) for f in films)
    images = [
        Image.fromarray(np.concatenate([f[min(t, len(f) - 1)] for f in films], axis=1))
        for t in range(0, T, every)
    ]
    tmp = Path(path).with_name(f".{Path(path).name}.tmp.gif")
    images[0].save(tmp, save_all=True, append_images=images[1:], duration=40 * every, loop=0)
    tmp.replace(path)
