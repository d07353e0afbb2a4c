"""Settings below the experiments and the round directories: value checks with one-line errors,
TOML files and values, and the ``[model]`` and ``[planner]`` settings that choose an agent.

Public means listed here and documented: every submodule below is part of the API.
"""

__all__ = [
    "checks",
    "model_planner",
    "observed",
    "toml",
]
