"""A linear-Gaussian system ``x' = A x + B u + w`` (``w ~ N(0, std² I)``) as a loop system.

Inside the linear offset model class (realisable), so it is the system on which DAgger and Batch
must recover the true model and the optimal LQR cost. Error coordinates are ``[x − x*; 1]``.
"""

import jax
import jax.numpy as jnp
import numpy as np

from loopid.systems.base import Dynamics, Task


def linear_dynamics(A, B) -> Dynamics:
    """:class:`Dynamics` of ``x' = A x + B u + w``: ``A [k, k]``, ``B [k, m]``, noise ``[k]``."""
    A = jnp.asarray(A, jnp.float64)
    B = jnp.asarray(B, jnp.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or B.ndim != 2 or B.shape[0] != A.shape[0]:
        raise ValueError(f"A must be [k, k] and B [k, m], got {A.shape} and {B.shape}")
    k, m = B.shape

    def step_delayed(x, fifo, du, noise):
        queue = jnp.concatenate([fifo, du[None]], axis=0)
        return A @ x + B @ queue[0] + noise, queue[1:]

    def to_error(x, x_star):
        return jnp.concatenate([x - x_star, jnp.ones(1)])

    def from_error(dx, x_star):
        return x_star + dx[:-1]

    def noise_sequence(key, T, std):
        rows = jax.vmap(lambda t: jax.random.normal(jax.random.fold_in(key, t), (k,)))
        return std * rows(jnp.arange(T))

    return Dynamics(step_delayed, to_error, from_error, noise_sequence, k + 1, m)


def linear_task(Q, R, x0, horizon: int, *, noise_std: float = 1.0, name: str = "linear") -> Task:
    """A regulation task to the origin: ``Q [k, k]`` (padded with a zero row and column for the
    constant coordinate), ``R [m, m]``, start ``x0 [k]``, ``horizon`` actions."""
    Q = np.asarray(Q, np.float64)
    k = Q.shape[0]
    Qe = np.zeros((k + 1, k + 1))
    Qe[:k, :k] = Q
    target = jnp.zeros((horizon + 1, k), jnp.float64)
    return Task(
        name,
        target,
        float(noise_std),
        0,
        jnp.asarray(Qe),
        jnp.asarray(R, jnp.float64),
        jnp.asarray(x0, jnp.float64),
        False,
    )
