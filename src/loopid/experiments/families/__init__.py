"""The registry of families: which kind of system a scenario is
(:class:`~loopid.experiments.families.base.Family`).

Families are found through the Python entry point group ``loopid.families``: each entry names a
:class:`~base.Family` instance, ``name = "package.module:FAMILY"``. loopid's own register the
same way in its ``pyproject.toml``::

    [project.entry-points."loopid.families"]
    helicopter = "loopid.experiments.families.helicopter:FAMILY"
    mdp = "loopid.experiments.families.mdp:FAMILY"
    gym = "loopid.experiments.families.gym:FAMILY"

so a family can live in another installed package, and worker processes and Ray workers, which
load the same entry points, find it too. loopid's own families come first, in the order above
(``helicopter``: the paper's Figure 2, ``hover``, ``hover-delay``, ``funnel``; ``mdp``:
``mdp-random``, ``mdp-trap``, ``mdp-trap-hinge``; ``gym``: any Gymnasium env from a
``--config`` file), then the others by name. :func:`register` adds a family from Python (a
script's), for this process only.

The registry is read once, at the first call that needs it: importing this module loads no
family.
"""

from functools import cache
from importlib.metadata import entry_points

from loopid.experiments.families.base import Family, FunctionFamily

#: The entry point group a family registers under.
GROUP = "loopid.families"
#: loopid's own families, first in this order.
OWN = ("helicopter", "mdp", "gym")


@cache
def families() -> dict[str, Family]:
    """Every family, by name: the entry points of :data:`GROUP` (loopid's own first), then
    those :func:`register` added. ``TypeError`` naming an entry point that is not a Family, or
    whose name is not the family's."""
    found = sorted(entry_points(group=GROUP), key=lambda e: (e.name not in OWN, _rank(e.name)))
    out: dict[str, Family] = {}
    for entry in found:
        family = entry.load()
        if not isinstance(family, Family):
            raise TypeError(
                f"entry point {entry.name} = {entry.value!r} of group {GROUP!r} is not a Family "
                f"(got {type(family).__name__})"
            )
        if family.name != entry.name:
            raise TypeError(
                f"entry point {entry.name} = {entry.value!r} names the family {family.name!r}"
            )
        out.setdefault(family.name, family)
    return out


def _rank(name: str) -> tuple[int, str]:
    return (OWN.index(name), "") if name in OWN else (len(OWN), name)


def register(family: Family) -> Family:
    """Add ``family`` to :func:`families` in this process (a family defined in a script; worker
    processes do not see it: give it an entry point instead). Its name and scenario names must
    not be taken. Returns it."""
    if not isinstance(family, Family):
        raise TypeError(f"register takes a Family, got {type(family).__name__}")
    taken = scenario_names()
    clash = sorted(n for n in (family.scenarios or [family.name]) if n in taken)
    if family.name in families() or clash:
        raise ValueError(f"family {family.name!r} or scenario name(s) {clash} already taken")
    families()[family.name] = family
    return family


def scenario_names() -> dict[str, Family]:
    """Every scenario name ``loopid run`` accepts, with its family (a family without shipped
    scenarios, as ``gym``, builds from a file and answers to its own name)."""
    names = {}
    for family in families().values():
        for name in family.scenarios or [family.name]:
            names[name] = family
    return names


def family_named(scenario: str) -> Family:
    """The family of scenario name ``scenario``; ``ValueError`` listing the names."""
    names = scenario_names()
    if scenario not in names:
        raise ValueError(f"unknown scenario {scenario!r}; choose from {', '.join(names)}")
    return names[scenario]


def family_called(name: str) -> Family:
    """The family called ``name`` (as ``config.toml`` records it); ``ValueError`` listing
    them."""
    if name not in families():
        raise ValueError(f"unknown family {name!r}; registered: {', '.join(families())}")
    return families()[name]


def family_of(config) -> Family:
    """The family whose config type ``config`` is."""
    for family in families().values():
        if isinstance(config, family.config):
            return family
    raise TypeError(
        f"{type(config).__name__} is not the config of any registered family (a worker process "
        f"finds the families of the {GROUP!r} entry points: give the family one)"
    )


__all__ = [
    "GROUP",
    "Family",
    "FunctionFamily",
    "families",
    "family_called",
    "family_named",
    "family_of",
    "register",
    "scenario_names",
]
