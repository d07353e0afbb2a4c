"""A killed ``update``, run again, leaves the same directory as one uninterrupted update: the
kill is simulated at each of the update's writes (the write raises, as a kill would stop it)."""

import numpy as np
import pytest
from rounds_helpers import transitions, write_config, write_round

from loopid import rounds
from loopid.rounds import api
from loopid.rounds.state import read_npz


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
