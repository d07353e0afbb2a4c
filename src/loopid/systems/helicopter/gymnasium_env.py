"""The helicopter tasks as Gymnasium environments: a thin stateful adapter over the JAX core.

Ids (registered by ``import loopid``): ``loopid/HelicopterHover-v0`` (d = 0, noise std 1),
``loopid/HelicopterHoverDelay-v0`` (d = 1, noise std 1), ``loopid/HelicopterFunnel-v0``
(d = 0, noise std 0.1); keyword arguments ``noise_std`` and ``delay`` override the defaults.

Observation: the raw state x_t [21] (float64, in the simulator's order). Action: the commanded
control change Δu_t [4] (float64).
Reward: r_t = −(Δx_tᵀ Q Δx_t + Δu_tᵀ R Δu_t), Δx_t = to_error(x_t, x*_t),
the stage cost of the state *before* the action and of the commanded action. ``info
["next_state_cost"]`` = Δx_{t+1}ᵀ Q Δx_{t+1}; at the last step it is the terminal term, so an
episode's total cost (``tasks.trajectory_cost``) is −Σ_t r_t + info["next_state_cost"] of the
last step. ``terminated`` is always False; ``truncated`` is True after ``task.horizon`` actions.

Noise: ``reset(seed=s)`` sets the episode's noise seed to s mod 2^63; a reset without a seed
draws one from the env's ``np_random``. The noise of step t is row t of
``helicopter.noise_sequence(jax.random.key(noise_seed), T, noise_std)``; the seed is returned as
``info["noise_seed"]`` so a JAX rollout can reproduce the episode exactly.

Both spaces are unbounded Boxes: the simulator has no control saturation and a diverging
controller drives the state past any bound, so finite bounds would be dishonest.
"""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from loopid.systems import helicopter
from loopid.systems.helicopter.tasks import make_task

__all__ = ["ENV_IDS", "HelicopterEnv", "register_helicopter_envs"]


@jax.jit
def _env_step(x, fifo, du, key, t, noise_std, target, Q, R):
    """One env transition: (x_next, fifo_next, stage cost of (x_t, Δu_t), state cost of x_next)."""
    noise = noise_std * jax.random.normal(jax.random.fold_in(key, t), (helicopter.N_NOISE,))
    dx = helicopter.to_error(x, target[t])
    cost = dx @ Q @ dx + du @ R @ du
    x_next, fifo_next = helicopter.step_delayed(x, fifo, du, noise)
    dx_next = helicopter.to_error(x_next, target[t + 1])
    return x_next, fifo_next, cost, dx_next @ Q @ dx_next


class HelicopterEnv(gymnasium.Env):
    """A helicopter task (``"hover"``, ``"hover-delay"``, ``"funnel"``) as a Gymnasium env."""

    metadata = {"render_modes": []}  # noqa: RUF012  (Gymnasium's class attribute)

    def __init__(self, task="hover", noise_std=None, delay=None, render_mode=None):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (no rendering), got {render_mode!r}")
        self.task = make_task(task, noise_std=noise_std, delay=delay)
        self.render_mode = render_mode
        self.observation_space = gymnasium.spaces.Box(
            -np.inf, np.inf, shape=(helicopter.N_STATE,), dtype=np.float64
        )
        self.action_space = gymnasium.spaces.Box(
            -np.inf, np.inf, shape=(helicopter.N_ACTION,), dtype=np.float64
        )
        self._noise_std = jnp.asarray(self.task.noise_std, dtype=jnp.float64)
        self._x = self.task.x0
        self._fifo = jnp.zeros((self.task.delay, helicopter.N_ACTION))
        self._key = jax.random.key(0)
        self._t = 0
        self.noise_seed = 0

    def reset(self, *, seed=None, options=None):
        """Start at ``task.x0`` with an empty (zero) delay FIFO; info = {"noise_seed": int}."""
        super().reset(seed=seed)
        if seed is not None:
            self.noise_seed = int(seed) % 2**63
        else:
            self.noise_seed = int(self.np_random.integers(2**63))
        self._key = jax.random.key(self.noise_seed)
        self._x = self.task.x0
        self._fifo = jnp.zeros((self.task.delay, helicopter.N_ACTION))
        self._t = 0
        return np.array(self._x, dtype=np.float64), {"noise_seed": self.noise_seed}

    def step(self, action):
        """Apply the commanded change Δu (delayed by ``task.delay`` steps) for one step."""
        du = np.asarray(action, dtype=np.float64)
        if du.shape != (helicopter.N_ACTION,) or not np.all(np.isfinite(du)):
            raise ValueError(f"action must be a finite array of shape (4,), got {action!r}")
        if self._t >= self.task.horizon:
            raise RuntimeError("the episode is over (truncated); call reset()")
        self._x, self._fifo, cost, next_cost = _env_step(
            self._x,
            self._fifo,
            jnp.asarray(du),
            self._key,
            self._t,
            self._noise_std,
            self.task.target,
            self.task.Q,
            self.task.R,
        )
        self._t += 1
        truncated = self._t >= self.task.horizon
        info = {"next_state_cost": float(next_cost)}
        return np.array(self._x, dtype=np.float64), -float(cost), False, truncated, info


#: The registered ids and the task each makes.
ENV_IDS = {
    "loopid/HelicopterHover-v0": "hover",
    "loopid/HelicopterHoverDelay-v0": "hover-delay",
    "loopid/HelicopterFunnel-v0": "funnel",
}


def register_helicopter_envs() -> None:
    """Register every id of :data:`ENV_IDS`; a second call is a no-op."""
    for env_id, task in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="loopid.systems.helicopter.gymnasium_env:HelicopterEnv",
                kwargs={"task": task},
            )
