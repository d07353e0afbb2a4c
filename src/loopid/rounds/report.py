"""``round.md``: what to collect next, what the data say, and the model-class check.

After controller N is written, the next round is Algorithm 1's iteration N + 1: ``m`` transitions
(``[rounds] samples``), of which ``round(p m)`` from running π_N and the rest from ν, with the
method's policy fraction p (:func:`loopid.algorithms.schedules.policy_fractions`: DAgger
``dagger_fraction``, ½ by default; Batch 0; Abbeel 0 in its first round, then 1).

Each update records one row of diagnostics (:func:`row`), all mean squared one-step prediction
errors ``‖Δx' − f̂(Δx, Δu)‖²`` in the state's units squared:

- ``loss_nu``, ``loss_policy``: the model's loss, before the update, on the round's ν rows and
  policy rows (None when there were none). A policy loss well above the ν loss is the
  train/test mismatch DAgger corrects.
- ``loss_all``: the new model's loss on every row so far (the aggregate dataset), and
  ``relative``: that loss over the mean ``‖o' − o‖²`` of those rows (the loss of a model that
  predicts no change).
- ``online``: the average over updates of the loss before each update; ``regret``: the sum of
  those losses minus the sum of each round's loss under the current model (a lower bound on the
  regret against the best fixed model in hindsight, which no-regret learners keep o(N)).
- ``policy_cost``: the mean design cost ``c(o, a)`` of the round's policy rows.

The model-class check is the paper's reduction (Ross & Bagnell 2012, Theorem 4.1 and the
discussion after it): either DAgger finds good policies, or no model in the class has low error
on the aggregate dataset. When the relative aggregate loss stays above :data:`HIGH` for two
rounds while the policy rows' cost does not fall by 5 %, the report says so and suggests a
richer model class.
"""

import numpy as np

from loopid.algorithms.host_agent import design_cost
from loopid.algorithms.schedules import policy_fractions
from loopid.rounds.config import RoundsConfig

COLUMNS = ("loss_nu", "loss_policy", "loss_all", "relative", "online", "regret", "policy_cost")
#: The relative aggregate loss above which the model class is suspected.
HIGH = 0.1


def split(config: RoundsConfig, n: int) -> tuple[int, int]:
    """``(policy rows, ν rows)`` to collect while controller ``n`` is deployed."""
    p = policy_fractions(config.method, n + 1, dagger_fraction=config.dagger_fraction)
    pol = round(float(p[n]) * config.samples)
    return pol, config.samples - pol


def row(config: RoundsConfig, n: int, data, **losses) -> dict:
    """The diagnostics of the update on ``data``, collected while controller ``n`` was deployed
    (``losses``: loss_nu, loss_policy, loss_all, relative, online, regret)."""
    cost = design_cost(config.spec, config.shape)
    pol = data.policy
    policy_cost = float(np.mean(cost(data.x[pol], data.u[pol]))) if pol.any() else None
    out = {
        "round": n, "rows_nu": int((~pol).sum()), "rows_policy": int(pol.sum()),
        **{k: float(v) for k, v in losses.items()}, "policy_cost": policy_cost,
    }  # fmt: skip
    for rows, loss in (("rows_nu", "loss_nu"), ("rows_policy", "loss_policy")):
        if not out[rows]:  # no such rows: no loss (not the masked mean's 0)
            out[loss] = None
    return out


def _g(v) -> str:
    return "–" if v is None else f"{v:.4g}"


def check(history) -> str:
    """The model-class check's paragraph (module docstring)."""
    if len(history) < 2:
        return "Too early: the check compares two rounds."
    a, b = history[-2], history[-1]
    high = min(a["relative"], b["relative"]) > HIGH
    costs = a["policy_cost"], b["policy_cost"]
    improving = None not in costs and costs[1] < 0.95 * costs[0]
    share = f"{100 * a['relative']:.3g} % and {100 * b['relative']:.3g} %"
    if high and not improving:
        return (
            f"**The model class looks too poor.** The aggregate loss stays high ({share} of a "
            "no-change model's) while the policy's cost does not improve. The paper's reduction "
            "says that either DAgger finds good policies or no model in the class fits the "
            "aggregate data well; this is the second case. Try a richer model class: "
            '`[model] kind = "features"` (with `[planner] kind = "ilqr"`), or `"mlp"`.'
        )
    if high:
        return (
            f"The aggregate loss is high ({share} of a no-change model's) but the policy's cost "
            "still falls: keep going, and check again next round."
        )
    return f"The model class fits the aggregate data ({share} of a no-change model's loss)."


def render(config: RoundsConfig, state) -> str:
    """``round.md`` for the state after controller ``state.round`` was written."""
    n = state.round
    pol, nu = split(config, n)
    lines = [
        f"# Round {n}", "",
        f"Controller {n} is `controllers/round-{n:03d}.npz`; deploy it with "
        f"`loopid round export DIR --round {n} --format c` (or json, npz).", "",
        "## Next round", "",
        f"Collect {config.samples} transitions, in one file with the columns "
        f"{', '.join(config.states)}, {', '.join(config.actions)}, "
        f"{', '.join('next_' + s for s in config.states)} and `source`:", "",
        f"- {pol} from running controller {n} from the start distribution (`source = policy`);",
        f"- {nu} from the exploration distribution ν (`source = nu`).", "",
        "Then run `loopid round update DIR FILE`.", "",
    ]  # fmt: skip
    if pol:
        lines += [
            "Two ways to draw the policy rows, as the paper does:", "",
            "1. Start the system from the start distribution, run the controller, and at every "
            "step stop with a small probability (1 − γ); keep only the last transition. One "
            "run gives one row: unbiased for the discounted state distribution, but slow.",
            f"2. Run whole episodes of {config.horizon} steps from the start distribution and "
            f"pick the {pol} rows uniformly at random among all their steps (fewer runs; the "
            "rows of one episode are correlated, so spread them over several episodes).", "",
        ]  # fmt: skip
    lines += ["## What the data say", ""]
    if not state.history:
        lines += ["No data yet: controller 1 is the initial model's.", ""]
    else:
        lines += [
            "| data of controller | ν rows | policy rows | loss on ν rows (before) | loss on "
            "policy rows (before) | loss on all data | relative | online loss | regret | "
            "policy rows' cost |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for h in state.history:
            cells = [h["round"], h["rows_nu"], h["rows_policy"]] + [_g(h[k]) for k in COLUMNS]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
        lines.append("")
    lines += ["## Model-class check", "", check(state.history), ""]
    return "\n".join(lines)
