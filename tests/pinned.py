"""A run's results table against a pinned one, held to what a CPU of another kind reproduces.

XLA compiles for the CPU's own vector instructions, so a CPU of another kind (or the same CPU
told to use fewer of them: ``XLA_FLAGS=--xla_cpu_max_isa=...``) rounds differently. A test
trajectory that diverges, or a policy that has not settled, is chaotic: it amplifies those
roundings, so its cost is not a figure a pin can hold. :func:`assert_matches_pin` holds each
column to what survives another instruction set (the pinned table's columns only; ``ours`` may
have more):

- identity, every row, exactly and in the same order: ``scenario, method, seed, iteration,
  samples`` (:data:`IDENTITY`);
- a row is *settled* when its test cost is at most ``factor`` × L (L: the pinned expert's test
  cost on the same scenario and seed) and it has no diverged test trajectory, in ``ours`` and in
  the pin alike; a row settled in one and not the other fails (rounding does not move a
  contracting closed loop from 1-4 × L past 10 × L, nor a 1.8e6 one below it);
- settled rows: every float column to ``rtol`` relative (1e-10), every int and bool exactly;
- unsettled rows: ``test_cost`` and ``test_cost_median`` (:data:`TEST_SIDE`) are not compared,
  ``diverged`` within ±1, every other float column (the model's losses, the solve's spectral
  radius, system diagnostics: all of the training side) to ``rtol_training`` (1e-6), every other
  int and bool (``policy_samples``, ``valid_samples``, ``solver_converged``) exactly.

Why, measured against ``tests/fixtures/reproduce_quick_literal.parquet`` (216 rows then, 208 now
that its funnel policy-gradient rows are gone; its settled ones are the 24 expert rows, at 1 × L,
and hover DAgger-ν_e seed 1 iteration 4, at 3.7 × L; every
learned row with a diverged test trajectory is at 1.2e7 to the cap of 1e8, and the unsettled
ones without at 1.8e6 to 9.6e6, 2.9e4 × L and more):

- rounding moves the test cost of a row with a diverged trajectory by up to 14 % relative, its
  median by up to 16 %, and its ``diverged`` count by one: on an AMD EPYC with AVX-512, 32 test
  costs moved and three counts by one; with ``--xla_cpu_max_isa=SSE4_2``, 33 costs (14 %) and one
  count; with ``AVX`` (no FMA), 29 costs (12.5 %), 14 medians (16 %) and one count. The one moved
  row without a diverged trajectory is hover-delay DAgger-ν_en seed 1 iteration 3, at 1.8e6
  (2.9e4 × L), by 2.5e-8 to 3.5e-8 relative: a policy that has not settled;
- the training side of a row is the model's fit to data flown by the cell's earlier policies,
  chaotic too when those diverged, but averaged over the batch: with SSE4.2 or AVX its losses
  moved by at most 1.9e-9 relative (Abbeel hover seed 0 iteration 4, after a policy whose test
  cost moved by 1 % and 12 %) and the spectral radius by at most 5.6e-11; the counts of policy
  and usable draws and the solver's verdicts never moved (the draws are set by the seeds, and no
  safe-region cut happens in that table). 1e-6 leaves a margin of 500, and a changed reading
  moves far more: the ``probable`` readings leave the experts' rows as they are but move 220
  losses by 7e-5 to order one, 34 spectral radii by 4.6e-5 and more, and 61 ``diverged`` counts
  by two or more;
- no settled row's test cost moved by 1e-10 on any CPU or instruction set tried, nor any other
  column of theirs with SSE4.2 or AVX; natively, on two AMD EPYCs of the three CPUs that ran it,
  no column moved by more than 1.1e-12 relative.

The rule is the same on every architecture (``platform.machine()``: x86_64 with any instruction
set, arm64/aarch64): settled rows are held to 1e-10 everywhere, and only unsettled ones move.
"""

import platform

import numpy as np
import pyarrow as pa

#: The columns that name a row: equal exactly, row for row, in every row.
IDENTITY = ("scenario", "method", "seed", "iteration", "samples")
#: The test rollouts' floats: chaotic in an unsettled row, so compared only in settled ones.
TEST_SIDE = ("test_cost", "test_cost_median")
#: The count of test trajectories that reached the cap: within ±1 in an unsettled row.
DIVERGED = "diverged"
#: The method whose test cost is a panel's L.
EXPERT = "expert"
#: A settled row's test cost is at most this many times L.
FACTOR = 10.0


def expert_costs(pinned: pa.Table, expert: str = EXPERT) -> dict[tuple[str, int], float]:
    """L of each ``(scenario, seed)``: the pinned expert's test cost (the same on every
    iteration, so the largest is taken)."""
    rows = pinned.select(["scenario", "method", "seed", "test_cost"]).to_pylist()
    L: dict[tuple[str, int], float] = {}
    for r in rows:
        if r["method"] == expert:
            key = (r["scenario"], r["seed"])
            L[key] = max(L.get(key, 0.0), r["test_cost"])
    return L


def settled(table: pa.Table, L: dict, factor: float = FACTOR) -> np.ndarray:
    """Which rows of ``table`` are settled: test cost at most ``factor`` × L of their scenario and
    seed, and no diverged test trajectory. Raises when a row's scenario and seed have no L."""
    panels = zip(table["scenario"].to_pylist(), table["seed"].to_pylist(), strict=True)
    try:
        bound = factor * np.array([L[k] for k in panels], dtype=np.float64)
    except KeyError as e:
        raise AssertionError(f"the pinned table has no expert row for {e.args[0]}") from None
    cost = table["test_cost"].to_numpy()
    return (cost <= bound) & (table[DIVERGED].to_numpy() == 0)


def keys(table: pa.Table, columns=IDENTITY) -> list[tuple]:
    """Each row's identity, a tuple of its ``columns`` (those of them the table has)."""
    present = [c for c in columns if c in table.column_names]
    return list(zip(*(table[c].to_pylist() for c in present), strict=True))


def _is_float(t: pa.DataType) -> bool:
    return pa.types.is_floating(t)


def _py(x):
    """A NumPy scalar as its Python value (for messages)."""
    return x.item() if isinstance(x, np.generic) else x


def _row_name(pinned: pa.Table, i: int) -> str:
    return " ".join(str(pinned[c][i].as_py()) for c in IDENTITY if c in pinned.column_names)


def assert_matches_pin(
    ours: pa.Table,
    pinned: pa.Table,
    *,
    rtol: float = 1e-10,
    rtol_training: float = 1e-6,
    factor: float = FACTOR,
    expert: str = EXPERT,
    shown: int = 40,
) -> None:
    """Assert that the results table ``ours`` matches ``pinned`` under the module's rule: the
    pinned columns present with their types, the same rows in the same order, settled rows to
    ``rtol`` (ints exactly), unsettled rows' ``diverged`` within ±1, their training-side floats
    to ``rtol_training``, their other ints exactly, their test costs not compared. Columns of
    ``ours`` that the pin lacks are ignored. Every failure is listed (the first ``shown``)."""
    where = f"on {platform.machine() or 'an unknown machine'}"
    missing = [f.name for f in pinned.schema if f.name not in ours.column_names]
    assert not missing, f"{where}: pinned columns missing from ours: {missing}"
    retyped = [
        f"{f.name}: {ours.schema.field(f.name).type} (pinned {f.type})"
        for f in pinned.schema
        if ours.schema.field(f.name).type != f.type
    ]
    assert not retyped, f"{where}: pinned columns of another type: {retyped}"
    ours = ours.select(pinned.column_names)

    identity = [c for c in IDENTITY if c in pinned.column_names]
    if ours.num_rows != pinned.num_rows:
        a, b = set(keys(ours)), set(keys(pinned))
        raise AssertionError(
            f"{where}: {ours.num_rows} rows, pinned {pinned.num_rows}; "
            f"missing {sorted(b - a)[:shown]}, extra {sorted(a - b)[:shown]}"
        )
    for c in identity:
        a, b = ours[c].to_numpy(zero_copy_only=False), pinned[c].to_numpy(zero_copy_only=False)
        moved = np.flatnonzero(a != b)
        assert not moved.size, (
            f"{where}: identity column {c!r} differs in {moved.size} rows, first row "
            f"{moved[0]}: {a[moved[0]]!r}, pinned {b[moved[0]]!r}"
        )

    L = expert_costs(pinned, expert)
    calm, calm_pin = settled(ours, L, factor), settled(pinned, L, factor)
    failures = [
        f"row {_row_name(pinned, i)}: {'settled' if calm_pin[i] else 'unsettled'} in the pin, "
        f"not in ours (test cost {ours['test_cost'][i].as_py()!r}, pinned "
        f"{pinned['test_cost'][i].as_py()!r}; diverged {ours[DIVERGED][i].as_py()}, pinned "
        f"{pinned[DIVERGED][i].as_py()})"
        for i in np.flatnonzero(calm != calm_pin)
    ]
    calm &= calm_pin
    for f in pinned.schema:
        if f.name in identity:
            continue
        a = ours[f.name].to_numpy(zero_copy_only=False)
        b = pinned[f.name].to_numpy(zero_copy_only=False)
        if f.name == DIVERGED:
            bad = np.where(calm, a != b, np.abs(a - b) > 1)
            rule = "exactly when settled, within ±1 otherwise"
        elif _is_float(f.type):
            close = np.isclose(a, b, rtol=rtol, atol=0, equal_nan=True)
            if f.name in TEST_SIDE:
                loose = np.ones_like(close)
                rule = f"to {rtol:g} relative when settled, not compared otherwise"
            else:
                loose = np.isclose(a, b, rtol=rtol_training, atol=0, equal_nan=True)
                rule = f"to {rtol:g} relative when settled, {rtol_training:g} otherwise"
            bad = ~np.where(calm, close, loose)
        else:
            bad = a != b
            rule = "exactly"
        failures += [
            f"row {_row_name(pinned, i)}, {f.name} ({rule}): {_py(a[i])!r}, pinned {_py(b[i])!r}"
            for i in np.flatnonzero(bad)
        ]
    if failures:
        listed = "\n".join(failures[:shown])
        more = f"\n... and {len(failures) - shown} more" if len(failures) > shown else ""
        raise AssertionError(
            f"{where}: {len(failures)} differences from the pin "
            f"({int(calm.sum())} of {pinned.num_rows} rows settled):\n{listed}{more}"
        )
