r"""Finite-MDP scenarios: the paper's theory made visible, through the same loop and results.

Scenarios (:data:`MDP_SCENARIOS`):

- ``mdp-random``: a random MDP (S = 10, A = 3, Dirichlet(0.3) rows, costs U[0, 1], γ = 0.9),
  ν uniform over the state-action pairs (the best ν for Batch), count-estimator model: the
  realisable case, where DAgger and Batch both become optimal.
- ``mdp-trap``: :func:`loopid.systems.mdp.trap_mdp` with ν = D_{μ,π_ε} of "walk, but act at
  random with probability ε = 10⁻³" (a base policy's distribution with action noise): Batch's
  policy jumps into the region ν rarely sees (huge c_ν^π̂), DAgger's does not.
- ``mdp-trap-hinge``: the same with the deterministic classifier model (online hinge): a
  misspecified class on a stochastic system (the walk slips), i.e. the agnostic case.

Methods (:data:`MDP_METHODS`): ``dagger`` (p_n = ½), ``batch`` (p_n = 0), ``abbeel`` (ν at
n = 2, then the policy only); the fractions come from
:func:`loopid.algorithms.methods.policy_fractions`. Policy draws are ``geometric`` (exact
draws from D_{μ,π}, the paper's analysis). Every method of a scenario shares one compiled cell.

Extra result columns (:func:`loopid.algorithms.mdp_agent.mdp_diagnostics`): ``j_policy``,
``j_best``, ``j_mixture``, ``j_optimal``, ``bound`` (Theorem 3.1 while all data came from ν,
Lemma 4.1 once the policies contribute), ``eps_prd_l1``, ``eps_prd_kl``, ``eps_mdl_l1``,
``eps_oc``, ``c_nu``, ``c_nu_policy``. ``test_cost`` is the exact J of the iteration's policy.
"""

from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

from loopid.algorithms import methods as M
from loopid.algorithms.loop import Row, Trace, at_least, cell_memory, make_cell, run_learning
from loopid.algorithms.mdp_agent import (
    classifier_model,
    counts_model,
    explicit_nu,
    mdp_agent,
    mdp_diagnostics,
    mdp_plant,
    policy_nu,
)
from loopid.experiments.config import (
    check_choice,
    check_int,
    check_number,
    read_flat_file,
    replaced,
)
from loopid.experiments.families.base import Family
from loopid.systems.mdp import TRAP_WALK, FiniteMDP, random_mdp, trap_mdp

__all__ = ["FAMILY", "MDP_METHODS", "MDP_SCENARIOS", "MDPScenario", "mdp_figure", "run_mdp"]

MDP_METHODS = ("dagger", "batch", "abbeel")
_FRACTIONS = {"dagger": "dagger-t", "batch": "batch-t", "abbeel": "abbeel"}


@dataclass(frozen=True)
class MDPScenario:
    """One finite-MDP experiment (frozen, hashable; checked when built).

    Attributes:
      name: the scenario name.
      system: ``random`` (a random MDP: ``n_states``, ``n_actions``, Dirichlet ``concentration``
        rows, drawn from ``jax.random.key(mdp_seed)``) or ``trap``
        (:func:`loopid.systems.mdp.trap_mdp` of ``length`` with ``slip``).
      gamma: the discount.
      nu: ``uniform`` over state-action pairs, or ``base``: D_{μ,π_ε} of the walk policy with
        action noise ``epsilon``.
      model: ``counts`` (count estimator, pseudo-weight ``alpha``) or ``hinge`` (deterministic
        classifier: step ``eta``, prior margin ``margin``).
      iterations, samples, seeds: N, m per iteration, and the seed count.
      horizon: rollout length (the geometric draw is truncated there: bias <= γ^horizon).
    """

    name: str
    system: str = "random"
    n_states: int = 10
    n_actions: int = 3
    concentration: float = 0.3
    length: int = 6
    slip: float = 0.2
    gamma: float = 0.9
    mdp_seed: int = 0
    nu: str = "uniform"
    epsilon: float = 1e-3
    model: str = "counts"
    alpha: float = 0.1
    eta: float = 1.0
    margin: float = 0.5
    iterations: int = 30
    samples: int = 100
    horizon: int = 150
    seeds: int = 8

    def __post_init__(self) -> None:
        for name in ("iterations", "samples", "seeds", "horizon", "n_states", "n_actions"):
            check_int(name, getattr(self, name))
        check_int("length", self.length)
        check_int("mdp_seed", self.mdp_seed, 0)
        check_choice("system", self.system, ("random", "trap"))
        check_choice("nu", self.nu, ("uniform", "base"))
        check_choice("model", self.model, ("counts", "hinge"))
        check_number("gamma", self.gamma, 0.0, 1.0 - 1e-12)
        check_number("epsilon", self.epsilon, 0.0, 1.0)
        check_number("slip", self.slip, 0.0, 1.0)
        for name in ("concentration", "alpha", "eta"):
            check_number(name, getattr(self, name), 0.0, open_low=True)
        check_number("margin", self.margin, 0.0)

    def replace(self, **changes) -> "MDPScenario":
        """A copy with ``changes``; unknown fields and bad values raise ValueError."""
        return replaced(self, changes, "MDP scenario")

    def to_dict(self) -> dict:
        """The fields as a plain dict (for config.toml)."""
        return asdict(self)


MDP_SCENARIOS = {
    "mdp-random": MDPScenario("mdp-random"),
    "mdp-trap": MDPScenario("mdp-trap", system="trap", nu="base", samples=50),
    "mdp-trap-hinge": MDPScenario(
        "mdp-trap-hinge", system="trap", nu="base", samples=50, model="hinge"
    ),
}


def _scenario(scenario) -> MDPScenario:
    if isinstance(scenario, MDPScenario):
        return scenario
    if scenario not in MDP_SCENARIOS:
        raise ValueError(f"unknown MDP scenario {scenario!r}; choose from {sorted(MDP_SCENARIOS)}")
    return MDP_SCENARIOS[scenario]


def scenario_mdp(s: MDPScenario) -> FiniteMDP:
    """The scenario's true MDP (a random one is drawn from ``jax.random.key(mdp_seed)``)."""
    if s.system == "random":
        key = jax.random.key(s.mdp_seed)
        return random_mdp(
            key, s.n_states, s.n_actions, gamma=s.gamma, concentration=s.concentration
        )
    if s.system == "trap":
        return trap_mdp(s.length, slip=s.slip, gamma=s.gamma)
    raise ValueError(f"system must be 'random' or 'trap', got {s.system!r}")


def scenario_nu(s: MDPScenario, mdp: FiniteMDP):
    """``(dist [S, A], nu)`` of the scenario's exploration distribution."""
    S, A = mdp.n_states, mdp.n_actions
    if s.nu == "uniform":
        dist = np.full((S, A), 1.0 / (S * A))
        return dist, explicit_nu(mdp, dist)
    if s.nu == "base":
        if not 0.0 <= s.epsilon <= 1.0:
            raise ValueError(f"epsilon must lie in [0, 1], got {s.epsilon!r}")
        pi0 = np.full((S, A), s.epsilon / A)
        pi0[:, TRAP_WALK] += 1.0 - s.epsilon
        dist, nu = policy_nu(mdp, pi0)
        return np.asarray(dist), nu
    raise ValueError(f"nu must be 'uniform' or 'base', got {s.nu!r}")


def scenario_model(s: MDPScenario, mdp: FiniteMDP):
    """The scenario's model class and learner."""
    if s.model == "counts":
        return counts_model(mdp.n_states, mdp.n_actions, alpha=s.alpha)
    if s.model == "hinge":
        return classifier_model(mdp.n_states, mdp.n_actions, eta=s.eta, margin=s.margin)
    raise ValueError(f"model must be 'counts' or 'hinge', got {s.model!r}")


class MDPSetup(NamedTuple):
    """Everything a scenario's methods share, including the compiled cell."""

    mdp: FiniteMDP
    nu_dist: np.ndarray
    plant: object
    agent: object
    nu: Callable
    cell: tuple


@lru_cache(maxsize=8)
def mdp_setup(s: MDPScenario) -> MDPSetup:
    """Build (and cache) the scenario's MDP, ν, agent, diagnostics and compiled cell."""
    mdp = scenario_mdp(s)
    dist, nu = scenario_nu(s, mdp)
    model = scenario_model(s, mdp)
    plant = mdp_plant(mdp, s.horizon)
    agent = mdp_agent(mdp, model)
    diag = mdp_diagnostics(mdp, dist, model)
    cell = make_cell(
        plant, agent, nu, samples=s.samples, iterations=s.iterations, n_test=1,
        mode="geometric", gamma=s.gamma, diagnostics=diag,
    )  # fmt: skip
    return MDPSetup(mdp, dist, plant, agent, nu, cell)


def run_mdp(
    method: str,
    scenario,
    seeds=None,
    progress: Callable[[int, Row], None] | None = None,
) -> Trace:
    """Run ``method`` (:data:`MDP_METHODS`) on a finite-MDP scenario (a name in
    :data:`MDP_SCENARIOS` or an :class:`MDPScenario`) for every seed (default
    ``range(scenario.seeds)``). The Trace's ``rows.extra`` holds the exact diagnostics."""
    s = _scenario(scenario)
    if method not in MDP_METHODS:
        raise ValueError(f"unknown MDP method {method!r}; choose from {', '.join(MDP_METHODS)}")
    seeds = list(range(s.seeds)) if seeds is None else list(seeds)
    setup = mdp_setup(s)
    fractions = M.policy_fractions(_FRACTIONS[method], s.iterations)
    return at_least(
        lambda padded: run_learning(
            setup.plant, setup.agent, setup.nu, fractions, padded, samples=s.samples, n_test=1,
            mode="geometric", gamma=s.gamma, progress=progress, cell=setup.cell,
        ),
        np.asarray(seeds),
    )  # fmt: skip


_LABEL = {"dagger": "DAgger", "batch": "Batch", "abbeel": "Abbeel"}
_COLOR = {"dagger": "C0", "batch": "C3", "abbeel": "C2"}


def _column(table, name) -> np.ndarray:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False))


def mdp_figure(table, path) -> Path:
    """Plot J against samples per MDP scenario in ``table`` (a results ``pyarrow.Table``).

    Left panel per scenario: mean ``j_policy`` per method (shaded: min-max over seeds) and
    J*. Right panel: the true gap ``j_best − J*`` (solid) beside the bound's gap ``bound − J*``
    (dashed) per method, log scale (a zero gap is drawn at 1e-6; an infinite bound as a
    triangle at the top edge). Saves to
    ``path`` (format from its suffix) and returns the path.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    needed = ("scenario", "method", "samples", "j_policy", "j_best", "j_optimal", "bound")
    missing = [c for c in needed if c not in table.column_names]
    if missing:
        raise ValueError(f"table has no MDP diagnostics column(s) {missing}")
    cols = {c: _column(table, c) for c in needed}
    keep = ~np.isnan(cols["j_policy"].astype(np.float64))
    cols = {c: v[keep] for c, v in cols.items()}
    scenarios = sorted(set(cols["scenario"]))
    if not scenarios:
        raise ValueError("table holds no MDP rows")
    fig, axes = plt.subplots(len(scenarios), 2, figsize=(10, 3.6 * len(scenarios)), squeeze=False)
    for row, name in enumerate(scenarios):
        ax_j, ax_gap = axes[row]
        in_s = cols["scenario"] == name
        j_star = float(np.mean(cols["j_optimal"][in_s]))
        top = 1.0
        for method in sorted(set(cols["method"][in_s])):
            sel = in_s & (cols["method"] == method)
            x = np.unique(cols["samples"][sel])

            def per_x(v, reduce, sel=sel, x=x):
                return np.array([reduce(v[sel & (cols["samples"] == xi)]) for xi in x])

            color, label = _COLOR.get(method, "k"), _LABEL.get(method, method)
            j = cols["j_policy"]
            ax_j.plot(x, per_x(j, np.mean), color=color, label=label)
            ax_j.fill_between(x, per_x(j, np.min), per_x(j, np.max), color=color, alpha=0.2)
            gap = np.maximum(per_x(cols["j_best"], np.mean) - j_star, 1e-6)
            bound = per_x(cols["bound"], np.mean) - j_star
            finite = np.isfinite(bound)
            top = max(top, float(np.max(bound[finite], initial=1.0)), float(gap.max()))
            ax_gap.plot(x, gap, color=color, label=f"{label}: J(best) − J*")
            ax_gap.plot(
                x[finite], bound[finite], color=color, ls="--", label=f"{label}: bound − J*"
            )
            if (~finite).any():
                ax_gap.plot(
                    x[~finite], np.full((~finite).sum(), top), color=color, ls="", marker="^"
                )
        ax_j.axhline(j_star, color="k", ls=":", label="J*")
        ax_j.set(title=f"{name}: J of the learnt policy", xlabel="samples", ylabel="J_μ(π)")
        ax_gap.set(title=f"{name}: gap and bound", xlabel="samples", ylabel="gap", yscale="log")
        ax_j.legend(fontsize=8)
        ax_gap.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def report(table, configs=None) -> list[str]:
    """``report.md``'s section of an MDP run: per scenario and method, the final mean J of the
    learnt policy, of the best policy so far, J* and the bound (means over seeds), and whether
    J(best) <= bound held on every row."""
    lines = ["## Exact quantities", ""]
    lines += [
        "Exact quantities (no sampling in the evaluation): J_μ(π) of the learnt policy,",
        "J of the best policy so far, the optimum J* and the right-hand side of the",
        "paper's bound for π' = π* (Theorem 3.1 while only ν data was seen, Lemma 4.1",
        "once a policy contributed). Means over seeds at the last iteration.",
        "",
    ]
    lines += [
        "| scenario | method | J(π_N) | J(best) | J* | bound | j_best ≤ bound, all rows |",
        "|---|---|---|---|---|---|---|",
    ]
    cols = {
        c: _column(table, c)
        for c in ("scenario", "method", "iteration", "j_policy", "j_best", "j_optimal", "bound")
    }
    for name in sorted(set(cols["scenario"])):
        for method in sorted(set(cols["method"][cols["scenario"] == name])):
            sel = (cols["scenario"] == name) & (cols["method"] == method)
            last = sel & (cols["iteration"] == cols["iteration"][sel].max())
            holds = bool(np.all(cols["j_best"][sel] <= cols["bound"][sel] + 1e-9))
            vals = [
                float(np.mean(cols[c][last])) for c in ("j_policy", "j_best", "j_optimal", "bound")
            ]
            lines.append(
                f"| {name} | {method} | "
                + " | ".join(f"{v:.4g}" for v in vals)
                + f" | {'yes' if holds else 'NO'} |"
            )
    return [*lines, ""]


def _build(name: str, changes: dict) -> MDPScenario:
    return _scenario(name).replace(**changes)


def load(s: MDPScenario, method: str, arrays: dict):
    """One seed's saved policy ``K [S, A]`` and learned ``T̂ [S, A, S]``."""
    from loopid.experiments.learned import TableController, TableModel

    return TableModel(arrays["T_hat"]), TableController(arrays["K"])


def evaluate(s: MDPScenario, arrays: dict, seeds, episodes: int, env=None) -> np.ndarray:
    """The exact ``J_μ(π)`` of each saved policy ``arrays["K"] [S, n_states, n_actions]``,
    repeated ``episodes`` times (no sampling: the evaluation is exact)."""
    K = arrays["K"]
    if env is not None:
        raise ValueError(f"--env {env!r} applies to gym runs, not to {s.name}")
    plant = mdp_setup(s).plant
    J = jax.jit(jax.vmap(lambda k: plant.eval_one(k, None)[0]))(jax.numpy.asarray(K))
    return np.repeat(np.asarray(J)[:, None], episodes, axis=1)


def trajectories(run_dir, configs, path) -> None:
    """``trajectories.png`` of a finite MDP run: where each method's saved final policy (first
    seed) goes, its exact discounted state occupancy ``D_{μ,π}(s)`` (a finite MDP has no path in
    space; this is the distribution its episodes visit), one panel per scenario, with the
    optimal policy's for reference."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from loopid.control.value_iteration import occupancy, value_iteration
    from loopid.experiments import artifacts
    from loopid.experiments.results import write_atomic_bytes

    cells = Path(run_dir) / "cells"
    panels = [(n, s) for n, s in configs.items() if list(cells.glob(f"{n}__*.json"))]
    if not panels:
        return
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * len(panels)), squeeze=False,
                             layout="constrained")  # fmt: skip
    for ax, (name, s) in zip(axes[:, 0], panels, strict=True):
        mdp = mdp_setup(s).mdp
        optimal = value_iteration(mdp.P, mdp.C, mdp.gamma, tol=1e-12, max_iter=100_000).policy
        policies = {"optimal": np.asarray(optimal)}
        for m in MDP_METHODS:
            if (cells / f"{name}__{m}.json").is_file():
                _, arrays = artifacts.read(cells, name, m)
                policies[m] = arrays["K"][0]
        width = 0.8 / len(policies)
        states = np.arange(mdp.n_states)
        for k, (label, K) in enumerate(policies.items()):
            d = np.asarray(occupancy(mdp.P, mdp.mu, mdp.gamma, jax.numpy.asarray(K))).sum(axis=1)
            ax.bar(states + (k - (len(policies) - 1) / 2) * width, d / d.sum(), width,
                   color="k" if label == "optimal" else f"C{k - 1}", label=label)  # fmt: skip
        ax.set(xlabel="state", ylabel="D_μ,π(s)", title=f"{name}: where the final policies go")
        ax.legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    write_atomic_bytes(buf.getvalue(), path)


FAMILY = Family(
    name="mdp",
    config=MDPScenario,
    methods=MDP_METHODS,
    scenarios=MDP_SCENARIOS,
    default_methods=lambda s: MDP_METHODS,
    build=_build,
    read_file=lambda path: read_flat_file(path, [f.name for f in fields(MDPScenario)]),
    run=lambda method, s, seeds=None, progress=None: run_mdp(method, s, seeds, progress),
    figure=lambda table, path, configs: mdp_figure(table, path),
    report=report,
    load=load,
    evaluate=evaluate,
    trajectories=trajectories,
    memory=lambda s, method, seeds: cell_memory(mdp_setup(s).cell, seeds),
)
