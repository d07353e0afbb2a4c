"""``round.md``: what to collect next, what the data say, and the model-class check.

After controller N is written, the next round is Algorithm 1's iteration N + 1: ``m`` transitions
(``[rounds] samples``), of which ``round(p m)`` from running π_N and the rest from ν, with the
method's policy fraction p (:func:`loopid.algorithms.schedules.policy_fractions`: DAgger
``dagger_fraction``, ½ by default; Batch 0; Abbeel 0 in its first round, then 1).

Each update records one row of diagnostics (:func:`row`), the losses all mean squared one-step
prediction errors ``‖Δx' − f̂(Δx, Δu)‖²`` in the scaled coordinates the model is fitted in
(:mod:`loopid.rounds.scale`: each state in units of its first round's standard deviation, so the
losses are plain numbers; in the log's units squared under ``[rounds] scale = "none"``):

- ``loss_nu``, ``loss_policy``: the model's loss, before the update, on the round's ν rows and
  policy rows (None when there were none). A policy loss well above the ν loss is the
  train/test mismatch DAgger corrects.
- ``loss_all``: the new model's loss on every row so far (the aggregate dataset), and
  ``relative``: that loss over the mean ``‖o' − o‖²`` of those rows (the loss of a model that
  predicts no change).
- ``online``: the average over updates of the loss before each update; ``regret``: the sum of
  those losses minus the sum of each round's loss under the current model (a lower bound on the
  regret against the best fixed model in hindsight, which no-regret learners keep o(N)).
- ``policy_cost``: the mean design cost ``c(o, a)`` of the round's policy rows (a per-row mean:
  a controller that falls early has few rows and can look cheap; see the episodes);
- ``episodes``: per-episode lengths and costs of the policy rows when the file has an
  ``episode`` column (:mod:`loopid.rounds.episodes`);
- ``gain_change``, ``pull``: how far the gains moved from the previous controller and the
  regulariser's pull on the model (:mod:`loopid.rounds.model`, thresholds 1 % each).

``round.md`` also shows the scale (:mod:`loopid.rounds.scale`), the identified ``A`` and ``B`` in
the log's units as a table when the system is small (at most :data:`SMALL` states and actions
together, time-invariant; otherwise a reference to ``loopid round export DIR --format model``),
and whether the controller's solve converged.

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
from loopid.rounds.episodes import sentence
from loopid.rounds.model import PULL_WARN, SETTLED
from loopid.rounds.scale import Scale

COLUMNS = ("loss_nu", "loss_policy", "loss_all", "relative", "online", "regret", "policy_cost")
#: The relative aggregate loss above which the model class is suspected.
HIGH = 0.1
#: The most states and actions together whose A and B round.md shows as a table.
SMALL = 8


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


def _scale(config: RoundsConfig, state) -> list[str]:
    if state.scale is None:
        return ["Not set yet: the first update sets it from its rows.", ""]
    sc = Scale.from_json(state.scale)
    if sc.note:
        return [f"Every column keeps the log's unit: {sc.note}.", ""]
    lines = [
        "The model is fitted and solved with each column divided by its scale, the standard "
        "deviation of the first round's rows, so the controller does not depend on the log's "
        "units; the controller and the model are written in the log's units.", "",
        "| column | scale |", "|---|---|",
    ]  # fmt: skip
    for name, s in zip([*config.states, *config.actions], [*sc.states, *sc.actions], strict=True):
        flat = " (no spread in the first round: unit scale)" if name in sc.flat else ""
        lines.append(f"| {name} | {s:.6g}{flat} |")
    if config.action_limit is not None and config.m > 1:
        lines.append("")
        lines.append("The actions share one scale: `action_limit` bounds them all.")
    return [*lines, ""]


def _model(config: RoundsConfig, n: int, arrays: dict) -> list[str]:
    if "A" not in arrays or arrays["A"].ndim != 2 or config.n_obs + config.m > SMALL:
        what = "its coefficients" if "A" in arrays else "the model's parameters"
        return [
            f"The model of controller {n} is too large for a table, or not linear: "
            f"{what} are in `controllers/round-{n:03d}.npz`; a linear model is written by "
            f"`loopid round export DIR --round {n} --format model`.", "",
        ]  # fmt: skip
    cols = [*config.states, "1", *config.actions]
    lines = [
        f"The model controller {n} was solved on, `Δx' = A Δx + B Δu` with `Δx = [o − o*; 1]`, "
        "`Δu = a − a_op`, in the log's units (exactly: `loopid round export DIR --format "
        "model`):", "",
        "| | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|",
    ]  # fmt: skip
    AB = np.concatenate([arrays["A"], arrays["B"]], axis=1)
    for i, s in enumerate(config.states):
        lines.append(f"| next_{s} | " + " | ".join(f"{v:.6g}" for v in AB[i]) + " |")
    return [*lines, ""]


def _pull(p: dict | None) -> str:
    if p is None:
        return "The regulariser's pull is not measured for this round."
    if p["pull"] is None:
        return f"The regulariser's pull is not measured: {p['why']}."
    pct = f"{100 * p['pull']:.3g} %"
    if p["pull"] > PULL_WARN:
        return (
            f"**The regulariser pulls the model.** Its coefficient {p['where']} is "
            f"{p['fit']:.6g}; plain least squares on the same rows gives {p['ls']:.6g} ({pct} "
            f"apart, above {100 * PULL_WARN:g} %). Lower `[model] lambda`, or collect more rows."
        )
    return (
        f"The regulariser's pull is {pct} (largest at {p['where']}), below "
        f"{100 * PULL_WARN:g} %: the model is the data's least-squares fit."
    )


def _gains(n: int, h: dict, converged: bool) -> list[str]:
    change = h.get("gain_change")
    if change is None:
        text = f"Controller {n - 1} did not act (zero gains): no gain change to measure."
    elif change < SETTLED:
        text = (
            f"The gains changed by {100 * change:.3g} % from controller {n - 1}: below "
            f"{100 * SETTLED:g} %, they have settled, and another round is unlikely to change "
            "the controller much."
        )
    else:
        text = f"The gains changed by {100 * change:.3g} % from controller {n - 1}."
    solve = (
        "The solve converged." if converged else "**The solve did not converge**: the model "
        "may not be stabilisable, or the planner ran out of iterations; do not deploy blindly."
    )  # fmt: skip
    return [text + " " + solve, ""]


def _episodes(config: RoundsConfig, history) -> list[str]:
    rows = [h for h in history if h.get("episodes")]
    if not rows:
        return [
            "No `episode` column in the data: add one (and `terminated`, if the system can say "
            "so) for per-episode costs and lengths.", "",
        ]  # fmt: skip
    lines = [
        "| data of controller | policy episodes | ended early | mean length (steps) | "
        "mean cost per episode |", "|---|---|---|---|---|",
    ]  # fmt: skip
    for h in rows:
        e = h["episodes"]
        lines.append(
            f"| {h['round']} | {e['episodes']} | {e['ended_early']} | "
            f"{np.mean(e['lengths']):.4g} | {np.mean(e['costs']):.4g} |"
        )
    last = history[-1]
    if last.get("episodes"):
        lines += ["", sentence(last["episodes"], last["round"], config.horizon)]
    return [*lines, ""]


def render(config: RoundsConfig, state, arrays: dict) -> str:
    """``round.md`` for the state after controller ``state.round`` (its ``arrays``) was
    written."""
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
        "Optional columns: `t` (the step within its episode, required for a time-varying "
        "model), `episode` (which episode a row belongs to: per-episode costs and lengths) and "
        "`terminated` (true on the row where an episode ended early, a fall).", "",
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
    if state.history:
        lines += ["## Episodes", "", *_episodes(config, state.history)]
    lines += ["## Gains", ""]
    if state.history:
        lines += _gains(n, state.history[-1], bool(arrays["converged"]))
    else:
        lines += ["No data yet: controller 1 is the initial model's LQR.", ""]
    lines += ["## The identified model", "", *_model(config, n, arrays)]
    if state.history:
        lines += [_pull(state.history[-1].get("pull")), ""]
    lines += ["## Units", "", *_scale(config, state)]
    lines += ["## Model-class check", "", check(state.history), ""]
    return "\n".join(lines)
