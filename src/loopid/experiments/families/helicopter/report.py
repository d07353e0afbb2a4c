"""A helicopter run's report sections and the paper's Figure 2, drawn from a results table
alone (``loopid plot DIR``).

Report (:func:`report`): the final costs per panel, each with its readings, and the paper's five
findings (:mod:`loopid.experiments.families.helicopter.findings`).

Figure (:func:`figure`): one panel per scenario in the table (in the table's order; the paper's
three are hover, hover with delay 1, nose-in funnel, top to bottom). In each: for every method, the
mean test cost over seeds against the samples collected so far (x linear, from 0: iteration 1 is the
initial model, with no data), a band of ± one standard error of that mean, y on a log axis. The
linearised expert L is a flat line (its mean over seeds). Means over seeds are what the paper plots;
a few diverging seeds (capped at ``cost_cap``) dominate early means, which is why the report also
gives medians. Matplotlib's Agg backend: no display needed.
"""

from pathlib import Path

import pyarrow as pa

from loopid.experiments import curves
from loopid.experiments.families.helicopter.findings import findings_section
from loopid.experiments.families.helicopter.scenario import Scenario, readings_line
from loopid.experiments.report import final_cost_sections
from loopid.settings import model_planner
from loopid.systems.helicopter.tasks import is_hover

#: Label, colour and line style per method (the paper's legend names).
STYLE = {
    "dagger-t": ("$D_t$", "C0", "-"),
    "dagger-e": ("$D_e$", "C1", "-"),
    "dagger-en": ("$D_{en}$", "C2", "-"),
    "batch-t": ("$B_t$", "C0", "--"),
    "batch-e": ("$B_e$", "C1", "--"),
    "batch-en": ("$B_{en}$", "C2", "--"),
    "abbeel": ("$A$", "C3", "-."),
    "expert": ("$L$", "black", "-"),
    "pg": ("PG", "C4", ":"),
    # the reading study's other readings of the policy gradient
    "pg (transitions)": ("PG, transitions", "C5", "-"),
    "pg (descent)": ("PG, descent", "C6", "-"),
}
TITLES = {"hover": "Hover", "hover-delay": "Hover, delay 1", "funnel": "Nose-in funnel"}


def report(table, configs: dict[str, Scenario]) -> list[str]:
    """The final costs per panel, each with its readings
    (:mod:`loopid.experiments.families.helicopter.readings`), and the five findings."""
    notes = {
        name: f"Readings: {readings_line(s)}."
        + ("" if model_planner.is_default(s) else f" {model_planner.describe(s)}")
        for name, s in configs.items()
    }
    hover = {name for name, s in configs.items() if is_hover(s.task)}
    return [*final_cost_sections(table, notes), *findings_section(table, hover)]


def figure(table: pa.Table, path: Path, configs=None) -> Path:
    """Figure 2 of ``table`` into ``path`` (:func:`loopid.experiments.curves.figure` with the
    paper's legend names and panel titles); return ``path``. ``configs`` (the run's scenarios)
    is not needed: the table names its panels."""
    return curves.figure(table, path, styles=STYLE, titles=TITLES)
