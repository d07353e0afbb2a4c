"""Per-episode figures of a round's policy rows, from the optional ``episode`` column.

A per-row mean cost can make a controller that falls look cheap: its short episodes contribute
few rows, each near the start. When the round's file has an ``episode`` column
(:mod:`loopid.rounds.data`), the policy rows of one label are one episode of the deployed
controller, and :func:`summary` gives, over those episodes:

- ``episodes``: how many there are;
- ``lengths``: each episode's length in steps, ``max(t) + 1`` when the file has a ``t`` column,
  else its number of rows (so log every step of an episode, or give ``t``);
- ``costs``: each episode's cost, the sum of the design cost ``c(o, a)`` over its rows;
- ``ended_early``: how many ended before the horizon, i.e. a fall: shorter than ``[system]
  horizon``, or with a row marked by the optional ``terminated`` column.

ν's episodes are exploration, not the controller's, and are not summarised.
"""

import numpy as np

from loopid.algorithms.host_agent import design_cost


def summary(config, data) -> dict | None:
    """The per-episode figures (module docstring) of ``data``'s policy rows; None without an
    ``episode`` column or without policy rows."""
    if data.episode is None or not data.policy.any():
        return None
    cost = np.asarray(design_cost(config.spec, config.shape)(data.x, data.u), np.float64)
    names = data.table.column_names
    t = data.table.column("t").to_numpy().astype(np.int64) if "t" in names else None
    ended = np.zeros(data.x.shape[0], bool) if data.terminated is None else data.terminated
    labels = data.episode[data.policy]
    rows = np.flatnonzero(data.policy)
    lengths, costs, early = [], [], 0
    for label in dict.fromkeys(labels.tolist()):  # in order of first appearance
        mine = rows[labels == label]
        length = int(t[mine].max()) + 1 if t is not None else mine.size
        lengths.append(length)
        costs.append(float(cost[mine].sum()))
        early += int(length < config.horizon or bool(ended[mine].any()))
    return {"episodes": len(lengths), "lengths": lengths, "costs": costs, "ended_early": early}


def sentence(ep: dict, n: int, horizon: int) -> str:
    """What the episodes of controller ``n`` say, in a plain sentence."""
    k, early = ep["episodes"], ep["ended_early"]
    if early == k:
        return (
            f"**Controller {n} ended every one of its {k} episodes early** (shorter than the "
            f"horizon of {horizon} steps, or marked `terminated`): it does not hold the "
            "system, whatever its per-row cost says."
        )
    if early:
        return f"Controller {n} ended {early} of its {k} episodes early (a fall)."
    return f"Controller {n} ran all {k} of its episodes to the horizon of {horizon} steps."
