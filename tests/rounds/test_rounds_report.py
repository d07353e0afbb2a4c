"""round.md: the next round's split by method, and the model-class check."""

from rounds_helpers import write_config

from loopid.rounds import read_config
from loopid.rounds.report import HIGH, check, split


def test_split_follows_the_method(tmp_path):
    def config(method):
        path = tmp_path / f"{method}.toml"
        return read_config(write_config(path, samples=9, rounds=f'method = "{method}"'))

    dagger, batch, abbeel = (config(m) for m in ("dagger", "batch", "abbeel"))
    assert [split(dagger, n) for n in (1, 2, 5)] == [(4, 5), (4, 5), (4, 5)]  # round(4.5) = 4
    assert [split(batch, n) for n in (1, 2, 5)] == [(0, 9)] * 3
    assert [split(abbeel, n) for n in (1, 2, 5)] == [(0, 9), (9, 0), (9, 0)]


def row(relative, cost):
    return {"relative": relative, "policy_cost": cost}


def test_the_model_class_check():
    assert check([row(1.0, 5.0)]).startswith("Too early")
    poor = check([row(2 * HIGH, 5.0), row(3 * HIGH, 5.0)])
    assert poor.startswith("**The model class looks too poor.**") and "richer model class" in poor
    assert check([row(2 * HIGH, 5.0), row(3 * HIGH, 4.0)]).startswith("The aggregate loss is high")
    assert check([row(HIGH / 2, 5.0), row(HIGH / 3, 5.0)]).startswith("The model class fits")
