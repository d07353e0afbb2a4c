"""Per-episode figures of a round's policy rows, from the optional ``episode`` column.

A per-row mean cost can make a controller that falls look cheap: its short episodes contribute
few rows, each near the start. When the round's file has an ``episode`` column
(:mod:`loopid.rounds.data`), the policy rows of one label are one episode of the deployed
controller, and :func:`summary` gives, over those episodes:

- ``episodes``: how many there are;
- ``lengths``: each episode's length in steps, ``max(t) + 1`` when the file has a ``t`` column,
  else its number of rows;
- ``costs``: each episode's cost, the sum of the design cost ``c(o, a)`` over its rows (the
  whole episode's cost when every step is logged);
- ``ended_early``: how many ended before the horizon, i.e. a fall: with a ``terminated`` column,
  the episodes with a row marked true; without it, those shorter than ``[system] horizon``.

So log every step of a policy episode (or at least its last one, with ``t``); when only some
steps are kept, as in ``round.md``'s second way of drawing the policy rows, give ``terminated``:
the lengths and costs are then those of the rows kept, and the falls are still counted right.

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
    ended = data.terminated
    labels = data.episode[data.policy]
    rows = np.flatnonzero(data.policy)
    lengths, costs, early = [], [], 0
    for label in dict.fromkeys(labels.tolist()):  # in order of first appearance
        mine = rows[labels == label]
        length = int(t[mine].max()) + 1 if t is not None else mine.size
        lengths.append(length)
        costs.append(float(cost[mine].sum()))
        early += int(length < config.horizon if ended is None else bool(ended[mine].any()))
    return {"episodes": len(lengths), "lengths": lengths, "costs": costs, "ended_early": early}


def sentence(ep: dict, n: int, horizon: int) -> str:
    """What the episodes of controller ``n`` say, in a plain sentence."""
    k, early = ep["episodes"], ep["ended_early"]
    if early == k:
        return (
            f"**Controller {n} ended every one of its {k} episodes early** (marked "
            f"`terminated`, or shorter than the horizon of {horizon} steps): it does not hold "
            "the system, whatever its per-row cost says."
        )
    if early:
        return f"Controller {n} ended {early} of its {k} episodes early (a fall)."
    every = "its one episode" if k == 1 else f"all {k} of its episodes"
    return f"Controller {n} ran {every} to the horizon of {horizon} steps."
