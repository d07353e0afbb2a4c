"""Exploration distributions ν over state-action pairs (paper section 6): ν_t, ν_e, ν_en.

Each sampler is a pure function ``sample(key, m) -> Transitions`` of ``m`` transitions: a pair
``(s, a) ~ ν`` is drawn and the real system is queried there (its generative model,
:meth:`Plant.query`) for ``s'``.

- ``ν_t`` (:func:`nu_trajectory`): the desired trajectory with white Gaussian noise: a target
  time ``t`` uniform on ``{0, …, T−2}``, error state ``Δx = [ξ; 1]`` with ``ξ ~ N(0, σ_s² I)``
  (σ_s² = 0.0025) mapped back through the error coordinates around the centre's state ``c_t``,
  action ``Δu = ū_t + η`` with ``η ~ N(0, σ_a² I)`` (σ_a² = 0.0001). The centre
  (:class:`Centre`, ``c_t`` ``[T, n_x]`` and ``ū_t`` ``[T, m]``) is one reading of "the desired
  trajectory": the cost's target with no actions (the default of :func:`nu_trajectory`), or a
  flyable trajectory with its actions, such as the expert's planned flight
  (:func:`planned_flight`).
- ``ν_e`` (:func:`nu_expert`, ``action_std = 0``): state-action pairs visited by the expert on
  the real noisy system, drawn uniformly from fresh expert rollouts.
- ``ν_en`` (:func:`nu_expert`, ``action_std = 0.01``): the same, with ``N(0, 0.0001 I)`` added
  to the expert's actions while it flies.

:func:`make_nus` builds all three; ν_e and ν_en are then one :func:`expert_draw` at two noise
levels, which a loop program serving all three methods' ν compiles once.

With a delay the plant's readings decide what a ν sample is: under ``delay_mode =
"fifo"`` each pair is queried with the pending FIFO filled with the action (``nu_pending =
"hold"``) or empty (``"zero"``), or, for ν_e/ν_en with ``"rollout"``, not queried at all: the
sample is the transition the expert's own delayed rollout recorded, ``(x_t, commanded Δu_t,
x_{t+1})`` (ν_t, which has no rollout, is then queried as under ``hold``). Under ``"latency"``
the expert flies with latency, the pair is the state and the change it applied, and the query
is a plain one-step query.
"""

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.contracts import SharedSampler, Transitions
from loopid.algorithms.plant import Plant, make_plant
from loopid.algorithms.transitions import draw, flatten

NU_KINDS = ("t", "e", "en")

Sampler = Callable[[jax.Array, int], Transitions]


def _query_many(plant: Plant, x, du, t, key) -> Transitions:
    keys = jax.random.split(key, x.shape[0])
    return jax.vmap(plant.query)(x, du, t, keys)


class Centre(NamedTuple):
    """What ``ν_t`` draws its noise around: raw states ``states [≥ horizon, n_x]`` (row t is the
    centre at target time t) and actions ``actions [horizon, m]`` (``Δu``), or ``None`` for no
    action (noise around zero)."""

    states: jax.Array
    actions: jax.Array | None = None


def planned_flight(plant: Plant, K: jax.Array) -> Centre:
    """The planned flight of the gain ``K [horizon, m, n]``: the plant flown from its start
    state with no process noise and no action noise, its raw states ``x_t [horizon, n_x]`` and
    the changes ``Δu_t [horizon, m]`` the policy made (the applied change under a delay's
    ``latency`` reading, the commanded one under ``fifo``: what the learner records).

    ``ValueError`` when the flight leaves the safe region (``plant.stop_norm``): it is then no
    trajectory of the task."""
    task = plant.task._replace(noise_std=0.0)
    quiet = make_plant(
        task, plant.dynamics, stop_norm=plant.stop_norm, nu_pending=plant.nu_pending,
        cost_cap=plant.cost_cap, delay_mode=plant.delay_mode,
    )  # fmt: skip
    flight = jax.jit(quiet.rollout)(jnp.asarray(K, jnp.float64), jax.random.key(0), 0.0)
    mask = np.asarray(flight.mask)
    if not mask.all():
        first = int(np.argmin(mask))
        raise ValueError(f"the planned flight leaves the safe region at step {first}")
    return Centre(flight.x, flight.du)


def nu_trajectory(
    plant: Plant,
    *,
    state_var: float = 0.0025,
    action_var: float = 0.0001,
    centre: Centre | None = None,
) -> Sampler:
    """``ν_t``: noise around the desired trajectory (state covariance ``state_var·I`` through the
    error coordinates, action covariance ``action_var·I``), centred on ``centre`` (default: the
    task's target, no action)."""
    if state_var < 0 or action_var < 0:
        raise ValueError(
            f"variances must be >= 0, got state_var={state_var}, action_var={action_var}"
        )
    if centre is None:
        centre = Centre(plant.task.target)
    states = jnp.asarray(centre.states, dtype=jnp.float64)
    actions = None if centre.actions is None else jnp.asarray(centre.actions, jnp.float64)
    n, m = plant.n_state, plant.n_action

    def sample(key: jax.Array, count: int) -> Transitions:
        k_t, k_s, k_a, k_q = jax.random.split(key, 4)
        t = jax.random.randint(k_t, (count,), 0, plant.horizon, dtype=jnp.int32)
        xi = math.sqrt(state_var) * jax.random.normal(k_s, (count, n - 1), dtype=jnp.float64)
        dx = jnp.concatenate([xi, jnp.ones((count, 1), jnp.float64)], axis=1)
        x = jax.vmap(plant.dynamics.from_error)(dx, states[t])
        du = math.sqrt(action_var) * jax.random.normal(k_a, (count, m), dtype=jnp.float64)
        if actions is not None:
            du = actions[t] + du
        return _query_many(plant, x, du, t, k_q)

    return sample


def expert_draw(plant: Plant, K_expert: jax.Array) -> Callable:
    """``draw(key, count, action_std)``: ``count`` pairs visited by the expert ``K_expert``
    ``[horizon, m, n]`` (its affine gain in error coordinates) flying with action noise of std
    ``action_std`` (a number or a traced scalar). Each call runs ``ceil(count / horizon)`` fresh
    expert rollouts, draws ``count`` visited pairs uniformly, and queries the system there
    (``plant.nu_pending == "rollout"``: keeps the rollouts' own recorded transitions instead,
    module docstring)."""

    def draw_pairs(key: jax.Array, count: int, action_std) -> Transitions:
        k_roll, k_draw, k_q = jax.random.split(key, 3)
        runs = -(-count // plant.horizon)
        tr = jax.vmap(lambda k: plant.rollout(K_expert, k, action_std))(
            jax.random.split(k_roll, runs)
        )
        visited = draw(flatten(tr), k_draw, count)
        if plant.nu_pending == "rollout":
            return visited
        fresh = _query_many(plant, visited.x, visited.du, visited.t, k_q)
        return fresh._replace(mask=fresh.mask & visited.mask)

    return draw_pairs


def nu_expert(plant: Plant, K_expert: jax.Array, *, action_std: float = 0.0) -> SharedSampler:
    """``ν_e`` (``action_std = 0``) or ``ν_en`` (``action_std = 0.01``): the expert's pairs
    (:func:`expert_draw`)."""
    if action_std < 0:
        raise ValueError(f"action_std must be >= 0, got {action_std}")
    return SharedSampler(expert_draw(plant, K_expert), float(action_std))


def make_nu(
    kind: str,
    plant: Plant,
    K_expert: jax.Array,
    *,
    state_var: float = 0.0025,
    action_var: float = 0.0001,
    expert_action_var: float = 0.0001,
    centre: Centre | None = None,
) -> Sampler:
    """The sampler for ``kind`` in :data:`NU_KINDS` (``"t"``, ``"e"``, ``"en"``); ``centre``:
    ν_t's (:func:`nu_trajectory`)."""
    if kind == "t":
        return nu_trajectory(plant, state_var=state_var, action_var=action_var, centre=centre)
    if kind == "e":
        return nu_expert(plant, K_expert, action_std=0.0)
    if kind == "en":
        if expert_action_var < 0:
            raise ValueError(f"expert_action_var must be >= 0, got {expert_action_var}")
        return nu_expert(plant, K_expert, action_std=math.sqrt(expert_action_var))
    raise ValueError(f"unknown exploration distribution {kind!r}; choose one of {NU_KINDS}")


def make_nus(plant: Plant, K_expert: jax.Array, **variances) -> list[Sampler]:
    """The samplers of :data:`NU_KINDS`, ``[ν_t, ν_e, ν_en]`` (``variances``: the keywords of
    :func:`make_nu`, ν_t's ``centre`` too), with ν_en at its own action noise on ν_e's
    :func:`expert_draw` (:class:`~loopid.algorithms.contracts.SharedSampler`), so that a
    program serving all three holds the expert's rollouts once."""
    t, e, en = (make_nu(kind, plant, K_expert, **variances) for kind in NU_KINDS)
    return [t, e, SharedSampler(e.draw, en.param)]
