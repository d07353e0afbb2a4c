"""The experiment pipeline above the loop: scenarios and their readings, families of systems,
run directories with resume and atomic files, executors (local workers, Ray, accelerators),
reports, figures, saved models and controllers, and the readings study.

Public means listed here and documented: every submodule below is part of the API.
"""

__all__ = [
    "artifacts",
    "backend",
    "checks",
    "chunks",
    "evaluate",
    "execute",
    "executors",
    "families",
    "findings",
    "flights",
    "learned",
    "plots",
    "readings",
    "report",
    "results",
    "rundir",
    "saved",
    "scenarios",
    "seeds",
    "study",
    "study_readings",
    "study_report",
    "tasks",
]
