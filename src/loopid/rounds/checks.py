"""A round's file against its round directory: rows not learned already, and the plan's split.

Both checks run after the file itself is checked (:mod:`loopid.rounds.data`) and before anything
is written; a refusal is one line of ``ValueError`` naming the file.

**The same rows again.** A row is what the learner takes from it: its state, action and next
state (and its step ``t`` for a time-varying model) as float64 numbers, after parsing. The
``source`` label is not part of it: the same transition labelled otherwise is still the same
data. Rows are compared by the bytes of those float64 numbers (:func:`row_keys`), with ``-0.0``
made ``+0.0`` first (adding ``+0.0`` does that and changes no other value). That is exact: two
finite float64 numbers are equal if and only if their bytes are, apart from the two zeros, and
the file's values are finite (checked). The comparison is by sorting (``np.isin`` on the rows'
bytes), not by a hash, so no two different rows can ever be taken for equal. The rows already
learned are the committed rounds' own copies, ``data/round-NNN.parquet``: Parquet keeps each
parsed value exactly, whatever format and compression the given file had. Then

- a file whose rows all equal rows already learned is refused, naming the earlier file(s): the
  same log saved again, perhaps as CSV or with another Parquet compression, would be learned
  twice and weigh twice in the fit;
- a file that shares only some rows is learned, with a warning (:class:`RoundWarning`) giving
  the overlap: a system at rest with quantised sensors logs identical rows.

**The split.** Algorithm 1 draws each of a round's ``m`` rows from running the current
controller with probability ``p`` (the method's policy fraction, ``round.md``'s plan), and from
ν otherwise; the learner's guarantee is for that mixture (for DAgger's ½, the state
distribution ½ν + ½π of the paper's analysis). So the number of policy rows ``k`` of a round
drawn as planned is Binomial(m, p). A file whose ``k`` lies outside the central
:data:`LEVEL` interval of that binomial, ``[F⁻¹(α/2), F⁻¹(1 − α/2)]`` with ``α = 1 −``
:data:`LEVEL` and ``F⁻¹`` its quantile function (``scipy.stats.binom.ppf``), is refused unless
the split is accepted (``--accept-split``): a round drawn as planned falls outside it with
probability at most ``α`` = 0.1 %. With ``p = 0`` (Batch; Abbeel's first round) any policy row
is refused, with ``p = 1`` any ν row.
"""

import warnings
from pathlib import Path

import numpy as np
from scipy.stats import binom

from loopid.algorithms.schedules import policy_fractions
from loopid.rounds.config import RoundsConfig
from loopid.rounds.data import RoundData, read_round
from loopid.rounds.state import data_path

#: The probability that a round drawn as planned passes the split check.
LEVEL = 0.999


class RoundWarning(UserWarning):
    """A file that was learned from, with something to know about it (one line)."""


def row_keys(data: RoundData, config: RoundsConfig) -> np.ndarray:
    """``[b]`` the rows' identities (module docstring): each row's float64 values ``[x, u,
    x_next(, t)]``, ``-0.0`` made ``+0.0``, as one opaque byte string (``np.void``)."""
    cols = [data.x, data.u, data.x_next]
    if config.time_varying:
        cols.append(data.t[:, None].astype(np.float64))
    rows = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype=np.float64) + 0.0
    return rows.view(np.dtype((np.void, rows.shape[1] * 8))).ravel()


def learned_rows(root, config: RoundsConfig, state) -> list[RoundData]:
    """The committed rounds' data (one file per update, by the controller that collected it);
    a copy that cannot be read is named, in one line, as damaged (nothing is recomputed: the
    copy holds what was given)."""
    out = []
    for n in range(1, state.round):
        path = data_path(root, n)
        try:
            out.append(read_round(path, config, episodes=False))
        except ValueError as err:
            why = str(err).split(": ", 1)[-1]
            if why.startswith("cannot read it ("):
                why = why[len("cannot read it (") : -1]
            raise ValueError(
                f"{str(path)!r} is damaged ({why}); restore it from a copy of the round directory"
            ) from None
    return out


def _named(state, rounds) -> str:
    files = state.files
    names = [
        f"round {n} ({files[n - 1]!r})" if n <= len(files) else f"round {n}" for n in rounds[:3]
    ]
    return ", ".join(names) + (f" and {len(rounds) - 3} more" if len(rounds) > 3 else "")


def overlap(path, data: RoundData, past: list[RoundData], state, config: RoundsConfig) -> None:
    """Refuse ``data`` when all its rows equal rows of ``past`` (the rounds of ``state``); warn
    (:class:`RoundWarning`) with the overlap when some do (module docstring)."""
    if not past:
        return
    new = row_keys(data, config)
    seen = np.zeros(new.shape, bool)
    rounds = []
    for n, d in enumerate(past, start=1):
        hit = np.isin(new, row_keys(d, config))
        if hit.any():
            rounds.append(n)
        seen |= hit
    k, b = int(seen.sum()), new.size
    if k == b:
        raise ValueError(
            f"{str(path)!r}: every row equals a row already learned, from {_named(state, rounds)}:"
            " the same data again (another format or compression has the same rows); not learned"
        )
    if k:
        warnings.warn(
            f"{str(path)!r}: {k} of {b} rows ({100 * k / b:.3g} %) equal rows already learned, "
            f"from {_named(state, rounds)}; learned anyway (a system at rest with quantised "
            "sensors logs identical rows; the same log twice would be refused)",
            RoundWarning,
            stacklevel=3,
        )


def interval(m: int, p: float) -> tuple[int, int]:
    """The central :data:`LEVEL` interval ``[lo, hi]`` of Binomial(m, p) (module docstring)."""
    alpha = 1.0 - LEVEL
    return int(binom.ppf(alpha / 2, m, p)), int(binom.ppf(1 - alpha / 2, m, p))


def split(path, data: RoundData, config: RoundsConfig, n: int, accept: bool = False) -> None:
    """Refuse ``data``, collected while controller ``n`` was deployed, when its policy rows lie
    outside :func:`interval` of the plan (module docstring), unless ``accept``."""
    m = int(data.policy.size)
    k = int(data.policy.sum())
    p = float(policy_fractions(config.method, n + 1, dagger_fraction=config.dagger_fraction)[n])
    lo, hi = interval(m, p)
    if accept or lo <= k <= hi:
        return
    plan = round(p * m)
    raise ValueError(
        f"{str(Path(path))!r}: {k} policy rows and {m - k} nu rows, against a plan of {plan} and "
        f"{m - plan} (policy fraction {p:g}); {100 * LEVEL:g} % of rounds drawn as planned have "
        f"{lo} to {hi} policy rows. Collect the split round.md asks for, or accept this one "
        "with --accept-split"
    )
