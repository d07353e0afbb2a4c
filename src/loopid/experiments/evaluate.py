"""``loopid evaluate RUN_DIR``: a run's saved controllers on fresh test episodes.

For every chosen (scenario, method, seed) with saved artifacts (:mod:`.artifacts`), the final
policy flies ``episodes`` new test episodes (noise the run never saw: key stream 4 of the seed,
or slot stream 4 for a Gymnasium env; ``env``: another Gymnasium id, to test transfer) through
its family's ``evaluate``. One row per (scenario, method, seed) is appended to
``RUN_DIR/evaluate.parquet`` (written atomically):

    scenario, method, seed, episodes, env, mean, se, recorded

``mean`` and ``se`` are the mean capped cost over the episodes and its standard error; ``recorded``
is the run's own final test cost of that seed (``results.parquet``), for comparison.
"""

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from loopid.experiments import artifacts
from loopid.experiments.results import read_table
from loopid.files import write_atomic

SCHEMA = pa.schema(
    [
        ("scenario", pa.string()),
        ("method", pa.string()),
        ("seed", pa.int64()),
        ("episodes", pa.int64()),
        ("env", pa.string()),
        ("mean", pa.float64()),
        ("se", pa.float64()),
        ("recorded", pa.float64()),
    ]
)


def _recorded(run_dir: Path) -> dict[tuple[str, str, int], float]:
    table = read_table(run_dir / "results.parquet").to_pydict()
    last: dict[tuple[str, str], int] = {}
    for s, m, it in zip(table["scenario"], table["method"], table["iteration"], strict=True):
        last[(s, m)] = max(last.get((s, m), 0), it)
    columns = ("scenario", "method", "seed", "iteration", "test_cost")
    return {
        (s, m, seed): cost
        for s, m, seed, it, cost in zip(*(table[c] for c in columns), strict=True)
        if it == last[(s, m)]
    }


def evaluate_run(
    run_dir, *, scenario=None, method=None, seed=None, episodes=None, env=None
) -> pa.Table:
    """Evaluate the chosen saved controllers (default: every one) and append their rows to
    ``evaluate.parquet``; returns the new rows. ``ValueError`` (one line) for a run directory,
    scenario, method or seed that is not there, or ``episodes < 1``."""
    from loopid.experiments.execute import run_family

    run_dir = Path(run_dir)
    if not (run_dir / "config.toml").is_file() or not (run_dir / "results.parquet").is_file():
        raise ValueError(f"{str(run_dir)!r} is not a finished run directory")
    family, configs = run_family(run_dir)
    if family.evaluate is None:
        raise ValueError(f"the {family.name} family cannot evaluate saved controllers")
    if episodes is not None and (isinstance(episodes, bool) or episodes < 1):
        raise ValueError(f"--episodes must be >= 1, got {episodes!r}")
    names = list(configs) if scenario is None else [scenario]
    for name in names:
        if name not in configs:
            raise ValueError(f"{run_dir} has no scenario {name!r}; it has {', '.join(configs)}")
    recorded = _recorded(run_dir)
    path = run_dir / "evaluate.parquet"
    try:  # the rows appended to, read before any controller flies
        before = pq.read_table(path) if path.is_file() else None
    except (OSError, pa.ArrowException) as e:
        remedy = "move it away (it holds earlier evaluations) and evaluate again"
        raise artifacts.Damaged(path, str(e), remedy) from None
    rows = []
    for name in names:
        found = (run_dir / "cells").glob(f"{name}__*.json")
        saved = sorted(p.stem.split("__", 1)[1] for p in found)
        methods = saved if method is None else [method]
        if method is not None and method not in saved:
            raise ValueError(
                f"{name} has no saved controller of method {method!r}; it has {', '.join(saved)}"
            )
        config = configs[name]
        n = episodes or getattr(config, "test_trajectories", 1)
        for m in methods:
            _, arrays = artifacts.read(run_dir / "cells", name, m)
            seeds = arrays["seeds"]
            pick = np.ones(seeds.shape, bool) if seed is None else seeds == seed
            if not pick.any():
                raise ValueError(f"seed {seed!r} is not in {name}/{m}; its seeds: {seeds.tolist()}")
            chosen = {
                k: v if k.startswith("shared.") else v[pick]
                for k, v in arrays.items()
                if k != "seeds"
            }
            costs = family.evaluate(config, chosen, seeds[pick], n, env)
            for k, c in zip(seeds[pick].tolist(), costs, strict=True):
                se = float(np.std(c, ddof=1) / np.sqrt(c.size)) if c.size > 1 else 0.0
                rows.append((name, m, k, n, env or "", float(np.mean(c)), se,
                             recorded.get((name, m, k), np.nan)))  # fmt: skip
    new = pa.table(
        {f.name: pa.array([r[i] for r in rows], f.type) for i, f in enumerate(SCHEMA)},
        schema=SCHEMA,
    )
    table = new if before is None else pa.concat_tables([before, new])
    write_atomic(table, path)
    return new
