"""The experiment pipeline above the loop: run directories with resume and atomic files, cells,
executors (local workers, Ray, accelerators), reports, learning curves, saved models and
controllers; and the families of systems it runs (:mod:`loopid.experiments.families`: the
helicopter of the paper's Figure 2 with its readings study, finite MDPs, Gymnasium envs), which
it reaches only through their registry.

Public means listed here and documented: every submodule below is part of the API.
"""

__all__ = [
    "artifacts",
    "backend",
    "checks",
    "chunks",
    "commands",
    "compilations",
    "curves",
    "evaluate",
    "execute",
    "executors",
    "families",
    "final_costs",
    "jobs",
    "learned",
    "report",
    "results",
    "rundir",
    "saved",
    "seeds",
]
