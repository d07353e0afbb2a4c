"""Key streams: every random draw of a run, named once.

Seed ``s`` has the root key ``k = jax.random.key(s)`` (:func:`seed_keys`). Each use of
randomness draws from its own *stream*, ``fold_in(k, stream)`` (:func:`stream_key`), so that
adding draws to one use never shifts another's numbers:

======== ===== ==================================================================================
stream   value what it draws
======== ===== ==================================================================================
TRAIN    1     iteration n's training draws, ``fold_in(fold_in(k, 1), n)`` (:func:`iteration_key`),
               split into the policy's draws, ν's draws and the mixing (:func:`iteration_keys`)
TEST     2     the test trajectories' process noise, drawn once and reused at every iteration
               (every method sees the same test noise: common random numbers)
SELECT   3     ``test_policy = "best"``: the independent noise on which the best policy so far is
               selected (and the mixture's draw of a policy), so the reported cost is unbiased
EVALUATE 4     ``loopid evaluate``: fresh test noise the run never saw
======== ===== ==================================================================================

Systems that are not JAX functions (a Gymnasium env, :mod:`loopid.algorithms.gym_loop`) seed
their episodes from NumPy's ``SeedSequence([seed, n, stream])`` instead, with the streams
:data:`HOST_POLICY`, :data:`HOST_NU`, :data:`HOST_TEST` (n = 0: the same episodes at every
iteration), :data:`HOST_EVALUATE` and :data:`HOST_SELECT` (n = 0: the episodes on which
``test_policy = "best"`` selects). Their values are what runs have always used, so saved
tables stay reproducible.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

TRAIN, TEST, SELECT, EVALUATE = 1, 2, 3, 4
HOST_POLICY, HOST_NU, HOST_TEST, HOST_EVALUATE, HOST_SELECT = 1, 2, 3, 4, 5


def seed_keys(seeds) -> jax.Array:
    """One key per integer seed (``jax.random.key(seed)``), stacked ``[S]``."""
    seeds = np.asarray(seeds)
    if seeds.ndim != 1 or seeds.size == 0 or not np.issubdtype(seeds.dtype, np.integer):
        raise ValueError(f"seeds must be a non-empty list of integers, got {seeds!r}")
    if (seeds < 0).any():
        raise ValueError(f"seeds must be >= 0, got {seeds.tolist()}")
    return jax.vmap(jax.random.key)(jnp.asarray(seeds, dtype=jnp.uint32))


def stream_key(key: jax.Array, stream: int) -> jax.Array:
    """The key of one stream of a seed's root key: ``fold_in(k, stream)``."""
    return jax.random.fold_in(key, stream)


def iteration_key(key: jax.Array, n) -> jax.Array:
    """The key of iteration ``n``'s training draws of one seed: ``fold_in(fold_in(k, 1), n)``."""
    return jax.random.fold_in(stream_key(key, TRAIN), n)


class IterationKeys(NamedTuple):
    """Iteration n's three training keys of one seed: the policy's draws, ν's draws, the mix."""

    policy: jax.Array
    nu: jax.Array
    mix: jax.Array


def iteration_keys(key: jax.Array, n) -> IterationKeys:
    """:func:`iteration_key` split three ways (every loop's one key schedule)."""
    return IterationKeys(*jax.random.split(iteration_key(key, n), 3))
