"""A run's seeds: a config's ``seeds`` (a count or a tuple) as an array, and the seeds as
``config.toml`` records them."""

import numpy as np


def seed_list(config) -> np.ndarray:
    """A config's seeds as an integer array: ``range(seeds)`` for a count, else the tuple."""
    seeds = config.seeds
    if isinstance(seeds, int | np.integer) and not isinstance(seeds, bool):
        return np.arange(int(seeds))
    return np.asarray(seeds, dtype=np.int64)


def seeds_value(seeds) -> int | dict | list[int]:
    """The seeds as ``config.toml`` records them: a count ``n`` for 0..n−1, ``{start, count}``
    for another run of consecutive seeds, else the list (:func:`seeds_from_value` inverts it)."""
    seeds = np.asarray(seeds, dtype=np.int64)
    if seeds.size and np.array_equal(seeds, np.arange(seeds[0], seeds[0] + seeds.size)):
        if seeds[0] == 0:
            return int(seeds.size)
        return {"start": int(seeds[0]), "count": int(seeds.size)}
    return [int(s) for s in seeds]


def seeds_from_value(value) -> np.ndarray:
    """The seed array of a :func:`seeds_value` (or of an older ``config.toml``'s list)."""
    if isinstance(value, dict):
        return np.arange(value["start"], value["start"] + value["count"], dtype=np.int64)
    if isinstance(value, int):
        return np.arange(value, dtype=np.int64)
    return np.asarray(value, dtype=np.int64)
