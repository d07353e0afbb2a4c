"""The registry of families: which kind of system a scenario is (:class:`base.Family`).

Families: ``helicopter`` (the paper's Figure 2: ``hover``, ``hover-delay``, ``funnel``), ``mdp``
(``mdp-random``, ``mdp-trap``, ``mdp-trap-hinge``) and ``gym`` (``gym``: any Gymnasium env from
a ``--config`` file). A new kind of system is one new module with a ``FAMILY`` added to
:data:`FAMILIES` (README, "Add your own system").
"""

from loopid.experiments.families import gym, helicopter, mdp
from loopid.experiments.families.base import Family

#: Every family, by name.
FAMILIES: dict[str, Family] = {f.name: f for f in (helicopter.FAMILY, mdp.FAMILY, gym.FAMILY)}


def scenario_names() -> dict[str, Family]:
    """Every scenario name ``loopid run`` accepts, with its family (``gym`` is built from a
    file, so it is the one name of a family without shipped scenarios)."""
    names = {}
    for family in FAMILIES.values():
        for name in family.scenarios or [family.name]:
            names[name] = family
    return names


def family_named(scenario: str) -> Family:
    """The family of scenario name ``scenario``; ``ValueError`` listing the names."""
    names = scenario_names()
    if scenario not in names:
        raise ValueError(f"unknown scenario {scenario!r}; choose from {', '.join(names)}")
    return names[scenario]


def family_of(config) -> Family:
    """The family whose config type ``config`` is."""
    for family in FAMILIES.values():
        if isinstance(config, family.config):
            return family
    raise TypeError(f"{type(config).__name__} is not the config of any family")


__all__ = ["FAMILIES", "Family", "family_named", "family_of", "scenario_names"]
