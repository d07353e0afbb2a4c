"""The real system as the loop sees it: rollouts, generative queries and test evaluation.

A *plant* wraps a JAX system and its task (target trajectory, cost, noise, delay) into the three
pure operations that Algorithm 1 of Ross & Bagnell (2012) needs:

- ``rollout(K, key, action_std)``: run the affine policy ``u_t = −K_τ Δx_t (+ ε_t)`` from the start
  state μ for ``horizon`` steps, restarting from μ whenever a training trajectory leaves the safe
  region ``‖[Δx_{:−1}; Δu]‖₂ > stop_norm`` (the safe region) or the task horizon ends. Returns every
  step as a transition with a validity mask (fixed shape ``[horizon]``).
- ``query(x, du, t, key)``: the generative model: set the system to raw state ``x`` at target time
  ``t``, apply ``du``, observe ``x'`` (with delay d the pending FIFO holds ``du`` for
  ``nu_pending="hold"`` (and ``"rollout"``, whose ν_e/ν_en samples skip the query), zeros for
  ``"zero"``; under ``delay_mode="latency"`` a plain one-step query, ``x' = f(x, du)``).
- ``eval_noise(key, n_test)``: the process noise ``[n_test, horizon, n_noise]`` of ``n_test`` test
  trajectories (trajectory i from ``jax.random.split(key, n_test)[i]``).
- ``eval_costs(K, noise)``: the test trajectories driven by that noise over the whole target,
  no early stop; each total cost ``Σ Δx_tᵀQΔx_t + Σ Δu_tᵀRΔu_t`` is capped at ``cost_cap``, and
  one that reaches the cap or a non-finite state counts as diverged. No NaN leaves here.
  ``eval_seeds(K, noise)`` does the same for every seed at once.

Speed: the test trajectories are most of the loop's arithmetic (100 per seed and iteration in
the paper's protocol). ``eval_seeds`` runs all of them (every seed's) as one column batch,
``x [n_x, S·n_test]``, so each state component is a contiguous vector over the batch and one
``lax.scan`` step advances every trajectory; on a CPU this is 2.8x faster
(``benchmarks/sim.py``) than ``vmap`` of one trajectory (whose batch axis ends up leading, with
the n_x state components as the short minor axis). ``eval_one`` stays the plain one-trajectory
form: the mixture policy's path and the reference ``eval_seeds`` is tested against.

Policies are time-varying affine gains in error coordinates, ``K: [horizon, m, n]``: the error
state ends with the constant 1, so the last column of ``K_t`` is the feedforward term.

Two readings of a delay of d steps (``delay_mode``; each closed-loop step goes through
:class:`loopid.algorithms.closed_loop.DelayedLoop`):

- ``"fifo"``: the policy commands ``Δu_t = −K_t Δx_t`` and the simulator applies the
  change commanded d steps earlier (a FIFO of commands, zeros at the start). The learner records
  the commanded change, ``(x_t, Δu_t, x_{t+1})``, which is not Markov in ``x_t``.
- ``"latency"`` (the course code that ships the simulator): the policy acts on the error state
  observed d steps earlier, ``Δu_t = −K_{t−d} Δx_{t−d}`` (a FIFO of observations, zero vectors at
  the start, so ``Δu_t = 0`` for t < d), and its change acts at once, ``x_{t+1} = f(x_t, Δu_t)``.
  The learner records that true, Markov transition.

For any fixed gain both modes apply the same change at every step: the closed loop, and so the
test cost, is the same (the cost's ``ΔuᵀRΔu`` term sums the commanded changes under ``fifo`` and
the applied ones under ``latency``; they differ by the last d commands, ~1e-12 of a hover cost).
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.closed_loop import DelayedLoop, check_delay_mode
from loopid.algorithms.contracts import Transitions
from loopid.algorithms.transitions import clean
from loopid.systems.base import Dynamics, Task


class Plant(NamedTuple):
    """The operations of one real JAX system and task (module docstring); pure and jittable.
    Implements :class:`LoopPlant`."""

    task: Task
    horizon: int
    n_state: int
    n_action: int
    rollout: Callable[..., Transitions]
    query: Callable[..., Transitions]
    eval_one: Callable[..., tuple[jax.Array, jax.Array]]
    eval_seeds: Callable[..., tuple[jax.Array, jax.Array]]
    noise_std: float
    dynamics: Dynamics
    delay_mode: str = "fifo"
    nu_pending: str = "hold"
    stop_norm: float = 5.0
    cost_cap: float = 1e8

    def eval_noise(self, key: jax.Array, n_test: int) -> jax.Array:
        """Process noise ``[n_test, horizon, n_noise]`` of ``n_test`` test trajectories."""
        keys = jax.random.split(key, n_test)
        sequence = self.dynamics.noise_sequence
        return jax.vmap(lambda k: sequence(k, self.horizon, self.noise_std))(keys)

    def eval_costs(self, K: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Capped costs ``[n_test]`` and diverged flags of the test trajectories of ``K`` driven by
        ``noise [n_test, horizon, n_noise]`` (the same noise for every policy: common random
        numbers)."""
        costs, diverged = self.eval_seeds(K[None], noise_columns(noise[None]))
        return costs[0], diverged[0]


def column_ops(dynamics: Dynamics) -> tuple[Callable, Callable]:
    """``(step_columns, error_columns)``: the system's ``step_delayed`` and ``to_error`` on column
    batches (``x [n_x, b]``, ``fifo [d, m, b]``, ``du [m, b]``, ``w [n_noise, b]``, an unbatched
    target): the functions themselves when the system takes columns (``dynamics.columns``),
    otherwise ``jax.vmap`` of them over the trailing axis (same numbers, slower on a CPU)."""
    if dynamics.columns:
        return dynamics.step_delayed, dynamics.to_error
    step = jax.vmap(dynamics.step_delayed, in_axes=-1, out_axes=-1)
    error = jax.vmap(dynamics.to_error, in_axes=(-1, None), out_axes=-1)
    return step, error


def noise_columns(noise: jax.Array) -> jax.Array:
    """Test noise ``[S, n_test, horizon, n_noise]`` (per seed, per trajectory) in the layout of
    :meth:`Plant.eval_seeds`, ``[horizon, n_noise, S, n_test]``."""
    return jnp.moveaxis(noise, (0, 1), (-2, -1))


def make_plant(
    task: Task,
    dynamics: Dynamics,
    *,
    stop_norm: float = 5.0,
    nu_pending: str = "hold",
    cost_cap: float = 1e8,
    delay_mode: str = "fifo",
) -> Plant:
    """A JAX system (:class:`loopid.systems.base.Dynamics`) under ``task`` as a :class:`Plant`.

    Args:
      task: a :class:`loopid.systems.base.Task` (target ``[T, k]``, noise std, delay, Q, R, x0).
      dynamics: the system's step, error coordinates and noise.
      stop_norm: training trajectories restart from μ when ``‖[Δx_{:−1}; Δu]‖₂ > stop_norm``.
      nu_pending: delayed-query convention for ν samples under ``fifo``: ``"hold"``, ``"zero"``
        or ``"rollout"`` (:data:`NU_PENDING`).
      cost_cap: a test trajectory's total cost is capped here and then counts as diverged.
      delay_mode: ``"fifo"`` or ``"latency"`` (module docstring;
        :data:`~loopid.algorithms.closed_loop.DELAY_MODES`).
    """
    check_delay_reading(delay_mode, nu_pending)
    if not stop_norm > 0:
        raise ValueError(f"stop_norm must be > 0, got {stop_norm!r}")
    if not cost_cap > 0:
        raise ValueError(f"cost_cap must be > 0, got {cost_cap!r}")
    target = jnp.asarray(task.target, dtype=jnp.float64)
    x0 = jnp.asarray(task.x0, dtype=jnp.float64)
    d = int(task.delay)
    std = float(task.noise_std)
    horizon = int(target.shape[0]) - 1
    m = dynamics.n_action
    n = dynamics.n_error
    step_delayed, to_error = dynamics.step_delayed, dynamics.to_error
    loop = DelayedLoop(delay_mode, d)
    latency = loop.latency
    fifo0 = jnp.zeros((d, m), dtype=jnp.float64)
    # what the controller remembers between steps: commands (fifo) or observations (latency)
    memory0 = loop.memory0(n, m)
    quad_Q, quad_R = quadratic_form(task.Q), quadratic_form(task.R)
    step_columns, error_columns = column_ops(dynamics)

    def rollout(K: jax.Array, key: jax.Array, action_std: float | jax.Array = 0.0) -> Transitions:
        """One training run of ``horizon`` steps with restarts; ``K: [horizon, m, n]``."""
        k_noise, k_act = jax.random.split(key)
        noise = dynamics.noise_sequence(k_noise, horizon, std)
        eps = action_std * jax.random.normal(k_act, (horizon, m), dtype=jnp.float64)

        def body(carry, inp):
            x, memory, tau = carry
            w, e = inp
            dx = to_error(x, target[tau])
            seen, tau_gain, memory = loop.sense(memory, dx, tau)
            du = -K[tau_gain] @ seen + e
            size = jnp.linalg.norm(jnp.concatenate([dx[:-1], du]))
            safe = jnp.isfinite(size) & (size <= stop_norm)
            x_next, memory_next = loop.act(step_delayed, x, memory, du, w)
            dx_next = to_error(x_next, target[tau + 1])
            restart = ~safe | (tau + 1 >= horizon)
            carry = (
                jnp.where(restart, x0, x_next),
                jnp.where(restart, memory0, memory_next),
                jnp.where(restart, 0, tau + 1),
            )
            return carry, Transitions(x, dx, du, dx_next, tau, safe)

        _, tr = jax.lax.scan(body, (x0, memory0, jnp.int32(0)), (noise, eps))
        return clean(tr)

    def query(x: jax.Array, du: jax.Array, t: jax.Array, key: jax.Array) -> Transitions:
        """One generative query at raw state ``x``, change ``du``, target time ``t`` (unbatched)."""
        w = dynamics.noise_sequence(key, 1, std)[0]
        if latency:  # a plain one-step query
            fifo = jnp.zeros((0, m), dtype=jnp.float64)
        else:
            fifo = fifo0 if nu_pending == "zero" else jnp.broadcast_to(du, (d, m))
        x_next, _ = step_delayed(x, fifo, du, w)
        dx = to_error(x, target[t])
        dx_next = to_error(x_next, target[t + 1])
        one = Transitions(x[None], dx[None], du[None], dx_next[None], t[None], jnp.ones(1, bool))
        return jax.tree_util.tree_map(lambda a: a[0], clean(one))

    def gain(K_t: jax.Array, dx: jax.Array) -> jax.Array:
        """``−K_t dx`` ``[m]`` of ``K_t [m, n]``, ``dx [n]``, summed j = 0, 1, ..., n − 1."""
        return -sum(K_t[:, j] * dx[j] for j in range(n))

    def eval_one(K: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Capped total cost and diverged flag of one test trajectory of ``K`` under process
        noise ``[horizon, n_noise]``. Its sums run in the fixed orders of :func:`eval_seeds`
        (``du`` term by term over the n error coordinates, the costs by :func:`ordered_sum`),
        so that a vmapped batch of it (the mixture policy's path) gives each trajectory the
        same bits at any batch size (a batched ``@`` need not)."""

        def body(carry, inp):
            x, memory, total = carry
            w, tau = inp
            dx = to_error(x, target[tau])
            seen, tau_gain, memory = loop.sense(memory, dx, tau)
            du = gain(K[tau_gain], seen)
            x, memory = loop.act(step_delayed, x, memory, du, w)
            total = total + quad_Q(dx) + quad_R(du)
            return (x, memory, total), None

        taus = jnp.arange(horizon, dtype=jnp.int32)
        (x, _, total), _ = jax.lax.scan(body, (x0, memory0, jnp.float64(0.0)), (noise, taus))
        dx = to_error(x, target[horizon])
        total = total + quad_Q(dx)
        diverged = ~jnp.isfinite(total) | (total >= cost_cap)
        return jnp.where(diverged, cost_cap, total), diverged

    def eval_seeds(K: jax.Array, W: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Capped costs and diverged flags ``[S, n_test]`` of every seed's test trajectories: seed
        s runs ``K[s]`` (``K [S, horizon, m, n]``) under the noise ``W[:, :, s]`` of
        ``W [horizon, n_noise, S, n_test]`` (:func:`noise_columns`: time-major, so the scan
        reads it without a copy). The same numbers as :func:`eval_one` on each trajectory."""
        S, n_test = W.shape[2:]
        b = S * n_test  # one flat batch: trajectory i of seed s is column s·n_test + i
        if latency:  # step τ uses the gain of the observed step τ − d
            K = K[:, jnp.maximum(jnp.arange(horizon) - d, 0)]
        Kc = jnp.moveaxis(K, 0, -1)  # [horizon, m, n, S]
        x = jnp.broadcast_to(x0[:, None], (x0.shape[0], b))
        memory = loop.memory0(n, m, (b,))

        def body(carry, inp):
            x, memory, total = carry
            w, K_t, tau = inp
            dx = error_columns(x, target[tau])
            seen, _, memory = loop.sense(memory, dx, tau)  # K_t is already the gain's time
            dx_s = seen.reshape(n, S, n_test)
            du = -sum(K_t[:, j, :, None] * dx_s[j] for j in range(n)).reshape(m, b)
            total = total + quad_Q(dx) + quad_R(du)
            x, memory = loop.act(step_columns, x, memory, du, w.reshape(-1, b))
            return (x, memory, total), None

        taus = jnp.arange(horizon, dtype=jnp.int32)
        total = jnp.zeros(b, jnp.float64)
        (x, _, total), _ = jax.lax.scan(body, (x, memory, total), (W, Kc, taus))
        total = (total + quad_Q(error_columns(x, target[horizon]))).reshape(S, n_test)
        diverged = ~jnp.isfinite(total) | (total >= cost_cap)
        return jnp.where(diverged, cost_cap, total), diverged

    return Plant(
        task, horizon, n, m, rollout, query, eval_one, eval_seeds, std, dynamics, delay_mode,
        nu_pending, float(stop_norm), float(cost_cap),
    )  # fmt: skip


#: Delayed ν queries under ``fifo``: the pending FIFO filled with the queried
#: action, left empty (zeros), or no query for ν_e/ν_en (the expert's own recorded transitions).
NU_PENDING = ("hold", "zero", "rollout")


def check_delay_reading(delay_mode: str, nu_pending: str) -> None:
    """Raise ``ValueError`` (one line) for an unknown ``delay_mode`` or ``nu_pending``, or a
    ``nu_pending`` other than ``hold`` under ``latency`` (whose ν queries are plain one-step
    queries: nothing is pending)."""
    check_delay_mode(delay_mode)
    if nu_pending not in NU_PENDING:
        raise ValueError(f"nu_pending must be one of {', '.join(NU_PENDING)}, got {nu_pending!r}")
    if delay_mode == "latency" and nu_pending != "hold":
        raise ValueError(
            f"nu_pending applies to delay_mode 'fifo' only (latency queries are plain one-step "
            f"queries), got nu_pending={nu_pending!r} with delay_mode='latency'"
        )


#: :func:`ordered_sum` unrolls an axis this short (or halved to this length) into row slices.
_UNROLL = 64


def ordered_sum(x, axis: int = 0) -> jax.Array:
    """The sum of ``x`` over ``axis`` (that axis removed) in one fixed order, whatever the other
    axes' sizes: pairwise halving, ``s_i ← s_i + s_{i+h}`` for i < h = ⌊len/2⌋ (an odd last
    element carried along) until one element is left; ``len − 1`` elementwise adds in all.

    Why not ``jnp.sum``: XLA's CPU backend picks its reduction loop (vectorised, tiled) from the
    whole shape, so the order in which a column's terms are added, and so the sum's last bit,
    depends on how many columns sit beside it. Measured: ``jnp.sum(v, axis=0)`` over the 21 rows
    of ``[21, b]`` differs in ~1 of 3 columns between b = 1400 and b = 2000 or 4000, and
    ``jnp.mean(c, axis=1)`` over the 100 columns of ``c [S, 100]`` changes from S = 41 on. Here
    every step is an elementwise add, which XLA does not reassociate, so a column's (a seed's) sum
    is the same number in any batch (so the experiment pipeline may split seeds into chunks).

    Speed: an axis of at most :data:`_UNROLL` (a longer one first halved as whole arrays down to
    it) is unrolled into row slices (:func:`halving_sum`); elementwise adds of slices fuse into
    one loop. The test rollouts' cost (:func:`quadratic_form`) builds its terms one by one and
    sums them with :func:`halving_sum`: ``eval_seeds`` then takes 0.95x the time it took with
    ``jnp.sum``, where halving whole arrays (slices and a concatenation per level) took 1.1x and
    ``ordered_sum`` of the ``[21, b]`` product array 1.2x (hover-delay, 20 seeds x 100
    trajectories, alternating in one process, best of 11)."""
    x = jnp.asarray(x)
    axis = axis % x.ndim
    n = x.shape[axis]
    if n == 0:
        return jnp.zeros(x.shape[:axis] + x.shape[axis + 1 :], x.dtype)
    while n > _UNROLL:
        h = n // 2
        pair = jax.lax.slice_in_dim(x, 0, h, axis=axis) + jax.lax.slice_in_dim(
            x, h, 2 * h, axis=axis
        )
        if n % 2:
            pair = jnp.concatenate([pair, jax.lax.slice_in_dim(x, 2 * h, n, axis=axis)], axis)
        x, n = pair, h + n % 2
    return halving_sum([jax.lax.index_in_dim(x, i, axis, keepdims=False) for i in range(n)])


def halving_sum(terms: list) -> jax.Array:
    """``terms[0] + ... + terms[n−1]`` (arrays of one shape) in :func:`ordered_sum`'s order:
    ``t_i ← t_i + t_{i+h}`` for i < h = ⌊n/2⌋, an odd last term carried, until one is left."""
    while len(terms) > 1:
        h = len(terms) // 2
        terms = [terms[i] + terms[i + h] for i in range(h)] + terms[2 * h :]
    return terms[0]


def quadratic_form(M) -> Callable[[jax.Array], jax.Array]:
    """``v ↦ vᵀ M v`` over the leading axis of ``v [k, *B]`` (-> ``[*B]``); a diagonal ``M`` (the
    usual cost weights, checked here on the concrete matrix) costs k products instead of k².

    Both sums run in a fixed order (:func:`ordered_sum`), so a column's value does not depend
    on the batch ``*B`` beside it: a trajectory's test cost is the same bits in a chunk of 14
    seeds as in one of 40."""
    M_np = np.asarray(M, np.float64)
    if np.array_equal(M_np, np.diag(np.diag(M_np))):
        w = np.diag(M_np)  # the terms w_i v_i² one by one: XLA fuses them with their sum
        return lambda v: halving_sum([w[i] * v[i] * v[i] for i in range(w.size)])
    M_j = jnp.asarray(M_np)

    def quad(v):  # (M v)_i = Σ_j M_ij v_j, then Σ_i v_i (M v)_i
        Mv = ordered_sum(M_j.reshape(M_j.shape + (1,) * (v.ndim - 1)) * v[None], axis=1)
        return ordered_sum(v * Mv, axis=0)

    return quad
