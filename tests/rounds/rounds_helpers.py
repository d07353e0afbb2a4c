"""A small linear system to identify round by round, its config and its round files."""

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

STATES, ACTIONS = ("p", "v"), ("f",)
#: The system the files come from: o' = F o + G a + c + noise.
F = np.array([[1.0, 0.1], [-0.05, 0.9]])
G = np.array([[0.0], [0.1]])
C = np.array([0.0, 0.02])

CONFIG = """
[system]
states = ["p", "v"]
actions = ["f"]
target = [0.5, 0.0]
action_op = [0.1]
horizon = 30
{system}
[cost]
Q = [1.0, 0.1]
R = [0.01]

[model]
lambda = 0.01
{model}
[rounds]
samples = {samples}
{rounds}
"""


def write_config(path, *, samples=40, system="", model="", rounds="") -> str:
    """The config file at ``path``; the keyword arguments add lines to their tables."""
    path.write_text(CONFIG.format(samples=samples, system=system, model=model, rounds=rounds))
    return str(path)


def transitions(rng, rows: int, *, t=False) -> dict:
    """``rows`` random transitions of the system, half labelled policy, half nu."""
    x = rng.normal(size=(rows, 2))
    u = rng.normal(size=(rows, 1))
    xn = x @ F.T + u @ G.T + C + 0.01 * rng.normal(size=(rows, 2))
    cols = {"p": x[:, 0], "v": x[:, 1], "f": u[:, 0], "next_p": xn[:, 0], "next_v": xn[:, 1]}
    cols["source"] = ["policy" if i % 2 else "nu" for i in range(rows)]
    if t:
        cols["t"] = rng.integers(0, 30, size=rows)
    return cols


def write_round(path, cols: dict) -> str:
    if str(path).endswith(".csv"):
        pacsv.write_csv(pa.table(cols), path)
    else:
        pq.write_table(pa.table(cols), path)
    return str(path)
