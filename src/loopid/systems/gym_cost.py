"""The quadratic cost of a Gymnasium env's observed entries and actions (:class:`ObservationCost`,
built and checked by :func:`observation_cost`): the helicopter task's cost written on
observations, for a target observation ``o*`` [n_obs] and an operating action ``a_op`` [m]::

    c(o, a) = (o − o*)ᵀ Q (o − o*) + (a − a_op)ᵀ R (a − a_op),    Q [n_obs, n_obs], R [m, m]

In the loop's coordinates (:mod:`loopid.systems.from_gymnasium`: ``Δx = [o[observe] − o*; 1]``,
``Δu = a − a_op``) it is ``ΔxᵀQ_aug Δx + ΔuᵀRΔu`` with Q_aug zero on the constant coordinate
(:meth:`ObservationCost.augmented`), the quadratic cost every solver takes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["ObservationCost", "finite_vector", "observation_cost"]


class ObservationCost(NamedTuple):
    """The quadratic cost on an env's observed entries and actions (the helicopter task's cost,
    written on observations): ``c(o, a) = (o − o*)ᵀ Q (o − o*) + (a − a_op)ᵀ R (a − a_op)``.

    ``target`` [n_obs], ``Q`` [n_obs, n_obs], ``R`` [m, m], ``a_op`` [m]. Callable on one pair
    (returns a float) or on batches ``obs [..., n_obs]``, ``action [..., m]`` (returns ``[...]``).
    """

    target: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    a_op: np.ndarray

    def __call__(self, obs, action):
        e = np.asarray(obs, np.float64) - self.target
        d = np.asarray(action, np.float64) - self.a_op
        c = np.einsum("...i,ij,...j->...", e, self.Q, e) + np.einsum(
            "...i,ij,...j->...", d, self.R, d
        )
        return float(c) if np.ndim(c) == 0 else c

    def augmented(self) -> tuple[np.ndarray, np.ndarray]:
        """(Q_aug [n, n], R [m, m]): Q on ``Δx = [o − o*; 1]``, 0 on the constant coordinate."""
        n_obs = self.Q.shape[0]
        Qa = np.zeros((n_obs + 1, n_obs + 1))
        Qa[:n_obs, :n_obs] = self.Q
        return Qa, self.R


def _square(name: str, value, size: int) -> np.ndarray:
    """A [size, size] PSD matrix from a full matrix, a diagonal vector or a scalar."""
    M = np.asarray(value, dtype=np.float64)
    if M.ndim == 0:
        M = np.full(size, float(M))
    if M.ndim == 1:
        if M.shape != (size,):
            raise ValueError(
                f"{name} must have {size} diagonal entries or be {size}x{size}, got shape {M.shape}"
            )
        M = np.diag(M)
    if M.shape != (size, size):
        raise ValueError(
            f"{name} must be {size}x{size} (or {size} diagonal entries), got shape {M.shape}"
        )
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} must be finite, got {M.tolist()}")
    if not np.allclose(M, M.T) or np.linalg.eigvalsh((M + M.T) / 2).min() < -1e-12:
        raise ValueError(f"{name} must be symmetric positive semidefinite, got {M.tolist()}")
    return (M + M.T) / 2


def finite_vector(name: str, value, size: int) -> np.ndarray:
    """``value`` as ``size`` finite float64 numbers; ``ValueError`` naming ``name`` otherwise."""
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise ValueError(
            f"{name} must be {size} finite numbers, got {np.asarray(value).tolist()!r}"
        )
    return v


def observation_cost(target, Q, R, a_op=None) -> ObservationCost:
    """A checked :class:`ObservationCost`; ``Q``/``R`` may be full matrices, diagonals or scalars.

    Raises ValueError naming ``Q``, ``R``, ``target`` or ``a_op`` when a size does not match.
    """
    t = np.asarray(target, dtype=np.float64)
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"target must be a non-empty vector, got shape {t.shape}")
    t = finite_vector("target", t, t.size)
    Rm = np.asarray(R, dtype=np.float64)
    m = Rm.shape[0] if Rm.ndim >= 1 else (np.asarray(a_op).size if a_op is not None else 1)
    Qm = _square("Q", Q, t.size)
    Rm = _square("R", R, m)
    a = np.zeros(m) if a_op is None else finite_vector("a_op", a_op, m)
    return ObservationCost(t, Qm, Rm, a)
