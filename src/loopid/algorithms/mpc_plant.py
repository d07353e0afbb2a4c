"""Model-predictive control flown on a JAX plant: the loop's MPC, one compiled
program over seeds.

:func:`mpc_plant` turns a :class:`~loopid.algorithms.plant.Plant`, whose policies are gains
``K [horizon, m, n]``, into one whose policy is a learned model's parameters ``P`` (any pytree)
flown by receding-horizon iLQR on that model (:mod:`loopid.control.mpc`): every ``every`` steps
the controller plans ``H`` steps ahead from the current error state ``Δx_τ`` at time τ,
warm-started from its previous plan shifted by ``every`` steps, and between re-plans applies the
plan's feedback ``Δu = U_j − K_j(Δx − X_j)`` (j = steps since the plan). Everything else is the
plant's: the system's step, the delay FIFO (under ``fifo`` the command acts d steps later, as
for gains), the noise, the safe region, the cost and its cap (:mod:`loopid.algorithms.plant`).
The loop flies it through :func:`loopid.algorithms.loop_program.make_loop_program`'s ``controller``
(the seed's model parameters), so one ``jit`` holds the planner, every seed and every test
trajectory.

Shape of the computation: an episode is ``⌈horizon / every⌉`` *blocks*; a block plans once and
then runs ``every`` steps of the plant (a ``lax.scan`` inside a ``lax.scan``). Under ``vmap`` a
``cond`` that re-plans only when due would run the planner at every step, so the blocks are
fixed instead: steps past the task horizon in the last block change nothing and cost nothing.

Training rollouts restart from μ when a trajectory leaves the safe region or reaches the
horizon, as the gains' do, but a restart waits for the end of its block (the plan is made at a
block's start): the block's remaining steps are *idle*, masked and not recorded. A rollout
has ``⌈horizon / every⌉·every`` rows, at least ``horizon``.

Cost (measured in ``benchmarks/nonlinear.py``): a test trajectory plans ``⌈horizon / every⌉``
times, each plan ``iterations`` iLQR iterations (times 1 + the number of alternatives) over H
steps of the model, so MPC's tests cost far more than flying gains; size ``test_trajectories``
and ``every`` for it.

Not supported (one-line ``ValueError``): ``delay_mode = "latency"`` with a delay (the
controller would plan from an observation d steps old; the gains' reading of it has no MPC
counterpart here yet).
"""

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from loopid.algorithms.closed_loop import DelayedLoop
from loopid.algorithms.contracts import Transitions
from loopid.algorithms.plant import Plant, quadratic_form
from loopid.algorithms.transitions import clean
from loopid.control.mpc import Replanner, empty_plan, local_action, replan


class MPCPlant(NamedTuple):
    """:func:`mpc_plant`'s result: ``plant``, the loop's :class:`Plant` flown by MPC, and
    ``flight(P, noise [horizon, n_noise]) -> (X [horizon + 1, n_x], total cost)``, one test
    trajectory's raw states (what ``trajectories.png`` and ``loopid animate`` draw)."""

    plant: Plant
    flight: Callable[..., tuple[jax.Array, jax.Array]]


def mpc_plant(plant: Plant, planner: Replanner) -> MPCPlant:
    """``plant`` flown by MPC (module docstring): the returned plant's ``rollout``, ``eval_one``
    and ``eval_seeds`` take the model's parameters ``P`` (``[S, ...]`` leaves for
    ``eval_seeds``) where ``plant``'s take gains; ``query`` and ``eval_noise`` are ``plant``'s.

    ``planner``: :func:`loopid.control.mpc.replanner` of the learned model
    ``(P, Δx [n], Δu [m], t) -> Δx'`` and the plan's cost, in the plant's error coordinates
    (``n = plant.n_state``, ``m = plant.n_action``). The safe region and the cost cap are the
    plant's (``plant.stop_norm``, ``plant.cost_cap``).
    """
    task, dynamics = plant.task, plant.dynamics
    if plant.delay_mode == "latency" and int(task.delay) > 0:
        raise ValueError(
            f"MPC flies delay_mode 'fifo' only; delay_mode 'latency' with delay {task.delay} "
            "would plan from an observation that many steps old"
        )
    n, m = plant.n_state, plant.n_action
    if planner.U0.shape[1] != m:
        raise ValueError(f"the planner's actions have {planner.U0.shape[1]} entries, not {m}")
    target = jnp.asarray(task.target, jnp.float64)
    x0 = jnp.asarray(task.x0, jnp.float64)
    d, std, horizon, every = int(task.delay), float(task.noise_std), plant.horizon, planner.every
    blocks = -(-horizon // every)
    length = blocks * every
    loop = DelayedLoop("fifo", d)  # the only reading MPC flies with a delay (at d = 0 both agree)
    memory0 = loop.memory0(n, m)
    step_delayed, to_error = dynamics.step_delayed, dynamics.to_error
    quad_Q, quad_R = quadratic_form(task.Q), quadratic_form(task.R)
    stop_norm, cost_cap = plant.stop_norm, plant.cost_cap

    def blocked(a: jax.Array) -> jax.Array:
        """Per-step inputs ``[horizon or length, ...]`` -> ``[blocks, every, ...]``, zero-padded."""
        pad = jnp.zeros((length - a.shape[0], *a.shape[1:]), a.dtype)
        return jnp.concatenate([a, pad]).reshape(blocks, every, *a.shape[1:])

    def flight(params: Any, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """One MPC test trajectory under process noise ``[horizon, n_noise]``: its raw states
        ``X [horizon + 1, n_x]`` and its total cost (uncapped)."""

        def block(carry, inp):
            x, memory, total, previous = carry
            w, b = inp
            t0 = b * every
            plan = replan(planner, params, to_error(x, target[t0]), t0, previous, b == 0)

            def step(carry, inp):
                x, memory, total = carry
                w, j = inp
                tau = t0 + j
                live = tau < horizon
                dx = to_error(x, target[jnp.minimum(tau, horizon)])
                du = local_action(planner, plan, dx, j)
                x_next, memory_next = loop.act(step_delayed, x, memory, du, w)
                total = total + jnp.where(live, quad_Q(dx) + quad_R(du), 0.0)
                x = jnp.where(live, x_next, x)
                memory = jnp.where(live, memory_next, memory)
                return (x, memory, total), x

            (x, memory, total), X = jax.lax.scan(step, (x, memory, total), (w, jnp.arange(every)))
            return (x, memory, total, plan), X

        carry = (x0, memory0, jnp.float64(0.0), empty_plan(planner, n))
        inputs = (blocked(noise), jnp.arange(blocks))
        (x, _, total, _), X = jax.lax.scan(block, carry, inputs)
        X = jnp.concatenate([x0[None], X.reshape(length, -1)[:horizon]])
        return X, total + quad_Q(to_error(x, target[horizon]))

    def eval_one(params: Any, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Capped total cost and diverged flag of one MPC test trajectory under process noise
        ``[horizon, n_noise]`` (the plant's cost, summed as its ``eval_one`` sums it)."""
        _, total = flight(params, noise)
        diverged = ~jnp.isfinite(total) | (total >= cost_cap)
        return jnp.where(diverged, cost_cap, total), diverged

    def eval_seeds(params: Any, W: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Capped costs and diverged flags ``[S, n_test]``: seed s flies its parameters
        ``params[s]`` under each of its test noises ``W[:, :, s, i]`` (``W [horizon, n_noise, S,
        n_test]``, :func:`~loopid.algorithms.plant.noise_columns`)."""
        trajectories = jax.vmap(eval_one, in_axes=(None, -1))
        return jax.vmap(trajectories, in_axes=(0, 2))(params, W)

    def rollout(params: Any, key: jax.Array, action_std: float | jax.Array = 0.0) -> Transitions:
        """One training run of ``length`` steps with restarts (module docstring); the action
        noise ``ε ~ N(0, action_std²)`` is added to each planned change."""
        k_noise, k_act = jax.random.split(key)
        noise = dynamics.noise_sequence(k_noise, length, std)
        eps = action_std * jax.random.normal(k_act, (length, m), dtype=jnp.float64)

        def block(carry, inp):
            x, memory, tau, previous, fresh = carry
            w, e = inp
            t0 = tau
            plan = replan(planner, params, to_error(x, target[t0]), t0, previous, fresh)

            def step(carry, inp):
                x, memory, tau, idle = carry
                w, e, j = inp
                dx = to_error(x, target[tau])
                du = local_action(planner, plan, dx, j) + e
                size = jnp.linalg.norm(jnp.concatenate([dx[:-1], du]))
                safe = jnp.isfinite(size) & (size <= stop_norm)
                x_next, memory_next = loop.act(step_delayed, x, memory, du, w)
                dx_next = to_error(x_next, target[tau + 1])
                end = ~idle & (~safe | (tau + 1 >= horizon))
                go = ~idle & ~end
                row = Transitions(x, dx, du, dx_next, tau, safe & ~idle)
                carry = (
                    jnp.where(go, x_next, x),
                    jnp.where(go, memory_next, memory),
                    jnp.where(go, tau + 1, tau),
                    idle | end,
                )
                return carry, row

            inner = (w, e, jnp.arange(every))
            (x, memory, tau, idle), rows = jax.lax.scan(
                step, (x, memory, tau, jnp.bool_(False)), inner
            )
            carry = (
                jnp.where(idle, x0, x),
                jnp.where(idle, memory0, memory),
                jnp.where(idle, 0, tau),
                plan,
                idle,
            )
            return carry, rows

        carry = (x0, memory0, jnp.int32(0), empty_plan(planner, n), jnp.bool_(True))
        _, rows = jax.lax.scan(block, carry, (blocked(noise), blocked(eps)))
        return clean(jax.tree_util.tree_map(lambda a: a.reshape(length, *a.shape[2:]), rows))

    return MPCPlant(plant._replace(rollout=rollout, eval_one=eval_one, eval_seeds=eval_seeds),
                    flight)  # fmt: skip
