"""Collection speed through the Gymnasium adapter: vector envs against a single environment.

Workload: the Pendulum example (``examples/pendulum.toml``): 32 training slots of 200 steps of a
linear policy with Gaussian action noise (``stop_norm`` restarts included), i.e. what one
iteration of 5 seeds collects, through :meth:`loopid.systems.from_gymnasium.GymSystem.rollouts` with
``num_envs`` sub-environments (SyncVectorEnv). Reference: the same episodes in a plain Python
loop over one ``gymnasium.make("Pendulum-v1")`` (reset with options, policy, clip, step), the
least a Gymnasium user could write. Best of 3 repeats; steps per second and the ratio to the
reference. Run: ``.venv/bin/python benchmarks/gym.py``.
"""

import time

import gymnasium
import numpy as np

import loopid  # noqa: F401
from loopid.systems.from_gymnasium import GymSystem
from loopid.systems.gym_slots import Slot

OPTIONS = {"x_init": 0.3, "y_init": 0.5}
K = np.array([[3.0, 0.5]])
SLOTS, T, STD, REPEATS = 32, 200, 0.5, 3


def plain_loop() -> tuple[float, int]:
    """One env, one episode after another: the reference."""
    env = gymnasium.make("Pendulum-v1")
    steps = 0
    t0 = time.perf_counter()
    for i in range(SLOTS):
        rng = np.random.default_rng(i)
        eps = STD * rng.standard_normal((T, 1))
        obs, _ = env.reset(seed=int(rng.integers(2**32)), options=OPTIONS)
        for t in range(T):
            a = np.clip(-K @ obs[1:] + eps[t], -2.0, 2.0).astype(np.float32)
            obs, _, term, trunc, _ = env.step(a)
            steps += 1
            if term or trunc:
                break
    secs = time.perf_counter() - t0
    env.close()
    return secs, steps


def adapter(num_envs: int, vectorization: str = "sync") -> tuple[float, int]:
    with GymSystem(
        "Pendulum-v1", target=[0.0, 0.0], observe=[1, 2], horizon=T, num_envs=num_envs,
        reset_options=OPTIONS, stop_norm=1.0, vectorization=vectorization,
    ) as system:  # fmt: skip
        policy = system.linear_policy(K)
        slots = [Slot(0, 0, i, STD, True) for i in range(SLOTS)]
        system.rollouts([policy], slots[:2])  # warm-up
        t0 = time.perf_counter()
        r = system.rollouts([policy], slots)
        return time.perf_counter() - t0, int(r.mask.size)


def best(f, *args) -> float:
    """Steps per second, best of REPEATS."""
    return max(steps / secs for secs, steps in (f(*args) for _ in range(REPEATS)))


def main() -> None:
    ref = best(plain_loop)
    rows = [("plain loop, 1 env (reference)", ref)]
    for e in (1, 4, 8, 16, 32):
        rows.append((f"adapter, SyncVectorEnv x{e}", best(adapter, e)))
    rows.append(("adapter, AsyncVectorEnv x2", best(adapter, 2, "async")))
    print(f"Pendulum-v1, {SLOTS} slots x {T} steps, linear policy + action noise")
    print(f"{'collection':<34}{'steps/s':>10}{'vs reference':>14}")
    for name, rate in rows:
        print(f"{name:<34}{rate:>10.0f}{rate / ref:>13.2f}x")


if __name__ == "__main__":
    main()
