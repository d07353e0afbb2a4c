"""Experiment scenarios: every setting of the paper's experimental protocol, with the paper's
values and, for the details it leaves open, the probable readings as defaults.

A :class:`Scenario` is one frozen record; every setting and every reading
(:mod:`loopid.experiments.families.helicopter.readings`) is a field, and the whole record is written
into each run directory's ``config.toml``. The paper's three panels are TOML
files shipped in the package
(``experiments/families/helicopter/scenarios/{hover,hover-delay,funnel}.toml``, every field spelled
out); ``SCENARIOS`` holds them, :func:`scenario` returns one with fields overridden and validated,
and :func:`read_config` reads a user's ``--config`` TOML.
"""

import dataclasses
import re
import tomllib
from dataclasses import dataclass
from importlib import resources

from loopid.algorithms.collect import SAMPLING_MODES
from loopid.algorithms.loop_program import TEST_POLICIES
from loopid.algorithms.plant import check_delay_reading
from loopid.algorithms.policy_gradient_step import SAMPLES_MODES as PG_SAMPLES
from loopid.algorithms.policy_gradient_step import UPDATES as PG_UPDATES
from loopid.experiments.families.helicopter.readings import (
    DEFAULT_PRESET,
    NU_T_CENTERS,
    PRESETS,
    READING_FIELDS,
    reading_text,
    readings_line,
)
from loopid.settings import model_planner
from loopid.settings.checks import check_int, check_number, replaced
from loopid.settings.toml import read_flat_file
from loopid.systems.helicopter.funnel_nominal import FUNNEL_NOMINALS
from loopid.systems.helicopter.tasks import TASK_DELAYS, TASK_NAMES


@dataclass(frozen=True)
class Scenario(model_planner.ModelPlanner):
    """One panel of the paper's Figure 2.

    Attributes:
      name: the scenario name (``hover``, ``hover-delay``, ``funnel``).
      task: the helicopter task (:data:`loopid.systems.helicopter.tasks.TASK_NAMES`).
      iterations: N, policies per run (iteration 1 is the initial model; N − 1 batches).
      samples: m, transitions per iteration.
      test_trajectories: test trajectories per evaluation point (common random numbers).
      seeds: how many seeds (0..seeds−1).
      noise_std: process-noise std on force and torque (None: the task's).
      delay: actuation delay in steps (None: the task's).
      sampling: the policy half's sampling mode, ``trajectory`` or ``geometric``.
      gamma: stopping parameter of ``geometric`` sampling (stop w.p. 1 − γ per step).
      dagger_fraction: DAgger's probability that a slot comes from the current policy.
      stop_norm: training trajectories restart when ‖[Δx; Δu]‖₂ exceeds this.
      nu_pending, delay_mode, funnel_nominal, pads, pg_samples, pg_update, nu_t_center: the
        readings of the
        details the paper leaves open (:mod:`loopid.experiments.families.helicopter.readings`);
        their defaults are the preset
        ``probable``: ``delay_mode = "latency"`` (the policy acts at once on the state observed
        d steps earlier; the learner records the true transition), ``nu_pending = "hold"``
        (used under ``fifo`` only), ``funnel_nominal = "heading"``, ``pads = True`` and
        ``pg_samples = "rollouts"`` (one perturbed-gain rollout per sample), ``pg_update =
        "descent"`` (gradient descent, each rollout its own noise) and ``nu_t_center =
        "nominal"`` (ν_t's noise around the expert's planned flight).
      nu_state_var, nu_action_var: ν_t's state and action noise variances.
      expert_action_var: ν_en's action noise variance.
      ftrl_lambda: λ of the FTRL regulariser (λ/√n)‖W‖²_F.
      test_policy: the policy tested: ``last`` (the paper's), ``best`` (lowest measured
        cost so far) or ``mixture`` (one of π_1..π_n drawn per test trajectory).
      cost_cap: a test trajectory's total cost is capped here (and counted as diverged).
      pg_horizon, pg_sigma, pg_step: the policy-gradient baseline's longest rollout (steps),
        perturbation size in action units and first trust radius in probing radii (see
        :mod:`loopid.algorithms.policy_gradient`).
      model_*, planner_*: the model class and the optimal-control solver
        (:mod:`loopid.settings.model_planner`; default the paper's linear model and LQR).
    """

    name: str
    task: str
    iterations: int
    samples: int
    test_trajectories: int = 100
    seeds: int = 20
    noise_std: float | None = None
    delay: int | None = None
    pads: bool = PRESETS[DEFAULT_PRESET]["pads"]
    sampling: str = "trajectory"
    gamma: float = 0.99
    dagger_fraction: float = 0.5
    stop_norm: float = 5.0
    nu_pending: str = PRESETS[DEFAULT_PRESET]["nu_pending"]
    delay_mode: str = PRESETS[DEFAULT_PRESET]["delay_mode"]
    funnel_nominal: str = PRESETS[DEFAULT_PRESET]["funnel_nominal"]
    pg_samples: str = PRESETS[DEFAULT_PRESET]["pg_samples"]
    pg_update: str = PRESETS[DEFAULT_PRESET]["pg_update"]
    nu_t_center: str = PRESETS[DEFAULT_PRESET]["nu_t_center"]
    nu_state_var: float = 0.0025
    nu_action_var: float = 0.0001
    expert_action_var: float = 0.0001
    ftrl_lambda: float = 1e-3
    test_policy: str = "last"
    cost_cap: float = 1e8
    pg_horizon: int = 600
    pg_sigma: float = 0.01
    pg_step: float = 0.1

    def __post_init__(self) -> None:
        validate(self)

    def replace(self, **changes) -> "Scenario":
        """A copy with ``changes``; unknown field names raise ``ValueError`` naming them."""
        return replaced(self, changes, "scenario")

    def to_dict(self) -> dict:
        """The fields as a plain dict (None values dropped, for TOML); the model and planner
        fields only when one of them differs from the paper's agent, so that a run of the
        paper's agent records the same ``config.toml`` as before they existed."""
        d = dataclasses.asdict(self)
        keep = [k for k in d if k not in model_planner.FIELDS]
        if not model_planner.is_default(self):
            keep += model_planner.FIELDS
        return {k: d[k] for k in keep if d[k] is not None}


_NAME = re.compile(r"[a-z0-9][a-z0-9-]*")


def validate(s: Scenario) -> None:
    """Raise ``ValueError`` naming the first bad field of ``s`` and what is allowed."""
    if not isinstance(s.name, str) or not _NAME.fullmatch(s.name):
        raise ValueError(
            f"name must be lower-case letters, digits and '-' (a file name), got {s.name!r}"
        )
    if not isinstance(s.task, str) or s.task not in TASK_NAMES:
        raise ValueError(f"task must be one of {', '.join(TASK_NAMES)}, got {s.task!r}")
    check_int("iterations", s.iterations)
    check_int("samples", s.samples)
    check_int("test_trajectories", s.test_trajectories)
    check_int("seeds", s.seeds)
    check_int("pg_horizon", s.pg_horizon)
    if s.noise_std is not None:
        check_number("noise_std", s.noise_std, 0.0)
    if s.delay is not None:
        check_int("delay", s.delay, minimum=0)
    if not isinstance(s.pads, bool):
        raise ValueError(f"pads must be true or false, got {s.pads!r}")
    if s.sampling not in SAMPLING_MODES:
        raise ValueError(f"sampling must be one of {', '.join(SAMPLING_MODES)}, got {s.sampling!r}")
    if s.test_policy not in TEST_POLICIES:
        raise ValueError(
            f"test_policy must be one of {', '.join(TEST_POLICIES)}, got {s.test_policy!r}"
        )
    check_delay_reading(s.delay_mode, s.nu_pending)
    if s.funnel_nominal not in FUNNEL_NOMINALS:
        raise ValueError(
            f"funnel_nominal must be one of {', '.join(FUNNEL_NOMINALS)}, got {s.funnel_nominal!r}"
        )
    if s.pg_samples not in PG_SAMPLES:
        raise ValueError(f"pg_samples must be one of {', '.join(PG_SAMPLES)}, got {s.pg_samples!r}")
    if s.pg_update not in PG_UPDATES:
        raise ValueError(f"pg_update must be one of {', '.join(PG_UPDATES)}, got {s.pg_update!r}")
    if s.nu_t_center not in NU_T_CENTERS:
        raise ValueError(
            f"nu_t_center must be one of {', '.join(NU_T_CENTERS)}, got {s.nu_t_center!r}"
        )
    check_number("gamma", s.gamma, 0.0, 1.0 - 1e-12, open_low=True)
    check_number("dagger_fraction", s.dagger_fraction, 0.0, 1.0)
    check_number("stop_norm", s.stop_norm, 0.0, open_low=True)
    for name in ("nu_state_var", "nu_action_var", "expert_action_var", "ftrl_lambda"):
        check_number(name, getattr(s, name), 0.0)
    check_number("cost_cap", s.cost_cap, 0.0, open_low=True)
    check_number("pg_sigma", s.pg_sigma, 0.0, open_low=True)
    check_number("pg_step", s.pg_step, 0.0, open_low=True)
    model_planner.validate(s)
    if s.planner_kind == "mpc" and s.test_policy != "last":
        raise ValueError(
            f"planner_kind 'mpc' flies the last policy only, got test_policy {s.test_policy!r}"
        )
    delay = TASK_DELAYS[s.task] if s.delay is None else s.delay
    if s.planner_kind == "mpc" and s.delay_mode == "latency" and delay > 0:
        raise ValueError(
            f"planner_kind 'mpc' flies delay_mode 'fifo' only, got delay_mode 'latency' with "
            f"delay {delay}"
        )


FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Scenario))


def from_dict(d: dict, *, where: str = "scenario") -> Scenario:
    """A :class:`Scenario` from a dict of fields; unknown or missing keys raise ``ValueError``."""
    unknown = sorted(set(d) - set(FIELDS))
    if unknown:
        raise ValueError(
            f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(FIELDS)}"
        )
    missing = [k for k in ("name", "task", "iterations", "samples") if k not in d]
    if missing:
        raise ValueError(f"{where}: missing key(s) {', '.join(missing)}")
    try:
        return Scenario(**d)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None


def _load_packaged() -> dict[str, Scenario]:
    folder = resources.files("loopid.experiments.families.helicopter") / "scenarios"
    out = {}
    for name in ("hover", "hover-delay", "funnel"):  # the paper's panel order
        text = (folder / f"{name}.toml").read_text(encoding="utf-8")
        out[name] = from_dict(tomllib.loads(text), where=f"scenarios/{name}.toml")
    return out


#: The paper's three panels, from the TOML files shipped in the package.
SCENARIOS: dict[str, Scenario] = _load_packaged()


def scenario(base: str, /, **overrides) -> Scenario:
    """The scenario ``base`` of :data:`SCENARIOS` with ``overrides`` (validated; ``name`` may be
    overridden too, e.g. for a variant of a panel)."""
    if base not in SCENARIOS:
        raise ValueError(f"unknown scenario {base!r}; choose from {', '.join(SCENARIOS)}")
    return SCENARIOS[base].replace(**overrides)


def read_config(path) -> tuple[dict, list[str] | None]:
    """A user's ``--config`` TOML: flat keys, each a :class:`Scenario` field or ``methods`` (a
    list of method names). Returns ``(fields, methods or None)``; one-line ``ValueError`` for an
    unreadable file, bad TOML or an unknown key (values are checked when the scenario is built).
    """
    return read_flat_file(path, FIELDS, tables=model_planner.TABLES)


__all__ = [
    "FIELDS", "READING_FIELDS", "SCENARIOS", "Scenario", "from_dict", "read_config",
    "reading_text", "readings_line", "scenario", "validate",
]  # fmt: skip
