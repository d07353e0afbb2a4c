"""Algorithm 1 one round at a time: :func:`init`, :func:`update`, :func:`controller`.

Ross & Bagnell (2012), Algorithm 1, for a system that cannot be stepped from Python (a rig, a
drone, a plant): each iteration n of the loop is one call, and a person runs the system in
between. ``init`` solves the initial model for π_1. Each ``update`` is iteration n + 1: the
transitions logged while π_n was deployed (the policy's rows and ν's, in the proportion
``round.md`` asked for) are one batch for the online learner (FTRL by default: after the k-th
update the model is the ridge fit on every row so far, regulariser λ/√(rows) on the mean loss,
i.e. λ√(rows) on the summed loss), the new model is solved (LQR for the linear model; iLQR or
MPC for the others) and π_{n+1} is written out. The fit and the solve run in the directory's
scaled coordinates (:mod:`loopid.rounds.scale`: each column in units of its first round's
standard deviation, so the controller does not depend on the log's units); the controller and
the identified model are saved in the log's units.

The agent is an observed system's (:func:`loopid.algorithms.host_agent.compiled_agent`, the
same model class × learner × planner as a Gymnasium scenario's), and the losses are the loop's
(:func:`loopid.algorithms.loop_program.batch_losses`): under ``[rounds] scale = "none"`` a round
fed the transitions a ``loopid run gym`` iteration learned from gives that iteration's model and
gains.
"""

from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.host_agent import CompiledAgent, compiled_agent
from loopid.algorithms.loop_program import batch_losses
from loopid.files import write_atomic
from loopid.rounds import checks, report
from loopid.rounds.config import RoundsConfig, read_config
from loopid.rounds.data import RoundData, read_round, transitions
from loopid.rounds.episodes import summary
from loopid.rounds.model import gain_change, linear_model, pull
from loopid.rounds.scale import (
    Scale,
    from_rows,
    log_gains,
    log_model,
    scaled_config,
    scaled_rows,
    unit,
)
from loopid.rounds.state import (
    CONFIG,
    REPORT,
    RoundState,
    controller_path,
    data_path,
    is_round_dir,
    load_state,
    read_npz,
    save_state,
    write_bytes,
    write_npz,
)


class Update(NamedTuple):
    """What one :func:`update` did: the new controller's number, the diagnostics it recorded
    (a :mod:`loopid.rounds.report` row) and the new gains ``K [horizon, m, n]``."""

    round: int
    row: dict
    K: np.ndarray


def _agent(config: RoundsConfig) -> CompiledAgent:
    try:
        return compiled_agent(config.spec, config.shape)
    except (ValueError, TypeError) as err:
        raise ValueError(str(err).splitlines()[0]) from None


def load_config(root) -> RoundsConfig:
    """The config of the round directory ``root``."""
    root = Path(root)
    if not is_round_dir(root):
        raise ValueError(f"{str(root)!r} is not a round directory (run loopid round init)")
    return read_config(root / CONFIG)


def _controller_arrays(config: RoundsConfig, compiled: CompiledAgent, learner, sc: Scale) -> dict:
    """Controller arrays in the log's units from the agent ``compiled`` of the scaled config."""
    K, info = jax.jit(compiled.agent.policy)(learner)
    arrays = {
        "kind": np.asarray("mpc" if compiled.mpc is not None else "gains"),
        "K": log_gains(np.asarray(K), sc), "target": np.asarray(config.target, np.float64),
        "action_op": np.asarray(config.action_op, np.float64),
        "states": np.asarray(config.states), "actions": np.asarray(config.actions),
        "converged": np.asarray(bool(info.converged)),
        "scale_states": sc.states, "scale_actions": sc.actions,
    }  # fmt: skip
    if compiled.agent.params is not None:
        params = compiled.agent.params(learner)
        arrays |= {f"model_{k}": np.asarray(v) for k, v in params.items()}
        AB = linear_model(scaled_config(config, sc), params)
        if AB is not None:
            arrays["A"], arrays["B"] = log_model(*AB, sc)
    return arrays


def init(root, config_path) -> Path:
    """Start the round directory ``root`` from the config file ``config_path``: solve the
    initial model, write controller 1 and ``round.md``. Refuses a directory already started."""
    root = Path(root)
    if is_round_dir(root):
        raise ValueError(f"{str(root)!r} is already a round directory")
    text = Path(config_path).read_bytes() if Path(config_path).is_file() else None
    config = read_config(config_path)
    compiled = _agent(config)
    learner = compiled.agent.init()
    arrays = _controller_arrays(config, compiled, learner, unit(config, "no data yet"))
    state = RoundState(1, learner, 0.0, (), ())
    write_bytes(root / CONFIG, text)
    write_npz(controller_path(root, 1), arrays)
    write_bytes(root / REPORT, report.render(config, state, arrays).encode())
    save_state(root, state)
    return controller_path(root, 1)


#: Why a directory saved before rounds were scaled keeps the log's units (module scale).
LEGACY = (
    "this round directory was started before rounds were scaled, and its model was learned in "
    "the log's units; start a new directory from the same files for the scaled fit"
)


def _scale(state: RoundState, data: RoundData, config: RoundsConfig) -> Scale:
    """The directory's scale: recorded, set by this first round, or unit for an old one."""
    if state.scale is not None:
        return Scale.from_json(state.scale)
    if state.round == 1:
        return from_rows(data.x, data.u, config)
    return unit(config, LEGACY)


def update(root, path, *, accept_split: bool = False) -> Update:
    """One iteration of Algorithm 1 on the transitions of the file ``path``
    (:mod:`loopid.rounds.data`): the learner's step, the new model solved, controller N + 1
    written, ``round.md`` rewritten, then the state committed (:mod:`loopid.rounds.state`).

    Refused (one-line ``ValueError``, nothing written): a file already given, one whose rows
    were all learned already, one whose split of policy and ν rows is far from the plan's
    (unless ``accept_split``; :mod:`loopid.rounds.checks`). A file that shares some rows with
    earlier ones is learned with a :class:`~loopid.rounds.checks.RoundWarning`.

    The model is fitted and solved in the directory's scaled coordinates
    (:mod:`loopid.rounds.scale`, set by the first update); the losses are in those units."""
    root = Path(root)
    config = load_config(root)
    state = load_state(root, _agent(config).agent.init())
    data = read_round(path, config)
    if data.digest in state.digests:
        given = state.digests.index(data.digest) + 1
        raise ValueError(f"{str(path)!r} was already given (the data of round {given})")
    past = checks.learned_rows(root, config, state)
    checks.split(path, data, config, state.round, accept_split)
    checks.overlap(path, data, past, state, config)
    sc = _scale(state, data, config)
    config_s = scaled_config(config, sc)
    compiled = _agent(config_s)
    agent = compiled.agent
    before = agent.init() if state.round == 1 else state.learner
    rows = [scaled_rows(d, sc) for d in [*past, data]]
    batch = transitions(rows[-1], config_s)
    take = jnp.asarray(data.policy)
    pol = batch._replace(mask=batch.mask & take)
    nu = batch._replace(mask=batch.mask & ~take)
    loss_nu, loss_pol, loss_batch = batch_losses(agent, before, pol, nu, take)
    learner = jax.jit(agent.update)(before, batch)
    n = state.round
    loss = jax.jit(agent.loss)
    per_round = [float(jnp.mean(loss(learner, transitions(d, config_s)))) for d in rows]
    counts = [d.x.shape[0] for d in rows]
    loss_all = float(np.average(per_round, weights=counts))
    spread = float(np.mean([np.sum((d.x_next - d.x) ** 2, 1).mean() for d in rows]))
    loss_sum = state.loss_sum + float(loss_batch)
    arrays = _controller_arrays(config, compiled, learner, sc)
    AB = linear_model(config_s, compiled.agent.params(learner)) if agent.params else None
    previous = read_npz(controller_path(root, n))["K"]
    row = report.row(
        config, n, data, loss_nu=float(loss_nu), loss_policy=float(loss_pol),
        loss_all=loss_all, relative=loss_all / spread if spread > 0 else float("inf"),
        online=loss_sum / n, regret=loss_sum - float(np.sum(per_round)),
    ) | {
        "gain_change": gain_change(arrays["K"], previous, sc),
        "pull": pull(config_s, rows, AB, sc, config), "episodes": summary(config, data),
    }  # fmt: skip
    new = RoundState(
        n + 1, learner, loss_sum, (*state.digests, data.digest), (*state.history, row),
        (*state.files, str(path)), sc.to_json(),
    )  # fmt: skip
    data_path(root, n).parent.mkdir(exist_ok=True)
    write_atomic(data.table, data_path(root, n))
    write_npz(controller_path(root, n + 1), arrays)
    write_bytes(root / REPORT, report.render(config, new, arrays).encode())
    save_state(root, new)
    return Update(n + 1, row, arrays["K"])


def controller_arrays(root, n: int | None = None) -> dict:
    """The saved arrays of controller ``n`` (default the latest committed one) of ``root``,
    with its number as ``round``."""
    root = Path(root)
    config = load_config(root)
    latest = load_state(root, _agent(config).agent.init()).round
    n = latest if n is None else n
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= latest:
        raise ValueError(f"--round must be 1..{latest} (the controllers so far), got {n!r}")
    return {**read_npz(controller_path(root, n)), "round": np.asarray(n)}


class Controller:
    """A saved linear controller: ``action(o [n_obs], t) -> a [m]``,
    ``a = a_op − K_{min(t, T−1)} [o − o*; 1]``."""

    def __init__(self, arrays: dict):
        self.K = np.asarray(arrays["K"], np.float64)
        self.target = np.asarray(arrays["target"], np.float64)
        self.action_op = np.asarray(arrays["action_op"], np.float64)

    def action(self, o, t: int = 0) -> np.ndarray:
        dx = np.append(np.asarray(o, np.float64) - self.target, 1.0)
        return self.action_op - self.K[min(max(int(t), 0), self.K.shape[0] - 1)] @ dx


def saved_scale(arrays: dict) -> Scale:
    """The scale a controller's arrays were solved in (unit for one saved before scaling)."""
    m, n_obs = len(arrays["actions"]), len(arrays["states"])
    return Scale(
        np.asarray(arrays.get("scale_states", np.ones(n_obs))),
        np.asarray(arrays.get("scale_actions", np.ones(m))),
    )


def controller(root, n: int | None = None) -> Any:
    """Controller ``n`` (default the latest) of ``root`` as a :class:`Controller`; an MPC
    controller is the compiled agent's MPC on the saved model (``act(obs [k, n_obs], t,
    index)``)."""
    arrays = controller_arrays(root, n)
    if str(arrays["kind"]) != "mpc":
        return Controller(arrays)
    from loopid.algorithms.planning_agent import restore_seeds

    sc = saved_scale(arrays)
    compiled = _agent(scaled_config(load_config(root), sc))
    saved = {k[len("model_") :]: v[None] for k, v in arrays.items() if k.startswith("model_")}
    mpc = compiled.mpc(restore_seeds(compiled.model, saved))
    return mpc if sc.unit else ScaledPolicy(mpc, sc)


class ScaledPolicy:
    """An MPC controller planned in scaled coordinates (:mod:`loopid.rounds.scale`), acting in
    the log's units: ``act(obs [k, n_obs], t, index) -> a [k, m]``."""

    def __init__(self, mpc, sc: Scale):
        self.mpc, self.scale = mpc, sc

    def act(self, obs, t, index) -> np.ndarray:
        a = self.mpc.act(np.asarray(obs, np.float64) / self.scale.states, t, index)
        return np.asarray(a) * self.scale.actions

    def reset(self) -> None:
        self.mpc.reset()
