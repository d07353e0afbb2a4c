"""The registry of families: which kind of system a scenario is (:class:`base.Family`).

Families: ``helicopter`` (the paper's Figure 2: ``hover``, ``hover-delay``, ``funnel``), ``mdp``
(``mdp-random``, ``mdp-trap``, ``mdp-trap-hinge``) and ``gym`` (``gym``: any Gymnasium env from
a ``--config`` file). A new kind of system is one new module with a ``FAMILY`` added to
:data:`FAMILIES` (README, "Add your own system").
"""

from loopid.experiments.families import gym, helicopter, mdp
from loopid.experiments.families.base import Family, FunctionFamily

#: Every family, by name.
FAMILIES: dict[str, Family] = {f.name: f for f in (helicopter.FAMILY, mdp.FAMILY, gym.FAMILY)}


def register(family: Family) -> Family:
    """Add ``family`` to :data:`FAMILIES` (a family defined outside loopid, from Python); its
    scenario names must not be taken. Returns it."""
    if not isinstance(family, Family):
        raise TypeError(f"register takes a Family, got {type(family).__name__}")
    taken = scenario_names()
    clash = sorted(n for n in (family.scenarios or [family.name]) if n in taken)
    if family.name in FAMILIES or clash:
        raise ValueError(f"family {family.name!r} or scenario name(s) {clash} already taken")
    FAMILIES[family.name] = family
    return family


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
    raise TypeError(
        f"{type(config).__name__} is not the config of any registered family (a worker process "
        "knows the families its imports register: define a family in an importable module)"
    )


__all__ = [
    "FAMILIES",
    "Family",
    "FunctionFamily",
    "family_named",
    "family_of",
    "register",
    "scenario_names",
]
