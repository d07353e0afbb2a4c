"""A round directory on disk: what is kept between rounds, and how it is committed.

Layout of ``DIR``::

    config.toml               the config, as given to loopid round init
    state.npz                 the learner's state, the round counter, the files already given
                              (their SHA-256 and the names they were given by), each round's
                              diagnostics and the scale the model is fitted in
                              (loopid.rounds.scale): the commit record
    controllers/round-NNN.npz controller N (π_N): gains K [horizon, m, n] in Δx = [o − o*; 1]
                              (a = a_op − K_t Δx), the identified model A, B in the log's
                              units (a linear model) or the model an MPC controller re-plans
                              on, and the scale (scale_states, scale_actions)
    data/round-NNN.parquet    the transitions collected while controller N was deployed
    round.md                  what to collect next and what the data say

Every file is written to a temporary name and renamed (:func:`replace_atomically`). An update
writes its data, controller and ``round.md`` first and ``state.npz`` last: until that last
rename the directory's state is the previous round's (the new round's files are overwritten
when the update is run again), after it the whole round is there. So a killed update loses
nothing and counts nothing twice: the file's hash is recorded in the same rename as the
learner's new state.
"""

import json
import zipfile
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from loopid.files import replace_atomically

STATE = "state.npz"
CONFIG = "config.toml"
REPORT = "round.md"


class RoundState(NamedTuple):
    """What ``state.npz`` holds.

    Attributes:
      round: the latest controller's number N (1 after ``init``).
      learner: the agent's state (a pytree; its structure is the agent's ``init()``'s).
      loss_sum: the sum over updates of the model's mean loss on the round's rows before the
        update (the online loss times the number of updates).
      digests: the SHA-256 of every file already given, in order.
      history: one dict of diagnostics per update (:mod:`loopid.rounds.report`).
      files: the path each of those files was given by, in order (what a refusal of the same
        rows names; empty for a directory written before the paths were kept).
      scale: the :meth:`loopid.rounds.scale.Scale.to_json` of the scale set by the first
        update (None before it, and in a directory saved before rounds were scaled).
    """

    round: int
    learner: Any
    loss_sum: float
    digests: tuple
    history: tuple
    files: tuple = ()
    scale: Any = None


def controller_path(root, n: int) -> Path:
    return Path(root) / "controllers" / f"round-{n:03d}.npz"


def data_path(root, n: int) -> Path:
    return Path(root) / "data" / f"round-{n:03d}.parquet"


def is_round_dir(root) -> bool:
    return (Path(root) / STATE).is_file()


def write_bytes(path: Path, data: bytes) -> None:
    """``data`` to ``path`` atomically (its folder made if needed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    replace_atomically(path, lambda tmp: tmp.write_bytes(data))


def write_npz(path: Path, arrays: dict) -> None:
    """``arrays`` as ``.npz`` at ``path``, atomically (its folder made if needed)."""
    path.parent.mkdir(parents=True, exist_ok=True)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)

    replace_atomically(path, write)


def read_npz(path: Path) -> dict:
    """Every array of an ``.npz`` file; one-line ValueError naming it when it is missing or
    cannot be read (a round directory's files are not computed again: they hold what was given)."""
    if not Path(path).is_file():
        raise ValueError(f"{str(path)!r} is missing")
    try:
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:  # closes a bad zip too
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        what = " ".join(str(err).split()) or type(err).__name__
        raise ValueError(
            f"{str(path)!r} is damaged ({what}); restore it from a copy of the round directory"
        ) from None


def _is_key(v) -> bool:
    return jax.numpy.issubdtype(v.dtype, jax.dtypes.prng_key)


def _plain(v) -> np.ndarray:
    """A leaf as a NumPy array (a typed random key as its key data, e.g. the MLP's)."""
    return np.asarray(jax.random.key_data(v) if _is_key(v) else v)


def _restored(a: np.ndarray, like):
    """The leaf ``a`` saved by :func:`_plain`, with the dtype of the template leaf ``like``."""
    if _is_key(like):
        return jax.random.wrap_key_data(jax.numpy.asarray(a), impl=jax.random.key_impl(like))
    return jax.numpy.asarray(a, dtype=like.dtype)


def save_state(root, state: RoundState) -> None:
    """Commit ``state`` (one atomic rename of ``state.npz``)."""
    leaves = jax.tree_util.tree_leaves(state.learner)
    meta = {
        "round": state.round, "loss_sum": state.loss_sum, "digests": list(state.digests),
        "history": list(state.history), "files": list(state.files), "scale": state.scale,
    }  # fmt: skip
    arrays = {f"leaf_{i}": _plain(v) for i, v in enumerate(leaves)}
    write_npz(Path(root) / STATE, {**arrays, "meta": np.asarray(json.dumps(meta))})


def load_state(root, template) -> RoundState:
    """The committed state of ``root``; ``template``: a learner state of the same structure
    (the agent's ``init()``)."""
    root = Path(root)
    if not is_round_dir(root):
        raise ValueError(f"{str(root)!r} is not a round directory (run loopid round init)")
    z = read_npz(root / STATE)
    meta = json.loads(str(z["meta"]))
    leaves, tree = jax.tree_util.tree_flatten(template)
    if len(z) - 1 != len(leaves):
        raise ValueError(f"{str(root / STATE)!r} does not fit the config's model class")
    learner = jax.tree_util.tree_unflatten(
        tree, [_restored(z[f"leaf_{i}"], v) for i, v in enumerate(leaves)]
    )
    return RoundState(
        int(meta["round"]), learner, float(meta["loss_sum"]), tuple(meta["digests"]),
        tuple(meta["history"]), tuple(meta.get("files", ())), meta.get("scale"),
    )  # fmt: skip
