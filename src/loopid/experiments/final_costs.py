"""Per-seed test costs of a results table, by scenario, method and iteration (:class:`Costs`),
and how a report writes a cost (:func:`significant`).

Every report of a run reads its final costs through :class:`Costs`: the final iteration of a
(scenario, method) cell is its largest ``iteration``; a seed counts as diverged at an iteration
when one of its test trajectories hit the cap or a non-finite state (``diverged > 0``).
"""

import numpy as np
import pyarrow as pa

from loopid.experiments.paired import pair


class Costs:
    """Per-seed test costs of a table, by (scenario, method, iteration)."""

    def __init__(self, table: pa.Table):
        self.scenario = np.asarray(table.column("scenario").to_pylist(), dtype=object)
        self.method = np.asarray(table.column("method").to_pylist(), dtype=object)
        self.seed = np.asarray(table.column("seed"))
        self.iteration = np.asarray(table.column("iteration"))
        self.cost = np.asarray(table.column("test_cost"))
        self.diverged = np.asarray(table.column("diverged"))
        self.scenarios = list(dict.fromkeys(self.scenario))
        self.methods = list(dict.fromkeys(self.method))

    def has(self, s: str, m: str) -> bool:
        return bool(np.any((self.scenario == s) & (self.method == m)))

    def last_iteration(self, s: str, m: str) -> int:
        return int(self.iteration[(self.scenario == s) & (self.method == m)].max())

    def _rows(self, s: str, m: str, iteration: int | None) -> np.ndarray:
        it = self.last_iteration(s, m) if iteration is None else iteration
        return (self.scenario == s) & (self.method == m) & (self.iteration == it)

    def at(self, s: str, m: str, iteration: int | None = None) -> np.ndarray:
        """``[seeds]`` test costs at ``iteration`` (default: the final one)."""
        return self.cost[self._rows(s, m, iteration)]

    def paired(
        self, s: str, a: str, b: str, it_a: int | None = None, it_b: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The test costs of methods ``a`` (at ``it_a``) and ``b`` (at ``it_b``; default: each
        one's final iteration) on the seeds both ran, aligned by seed."""
        ra, rb = self._rows(s, a, it_a), self._rows(s, b, it_b)
        return pair(self.seed[ra], self.cost[ra], self.seed[rb], self.cost[rb])

    def diverged_seeds(self, s: str, m: str) -> int:
        """Seeds with at least one diverged test trajectory at the final iteration."""
        sel = (self.scenario == s) & (self.method == m)
        sel &= self.iteration == self.last_iteration(s, m)
        return int(np.sum(self.diverged[sel] > 0))


def significant(x: float) -> str:
    """``x`` to four significant digits (``f"{x:.4g}"``), as every report writes a cost."""
    return f"{x:.4g}"
