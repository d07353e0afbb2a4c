"""A killed ``update``, run again, leaves the same directory as one uninterrupted update: the
kill is simulated at each of the update's writes (the write raises, as a kill would stop it)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rounds_helpers import transitions, write_config, write_round

from loopid import rounds
from loopid.rounds import api
from loopid.rounds.state import RoundState, load_state, read_npz, save_state


def contents(root) -> dict:
    """Every file under ``root`` (temporary files left by a kill excepted): arrays for .npz
    (their zip headers hold a time), bytes otherwise."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and ".tmp-" not in p.name:
            key = str(p.relative_to(root))
            out[key] = read_npz(p) if p.suffix == ".npz" else p.read_bytes()
    return out


def same(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    for k in a:
        x, y = a[k], b[k]
        if isinstance(x, dict):
            if x.keys() != y.keys() or not all(np.array_equal(x[i], y[i]) for i in x):
                return False
        elif x != y:
            return False
    return True


def start(tmp_path, name: str):
    rng = np.random.default_rng(5)
    root = tmp_path / name
    rounds.init(root, write_config(tmp_path / "c.toml"))
    files = [write_round(tmp_path / f"r{k}.parquet", transitions(rng, 40)) for k in (1, 2)]
    rounds.update(root, files[0])
    return root, files[1]


class Killed(BaseException):
    """Stands for SIGKILL: not an error the code may catch."""


@pytest.mark.parametrize("at", ["write_atomic", "write_npz", "write_bytes", "save_state"])
def test_killed_update_then_rerun_equals_one_update(tmp_path, monkeypatch, at):
    whole, second = start(tmp_path, "whole")
    rounds.update(whole, second)
    killed, _ = start(tmp_path, "killed")
    before = contents(killed)

    def kill(*args, **kwargs):
        raise Killed

    with monkeypatch.context() as m:
        m.setattr(api, at, kill)
        with pytest.raises(Killed):
            rounds.update(killed, second)
    committed = read_npz(killed / "state.npz")
    assert np.array_equal(committed["meta"], before["state.npz"]["meta"])  # nothing counted
    rounds.update(killed, second)  # not refused: the file was not counted
    assert same(contents(killed), contents(whole))
    with pytest.raises(ValueError, match="already given"):
        rounds.update(killed, second)


def test_state_round_trip_keeps_every_leaf(tmp_path):
    """A learner's state with a typed random key (the MLP's), ints and floats comes back as it
    was saved: same structure, dtypes and values."""
    learner = {"key": jax.random.key(4), "n": jnp.int32(7), "W": jnp.arange(6.0).reshape(2, 3)}
    state = RoundState(3, learner, 1.5, ("ab", "cd"), ({"round": 1, "loss_nu": None},))
    save_state(tmp_path, state)
    template = {"key": jax.random.key(0), "n": jnp.int32(0), "W": jnp.zeros((2, 3))}
    back = load_state(tmp_path, template)
    assert back._replace(learner=None) == state._replace(learner=None)
    assert back.learner["n"].dtype == jnp.int32 and int(back.learner["n"]) == 7
    np.testing.assert_array_equal(back.learner["W"], learner["W"])
    assert jnp.array_equal(
        jax.random.key_data(back.learner["key"]), jax.random.key_data(learner["key"])
    )
