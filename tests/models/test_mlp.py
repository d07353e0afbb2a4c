"""The online MLP model (issue 19): ring buffer, Adam steps in one scan, seeds under vmap."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.models import LinearOffsetModel, MLPState, mlp_learner
from loopid.models import linear_offset as lo

N, M = 4, 1  # the pendulum's error state [cos θ − 1, sin θ, θ̇, 1] and torque
NOMINAL = LinearOffsetModel(jnp.eye(N), jnp.zeros((N, M)))


def _pendulum(rng, b):
    """Rows of a smooth pendulum (no clipping): θ̇' = θ̇ + 0.05(15 sin θ + 3u), θ' = θ + 0.05θ̇'."""
    th, w = rng.uniform(-np.pi, np.pi, b), rng.uniform(-4, 4, b)
    du = rng.uniform(-2, 2, (b, M))
    w2 = w + 0.05 * (15 * np.sin(th) + 3 * du[:, 0])
    th2 = th + 0.05 * w2

    def err(th, w):
        return np.stack([np.cos(th) - 1, np.sin(th), w, np.ones_like(w)], 1)

    return err(th, w), du, err(th2, w2)


def test_the_online_loss_falls_on_a_smooth_nonlinear_system(rng):
    """Before any data the model is exactly the nominal; over six updates of 100 rows the online
    loss (the current model on the next batch, before learning from it) falls by more than 100x,
    with minibatches and with the full buffer (batch=None). Measured (seed 0): 0.30 -> 1.0e-3
    (batch 64) and 0.32 -> 9.6e-4 (full buffer)."""
    for batch in (64, None):
        learner = mlp_learner(
            NOMINAL, hidden=(32, 32), lr=3e-3, steps=60, capacity=1000, batch=batch
        )
        state = learner.init(0)
        online = []
        for _ in range(6):
            dx, du, dx_next = _pendulum(rng, 100)
            loss = np.asarray(learner.loss(state, dx, du, dx_next))
            if not online:
                zero = lo.per_sample_loss(NOMINAL, np.zeros((N + M, N)), dx, du, dx_next)
                np.testing.assert_array_equal(loss, np.asarray(zero))
            online.append(loss.mean())
            state = learner.update(state, dx, du, dx_next)
        assert online[-1] < online[0] / 100, (batch, online)
        assert int(state.size) == 600 and float(state.seen) == 600.0
        assert np.isfinite(float(state.train_loss))


def test_jit_vmap_over_seeds_equals_one_at_a_time(rng):
    """jax.jit(jax.vmap(update)) over 3 seeds (own data each, partly masked) gives each seed's
    state as its own update does, to 1e-10."""
    learner = mlp_learner(NOMINAL, hidden=(16,), lr=1e-2, steps=20, capacity=64, batch=16)
    seeds = jnp.arange(3)
    states = jax.vmap(learner.init)(seeds)
    data = [_pendulum(rng, 3 * 40) for _ in range(2)]
    masks = [rng.random((3, 40)) < 0.7 for _ in range(2)]

    def split(a):
        return jnp.asarray(a).reshape(3, 40, -1)

    update = jax.jit(jax.vmap(learner.update))
    for (dx, du, dx_next), mask in zip(data, masks, strict=True):
        states = update(states, split(dx), split(du), split(dx_next), jnp.asarray(mask))
    for i in range(3):
        single = learner.init(int(seeds[i]))
        for (dx, du, dx_next), mask in zip(data, masks, strict=True):
            single = learner.update(single, split(dx)[i], split(du)[i], split(dx_next)[i], mask[i])
        batched = jax.tree.map(lambda a, i=i: a[i], states)
        for a, b in zip(jax.tree.leaves(batched), jax.tree.leaves(single), strict=True):
            if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
                a, b = jax.random.key_data(a), jax.random.key_data(b)
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-12)
    # different seeds, different networks
    assert not np.allclose(states.params[0][0][0], states.params[0][0][1])


def test_the_ring_buffer_keeps_the_latest_rows_in_order(rng):
    """Against an oracle that writes the kept rows one by one at slot head, head + 1, ... mod
    capacity: masked rows (NaN) are skipped, the oldest rows are overwritten, and a batch with
    more kept rows than the buffer leaves what writing them one by one would (its last
    `capacity` rows, none written twice); size, head and the unfilled slots agree."""
    capacity = 7
    learner = mlp_learner(NOMINAL, hidden=(4,), steps=1, capacity=capacity, batch=4)
    state: MLPState = learner.init(1)
    slots = [None] * capacity
    head = size = seen = most = 0
    for b in (3, 5, 2, 12, 0, 4):  # real rows, padded to 12 (fixed shapes, one compile)
        dx, du, dx_next = _pendulum(rng, 12)
        dx[:, 2] = np.arange(seen + 100, seen + 112)  # θ̇ labels the row
        mask = (rng.random(12) < 0.75) & (np.arange(12) < b)
        dx_next[~mask] = np.nan
        state = learner.update(state, dx, du, dx_next, mask)
        for label in dx[mask, 2]:  # the stream, row by row
            slots[head] = label
            head = (head + 1) % capacity
        kept = int(mask.sum())
        most = max(most, kept)
        state_head = int(state.head)
        seen += 12
        size = min(size + kept, capacity)
        assert int(state.size) == size and state_head == head
        labels = np.asarray(state.v)[:size, 2]
        np.testing.assert_array_equal(labels, np.array(slots[:size], dtype=float))
        assert np.all(np.isfinite(np.asarray(state.y))) and np.all(np.asarray(state.v)[size:] == 0)
    assert most > capacity  # the wrap within one batch was exercised
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree.leaves(state.params))


def test_dynamics_jacobian_and_constant_coordinate(rng):
    """The planner's f: jax.jacfwd equals central differences (time-varying nominal, traced t);
    it equals predict apart from the last entry, which is exactly 1."""
    base = LinearOffsetModel(np.eye(N) + 0.05 * rng.normal(size=(N, N)), rng.normal(size=(N, M)))
    model = lo.time_varying_nominal(base.A, base.B, 0.1 * rng.normal(size=(5, N)))
    learner = mlp_learner(model, hidden=(8, 8), steps=30, capacity=200, batch=32)
    dx, du, dx_next = _pendulum(rng, 120)
    t = rng.integers(0, 5, 120).astype(np.int32)
    state = learner.update(learner.init(2), dx, du, dx_next, t=t)
    f = jax.jit(learner.dynamics(state))
    x, u, s = dx[0], du[0], jnp.int32(3)
    Jx, Ju = jax.jacfwd(f, argnums=(0, 1))(x, u, s)
    h = 1e-6
    fd_x = np.stack([(f(x + h * e, u, s) - f(x - h * e, u, s)) / (2 * h) for e in np.eye(N)], 1)
    fd_u = np.stack([(f(x, u + h * e, s) - f(x, u - h * e, s)) / (2 * h) for e in np.eye(M)], 1)
    np.testing.assert_allclose(np.asarray(Jx), fd_x, atol=1e-7)
    np.testing.assert_allclose(np.asarray(Ju), fd_u, atol=1e-7)
    row = learner.predict(state, x[None], u[None], np.array([3], np.int32))[0]
    np.testing.assert_allclose(np.asarray(f(x, u, s))[:-1], np.asarray(row)[:-1], rtol=1e-12)
    assert float(f(x, u, s)[-1]) == 1.0


@pytest.mark.parametrize(
    ("settings", "word"),
    [
        ({"hidden": (0,)}, "hidden"),
        ({"hidden": "64"}, "hidden"),
        ({"hidden": (32, -1)}, "hidden"),
        ({"lr": 0.0}, "lr"),
        ({"lr": float("nan")}, "lr"),
        ({"steps": 0}, "steps"),
        ({"capacity": 0}, "capacity"),
        ({"batch": 0}, "batch"),
    ],
)
def test_bad_settings_raise_one_line(settings, word):
    with pytest.raises(ValueError, match=word) as info:
        mlp_learner(NOMINAL, **settings)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("kind", ["mlp", "features"])
def test_a_model_restored_from_its_saved_arrays_predicts_as_the_learned_one(rng, kind):
    """``ModelClass.restore(saved(state))`` (what ``loopid evaluate`` re-plans on for a run that
    flew MPC) gives the learned model's dynamics exactly, after two updates that moved it."""
    from loopid.algorithms.contracts import Transitions
    from loopid.algorithms.planning_agent import feature_model, mlp_model
    from loopid.learners import ftrl_least_squares
    from loopid.models.feature_maps import polynomial

    if kind == "mlp":
        mc = mlp_model(NOMINAL, mlp_learner(NOMINAL, hidden=(8,), lr=3e-3, steps=20, capacity=300))
    else:
        mc = feature_model(NOMINAL, polynomial(N, M, 3), ftrl_least_squares(1e-3))
    state = mc.init()
    for _ in range(2):
        dx, du, dx_next = _pendulum(rng, 100)
        rows = Transitions(dx, dx, du, dx_next, jnp.zeros(100, jnp.int32), jnp.ones(100, bool))
        state = mc.update(state, rows)
    saved = {k: np.asarray(v) for k, v in mc.saved(state).items()}
    dx, du, _ = _pendulum(rng, 5)
    learned = jax.vmap(lambda x, u: mc.dynamics(mc.params(state), x, u, 0))(dx, du)
    restored = jax.vmap(lambda x, u: mc.dynamics(mc.restore(saved), x, u, 0))(dx, du)
    np.testing.assert_array_equal(np.asarray(restored), np.asarray(learned))
    assert np.max(np.abs(np.asarray(learned) - np.asarray(dx))) > 1e-3  # it learned something
