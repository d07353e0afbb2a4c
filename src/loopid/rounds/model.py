"""The identified model of a round, what the regulariser did to it, and how far the gains moved.

- :func:`linear_model`: the learned linear model ``Δx' = A Δx + B Δu`` (``A [n, n]``,
  ``B [n, m]``, or ``[T, ·, ·]`` when time-varying) in the scaled coordinates
  (:mod:`loopid.rounds.scale`; :func:`loopid.rounds.scale.log_model` takes it to the log's units).
- :func:`pull`: the regulariser's pull, the largest relative change of a model coefficient
  between the learned fit and plain least squares on the same rows (every row so far).
- :func:`gain_change`: the relative change of the gains from the previous controller.

**The pull.** With ``θ = [A B]`` without the constant's row (``n_obs`` rows; columns: the states,
the constant ``1``, the actions), from the learned model (``θ_fit``) and from plain least
squares on every row so far (``θ_ls``, the same nominal model and coordinates)::

    pull = max_ij |θ_fit,ij − θ_ls,ij| / max(|θ_ls,ij|, 0.01 · max_kl |θ_ls,kl|)

in the scaled coordinates, where every coefficient is a plain number (so the floor is the same in
any units; it keeps a coefficient least squares finds near zero from dividing by its noise).
Above :data:`PULL_WARN` (1 %) ``round.md`` warns that the regulariser biases the model: lower
``[model] lambda``, or collect more rows. It is measured for the time-invariant linear model,
when least squares is determined (the rows span every coordinate); otherwise it is None with the
reason.

**The gain change.** ``‖K_s − K_s,prev‖_F / ‖K_s,prev‖_F`` over every step's gain, in the
scaled coordinates (``K_s = D_u⁻¹ K D_x``: the same in any units); None when the previous
controller did not act (``K = 0``). Below :data:`SETTLED` (1 %) ``round.md`` says the gains have
stopped changing.
"""

import numpy as np

from loopid.algorithms.host_agent import nominal_model
from loopid.models.linear_offset import residual_targets, to_matrices
from loopid.rounds.data import transitions
from loopid.rounds.scale import Scale, log_model, scaled_gains

#: Above this pull (a relative change of 1 %) round.md warns of the regulariser's bias.
PULL_WARN = 0.01
#: The floor of the pull's denominator, as a fraction of the largest coefficient.
FLOOR = 0.01
#: Below this relative gain change (1 %) round.md says the gains have settled.
SETTLED = 0.01


def linear_model(config_s, params: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """``(A_s, B_s)`` of the learned offsets ``params["W"]`` on ``config_s``'s nominal model,
    in ``config_s``'s (scaled) coordinates; None for a model class other than the linear."""
    if config_s.model_kind != "linear" or "W" not in params:
        return None
    A, B = to_matrices(nominal_model(config_s.spec, config_s.shape), np.asarray(params["W"]))
    return np.asarray(A, np.float64), np.asarray(B, np.float64)


def coefficient_name(config, i: int, j: int) -> str:
    """The name of ``θ[i, j]`` (module docstring): ``A[next_p, v]``, ``A[next_p, 1]``,
    ``B[next_v, f]``."""
    cols = [*config.states, "1"]
    if j < len(cols):
        return f"A[next_{config.states[i]}, {cols[j]}]"
    return f"B[next_{config.states[i]}, {config.actions[j - len(cols)]}]"


def pull(config_s, rows_s, model_s, scale: Scale, config) -> dict:
    """The regulariser's pull (module docstring) on the scaled rows ``rows_s`` (every round's
    :class:`~loopid.rounds.data.RoundData` so far) of the learned ``model_s = (A_s, B_s)``:
    ``{"pull", "where", "fit", "ls"}`` (the coefficient's two values in the log's units) or
    ``{"pull": None, "why"}``."""
    if model_s is None:
        return {"pull": None, "why": f"the {config.model_kind} model class has no A and B"}
    if config_s.time_varying:
        return {"pull": None, "why": "the model is time-varying"}
    nominal = nominal_model(config_s.spec, config_s.shape)
    batches = [transitions(d, config_s) for d in rows_s]
    dx, du, dxn = (np.concatenate([np.asarray(getattr(b, k)) for b in batches])
                   for k in ("dx", "du", "dx_next"))  # fmt: skip
    Y = np.asarray(residual_targets(nominal, dx, du, dxn))
    Z = np.concatenate([dx, du], axis=1)
    W, _, rank, _ = np.linalg.lstsq(Z, Y, rcond=None)
    if rank < Z.shape[1]:
        return {
            "pull": None,
            "why": f"plain least squares is not determined (the rows span {rank} of "
            f"{Z.shape[1]} coordinates)",
        }
    n_obs = config.n_obs
    A_ls, B_ls = (np.asarray(a, np.float64) for a in to_matrices(nominal, W))
    fit = np.concatenate(model_s, axis=1)[:n_obs]
    ls = np.concatenate([A_ls, B_ls], axis=1)[:n_obs]
    floor = FLOOR * np.max(np.abs(ls))
    rel = np.abs(fit - ls) / np.maximum(np.abs(ls), floor)
    i, j = np.unravel_index(int(np.argmax(rel)), rel.shape)
    logs = [np.concatenate(log_model(*m, scale), axis=1)[:n_obs] for m in (model_s, (A_ls, B_ls))]
    return {
        "pull": float(rel[i, j]), "where": coefficient_name(config, int(i), int(j)),
        "fit": float(logs[0][i, j]), "ls": float(logs[1][i, j]),
    }  # fmt: skip


def gain_change(K: np.ndarray, K_prev: np.ndarray, scale: Scale) -> float | None:
    """The relative Frobenius change of the gains (module docstring); ``K``, ``K_prev`` in the
    log's units ``[T, m, n]``."""
    new, old = scaled_gains(K, scale), scaled_gains(K_prev, scale)
    size = float(np.linalg.norm(old))
    return float(np.linalg.norm(new - old)) / size if size > 0 else None
