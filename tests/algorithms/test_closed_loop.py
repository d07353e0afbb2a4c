"""The delayed closed-loop step (:mod:`loopid.algorithms.closed_loop`) and the key streams
(:mod:`loopid.algorithms.keys`).

Oracle: a hand-written FIFO of commands on a linear system, ``x' = A x + B u_applied + w``; under
``fifo`` the applied change is the command of d steps ago, under ``latency`` the controller sees
the state of d steps ago and its change acts at once. For a fixed gain both readings apply the
same changes, so their closed loops agree to round-off.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.closed_loop import DelayedLoop, check_delay_mode
from loopid.algorithms.keys import (
    EVALUATE,
    SELECT,
    TEST,
    TRAIN,
    iteration_key,
    iteration_keys,
    seed_keys,
    stream_key,
)

N, M, T = 3, 2, 12


def _system(rng):
    A = np.eye(N) + 0.05 * rng.normal(size=(N, N))
    B = rng.normal(size=(N, M))

    def step_delayed(x, fifo, du, w):
        """The systems' convention: the oldest pending change acts, ``du`` joins the FIFO."""
        if fifo.shape[0] == 0:
            return A @ x + B @ du + w, fifo
        applied = fifo[0]
        return A @ x + B @ applied + w, jnp.concatenate([fifo[1:], du[None]], axis=0)

    return A, B, step_delayed


def _fly(loop, K, step_delayed, W, x0):
    def body(carry, inp):
        x, memory = carry
        w, t = inp
        seen, _, memory = loop.sense(memory, x, t)
        du = -K @ seen
        x, memory = loop.act(step_delayed, x, memory, du, w)
        return (x, memory), (x, du)

    _, (X, dU) = jax.lax.scan(body, (x0, loop.memory0(N, M)), (W, jnp.arange(T)))
    return np.asarray(X), np.asarray(dU)


@pytest.mark.parametrize("d", [0, 1, 3])
def test_both_readings_fly_the_same_closed_loop_as_a_hand_written_fifo(d, rng):
    A, B, step_delayed = _system(rng)
    K = 0.3 * rng.normal(size=(M, N))
    W = 0.1 * rng.normal(size=(T, N))
    x0 = rng.normal(size=N)
    # the oracle: a Python loop with an explicit list of pending commands
    x, pending, X = x0.copy(), [np.zeros(M)] * d, []
    for t in range(T):
        command = -K @ x
        pending.append(command)
        applied = pending.pop(0)
        x = A @ x + B @ applied + W[t]
        X.append(x)
    X_fifo, _ = _fly(DelayedLoop("fifo", d), K, step_delayed, W, x0)
    X_latency, dU = _fly(DelayedLoop("latency", d), K, step_delayed, W, x0)
    np.testing.assert_allclose(X_fifo, np.array(X), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(X_latency, np.array(X), rtol=1e-12, atol=1e-12)
    assert np.all(dU[:d] == 0)  # latency: nothing observed yet, nothing done


def test_latency_sees_the_state_of_d_steps_ago_and_the_gain_of_that_time():
    loop = DelayedLoop("latency", 2)
    memory = loop.memory0(N, M)
    assert memory.shape == (2, N)
    seen_at = []
    for t in range(5):
        dx = jnp.full(N, float(t + 1))
        seen, t_gain, memory = loop.sense(memory, dx, t)
        seen_at.append((float(seen[0]), int(t_gain)))
    assert seen_at == [(0.0, 0), (0.0, 0), (1.0, 0), (2.0, 1), (3.0, 2)]
    fifo = DelayedLoop("fifo", 2)
    assert fifo.memory0(N, M, (7,)).shape == (2, M, 7)  # commands, a trailing batch axis
    dx = jnp.ones(N)
    seen, t_gain, memory = fifo.sense(fifo.memory0(N, M), dx, 4)
    assert seen is dx and t_gain == 4


def test_unknown_delay_mode_is_one_line():
    with pytest.raises(ValueError, match="delay_mode must be one of fifo, latency, got 'lag'"):
        check_delay_mode("lag")


def test_key_streams_are_distinct_and_documented():
    assert len({TRAIN, TEST, SELECT, EVALUATE}) == 4
    k = seed_keys(np.array([5]))[0]
    draws = {s: float(jax.random.normal(stream_key(k, s))) for s in (TRAIN, TEST, SELECT, EVALUATE)}
    assert len(set(draws.values())) == 4
    expected = jax.random.fold_in(jax.random.fold_in(jax.random.key(5), 1), 7)
    assert jnp.array_equal(jax.random.key_data(iteration_key(k, 7)), jax.random.key_data(expected))
    three = iteration_keys(k, 7)
    split = jax.random.split(expected, 3)
    for got, want in zip(three, split, strict=True):
        assert jnp.array_equal(jax.random.key_data(got), jax.random.key_data(want))
