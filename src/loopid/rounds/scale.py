"""Rounds that do not depend on the log's units: each column in units of its first round's spread.

FTRL's regulariser (the ridge ``λ√N ‖W‖²`` on the summed loss, :mod:`loopid.rounds.api`) is
absolute: it pulls every coefficient toward the nominal model by the same amount whatever the
units of its column. Logged in radians, a tilt of 0.01-0.05 gives sums ``ZᵀZ`` so small that
``λ√N`` dominates them and shrinks the fitted model; logged in degrees, the same physics is
barely touched. So under ``[rounds] scale = "std"`` (the default) the model is fitted and solved
in scaled coordinates, and only the controller and the model written out are in the log's units.

The scale, fixed by the first update and recorded in ``state.npz`` (and shown in ``round.md``):

- ``s_x [n_obs]``, ``s_u [m]``: the standard deviation (population, ``ddof = 0``) of each state
  and each action column over the first round's rows, policy and ν together (a next state
  ``next_s`` takes the scale of ``s``);
- a column with no spread (standard deviation 0, or at most ``1e-12`` of the column's largest
  magnitude: constant to rounding) keeps unit scale, and the column is named as such;
- with ``[system] action_limit`` (one bound for every action) the actions share one scale: the
  standard deviation of all their entries together;
- with a ``[planner] cost`` function (written in the log's units) every column keeps unit scale.

With ``D_x = diag(s_x, 1)`` (the constant entry of ``Δx = [o − o*; 1]`` is not scaled) and
``D_u = diag(s_u)``, the scaled coordinates are ``Δx_s = D_x⁻¹ Δx``, ``Δu_s = D_u⁻¹ Δu``. Every
setting in the log's units is carried over (:func:`scaled_config`): ``o*``, ``[planner] start``
``/ s_x``; ``a_op``, ``[planner] alternatives`` ``/ s_u``; ``Q_s = D Q D``, ``R_s = D_u R D_u``;
the nominal ``A_s = D_x⁻¹ A D_x``, ``B_s = D_x⁻¹ B D_u``; ``action_limit / s_u``. Features'
``bandwidth`` and the MLP's inputs are then in scaled units too. Back in the log's units
(:func:`log_gains`, :func:`log_model`): ``K = D_u K_s D_x⁻¹``, ``A = D_x A_s D_x⁻¹``,
``B = D_x B_s D_u⁻¹``.

Why this is invariant: changing the unit of a column by a factor ``c`` (and ``Q``, ``R`` and the
target to match) multiplies its standard deviation by ``c``, so the scaled rows and settings are
the same numbers to rounding, and so are the fit, the solve and ``K_s``; the action for a
physical state is the same to rounding. ``[rounds] scale = "none"`` keeps the log's units (the
regulariser absolute: the Gymnasium family's and the paper's λ/√n on the mean loss, exactly).

A round directory whose ``state.npz`` predates the scale and already learned from data keeps
unit scale (its learner's sums are in the log's units; rescaling them mid-run would change the
model and the online loss it was measured by), and ``round.md`` says so.
"""

from dataclasses import replace
from typing import NamedTuple

import numpy as np

#: A column whose standard deviation is at most this fraction of its largest magnitude has no
#: spread (constant to rounding): it keeps unit scale.
FLAT = 1e-12


class Scale(NamedTuple):
    """The units a round directory fits in.

    Attributes:
      states, actions: ``s_x [n_obs]``, ``s_u [m]`` (the log's unit per scaled unit).
      note: why every column keeps unit scale (empty when the first round set them).
      flat: the names of the columns with no spread in the first round (unit scale).
    """

    states: np.ndarray
    actions: np.ndarray
    note: str = ""
    flat: tuple = ()

    def to_json(self) -> dict:
        return {
            "states": self.states.tolist(), "actions": self.actions.tolist(),
            "note": self.note, "flat": list(self.flat),
        }  # fmt: skip

    @classmethod
    def from_json(cls, d: dict) -> "Scale":
        return cls(
            np.asarray(d["states"], np.float64), np.asarray(d["actions"], np.float64),
            str(d["note"]), tuple(d["flat"]),
        )  # fmt: skip

    @property
    def unit(self) -> bool:
        return bool(np.all(self.states == 1.0) and np.all(self.actions == 1.0))


def unit(config, note: str) -> Scale:
    """Unit scale on every column, for the reason ``note``."""
    return Scale(np.ones(config.n_obs), np.ones(config.m), note)


def _spread(v: np.ndarray) -> float | None:
    """The standard deviation of ``v``, None when it has no spread (module docstring)."""
    s = float(np.std(v))
    return s if s > FLAT * float(np.max(np.abs(v))) and np.isfinite(s) else None


def from_rows(x: np.ndarray, u: np.ndarray, config) -> Scale:
    """The scale set by the first round's states ``x [b, n_obs]`` and actions ``u [b, m]``."""
    if config.scale == "none":
        return unit(config, '`[rounds] scale = "none"`: the log\'s units')
    if config.planner_cost is not None:
        return unit(config, "a `[planner] cost` function is written in the log's units")
    flat = []
    states = []
    for name, col in zip(config.states, x.T, strict=True):
        s = _spread(col)
        flat += [name] if s is None else []
        states.append(s or 1.0)
    if config.action_limit is None:
        cols = list(zip(config.actions, u.T, strict=True))
    else:  # one bound for every action: one scale for them all
        cols = [(", ".join(config.actions), u.ravel())]
    actions = []
    for name, col in cols:
        s = _spread(col)
        flat += [name] if s is None else []
        actions.append(s or 1.0)
    actions = np.broadcast_to(np.asarray(actions), (config.m,)).copy()
    return Scale(np.asarray(states, np.float64), actions, "", tuple(flat))


def _dx(scale: Scale) -> np.ndarray:
    return np.append(scale.states, 1.0)


def _similar(M, d_out: np.ndarray, d_in: np.ndarray, n_obs: int) -> list:
    """``diag(d_out)⁻¹ M diag(d_in)`` for ``M`` given ``[n_obs, ·]`` or ``[n_obs + 1, ·]``."""
    M = np.asarray(M, np.float64)
    d_out = d_out[: M.shape[-2]] if M.shape[-2] in (n_obs, n_obs + 1) else d_out
    d_in = d_in[: M.shape[-1]] if M.shape[-1] in (n_obs, n_obs + 1) else d_in
    return (M * d_in[None, :] / d_out[:, None]).tolist()


def _quadratic(M, d: np.ndarray) -> list:
    """``D M D`` for ``M`` a scalar (``M I``), a diagonal or a full matrix."""
    M = np.asarray(M, np.float64)
    if M.ndim == 0:
        return (float(M) * d**2).tolist()
    if M.ndim == 1:
        return (M * d**2).tolist()
    return (M * np.outer(d, d)).tolist()


def scaled_config(config, scale: Scale):
    """``config`` with every setting in the log's units carried to the scaled coordinates
    (module docstring); ``config`` itself under unit scale."""
    if scale.unit:
        return config
    sx, su, dx = scale.states, scale.actions, _dx(scale)
    n_obs = config.n_obs
    changes = {
        "target": (np.asarray(config.target) / sx).tolist(),
        "action_op": (np.asarray(config.action_op) / su).tolist(),
        "Q": _quadratic(config.Q, sx), "R": _quadratic(config.R, su),
    }  # fmt: skip
    if config.A is not None:
        changes["A"] = _similar(config.A, dx, dx, n_obs)
    if config.B is not None:
        changes["B"] = _similar(config.B, dx, su, n_obs)
    if config.action_limit is not None:
        changes["action_limit"] = float(config.action_limit / su[0])
    if config.planner_start is not None:
        changes["planner_start"] = (np.asarray(config.planner_start) / sx).tolist()
    if config.planner_alternatives is not None:
        changes["planner_alternatives"] = (np.asarray(config.planner_alternatives) / su).tolist()
    return replace(config, **changes)


def scaled_rows(data, scale: Scale):
    """A :class:`~loopid.rounds.data.RoundData`'s states and actions in scaled units."""
    if scale.unit:
        return data
    return data._replace(
        x=data.x / scale.states, u=data.u / scale.actions, x_next=data.x_next / scale.states
    )


def log_gains(K_s: np.ndarray, scale: Scale) -> np.ndarray:
    """``K = D_u K_s D_x⁻¹`` (``K_s [..., m, n]``): a controller's gains in the log's units."""
    return np.asarray(K_s, np.float64) * scale.actions[:, None] / _dx(scale)[None, :]


def scaled_gains(K: np.ndarray, scale: Scale) -> np.ndarray:
    """``K_s = D_u⁻¹ K D_x``: gains in the scaled, dimensionless units."""
    return np.asarray(K, np.float64) / scale.actions[:, None] * _dx(scale)[None, :]


def log_model(A_s: np.ndarray, B_s: np.ndarray, scale: Scale) -> tuple[np.ndarray, np.ndarray]:
    """``A = D_x A_s D_x⁻¹``, ``B = D_x B_s D_u⁻¹`` (``[..., n, n]``, ``[..., n, m]``)."""
    dx = _dx(scale)
    A = np.asarray(A_s, np.float64) * dx[:, None] / dx[None, :]
    B = np.asarray(B_s, np.float64) * dx[:, None] / scale.actions[None, :]
    return A, B
