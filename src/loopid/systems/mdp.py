r"""Finite MDPs as pytrees, and three constructors: random, slippery gridworld, trap.

A :class:`FiniteMDP` holds every quantity of the paper's section 2 for a finite system:

- ``P [S, A, S]``: the transition tensor, ``P[s, a, s'] = T_sa(s')`` (rows sum to 1);
- ``C [S, A]``: the known cost, with every entry in the stated range ``[c_min, c_max]``;
- ``gamma``: the discount, in (0, 1);
- ``mu [S]``: the start distribution.

Costs are per step and unitless; ``J_μ(π) = E_{s∼μ} V_π(s)`` is a discounted sum. All leaves are
float64 arrays, so a stack of MDPs (leading batch axes on every leaf) is itself a FiniteMDP and
the solvers in :mod:`loopid.control.value_iteration` take it as is.

The trap MDP (:func:`trap_mdp`) is the paper's section-3 drawback of Batch made concrete; its
docstring gives the construction and why Batch falls into it while DAgger does not.
"""

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "TRAP_JUMP",
    "TRAP_WALK",
    "FiniteMDP",
    "check_mdp",
    "cost_range",
    "gridworld",
    "horizon_factor",
    "make_mdp",
    "random_mdp",
    "trap_mdp",
]


class FiniteMDP(NamedTuple):
    """A finite MDP: ``P [S, A, S]``, ``C [S, A]``, ``gamma`` (scalar), ``mu [S]`` and the known
    cost range ``c_min``, ``c_max`` (scalars). Batch axes, when present, lead every leaf."""

    P: jax.Array
    C: jax.Array
    gamma: jax.Array
    mu: jax.Array
    c_min: jax.Array
    c_max: jax.Array

    @property
    def n_states(self) -> int:
        return int(self.P.shape[-1])

    @property
    def n_actions(self) -> int:
        return int(self.P.shape[-2])


def cost_range(mdp: FiniteMDP) -> jax.Array:
    """``C_rng = c_max − c_min``."""
    return mdp.c_max - mdp.c_min


def horizon_factor(mdp: FiniteMDP) -> jax.Array:
    """The paper's ``H = γ C_rng / (1 − γ)²`` (relates L1 model error to total-cost error)."""
    return mdp.gamma * cost_range(mdp) / (1.0 - mdp.gamma) ** 2


def _f64(x):
    return jnp.asarray(x, dtype=jnp.float64)


def make_mdp(P, C, gamma, mu, c_min=None, c_max=None) -> FiniteMDP:
    """A checked :class:`FiniteMDP` (no batch axes) from array-likes; ``c_min``/``c_max``
    default to the smallest/largest cost. Raises ``ValueError`` naming a bad argument."""
    P, C, mu = np.asarray(P, np.float64), np.asarray(C, np.float64), np.asarray(mu, np.float64)
    c_min = float(C.min()) if c_min is None else float(c_min)
    c_max = float(C.max()) if c_max is None else float(c_max)
    mdp = FiniteMDP(_f64(P), _f64(C), _f64(gamma), _f64(mu), _f64(c_min), _f64(c_max))
    check_mdp(mdp)
    return mdp


def check_mdp(mdp: FiniteMDP, atol: float = 1e-9) -> FiniteMDP:
    """Validate shapes and (on concrete arrays) values; batch axes allowed. Returns ``mdp``.

    Raises ``ValueError`` naming the field: P not ``[..., S, A, S]`` or rows not distributions,
    C not ``[..., S, A]`` or outside ``[c_min, c_max]``, gamma outside (0, 1), mu not a
    distribution over the S states.
    """
    P, C, mu = mdp.P, mdp.C, mdp.mu
    if P.ndim < 3 or P.shape[-1] != P.shape[-3]:
        raise ValueError(f"P must have shape [..., S, A, S], got {P.shape}")
    S, A = P.shape[-1], P.shape[-2]
    batch = P.shape[:-3]
    if C.shape != (*batch, S, A):
        raise ValueError(f"C must have shape {(*batch, S, A)} (P is {P.shape}), got {C.shape}")
    if mu.shape != (*batch, S):
        raise ValueError(f"mu must have shape {(*batch, S)}, got {mu.shape}")
    for name in ("gamma", "c_min", "c_max"):
        if np.shape(getattr(mdp, name)) != batch:
            raise ValueError(f"{name} must have shape {batch}, got {np.shape(getattr(mdp, name))}")
    if any(isinstance(x, jax.core.Tracer) for x in mdp):
        return mdp
    P, C, mu = np.asarray(P), np.asarray(C), np.asarray(mu)
    g = np.asarray(mdp.gamma)
    lo, hi = np.asarray(mdp.c_min), np.asarray(mdp.c_max)
    if not (np.isfinite(P).all() and (P >= 0).all()) or not np.allclose(P.sum(-1), 1, atol=atol):
        raise ValueError("P rows must be probability distributions (non-negative, sum 1)")
    if not ((g > 0) & (g < 1)).all():
        raise ValueError(f"gamma must lie in (0, 1), got {g}")
    if not (np.isfinite(mu).all() and (mu >= 0).all()) or not np.allclose(mu.sum(-1), 1, atol=atol):
        raise ValueError("mu must be a probability distribution over the states")
    if not (lo <= hi).all():
        raise ValueError(f"c_min must be <= c_max, got {lo} > {hi}")
    lo_b, hi_b = lo[..., None, None], hi[..., None, None]
    if not (np.isfinite(C).all() and (C >= lo_b).all() and (C <= hi_b).all()):
        raise ValueError(f"C must be finite and within [c_min, c_max] = [{lo}, {hi}]")
    return mdp


def random_mdp(
    key: jax.Array,
    n_states: int,
    n_actions: int,
    *,
    gamma: float = 0.9,
    concentration: float = 1.0,
) -> FiniteMDP:
    """A random MDP: every row ``T_sa ∼ Dirichlet(concentration · 1_S)``, costs ``C ∼ U[0, 1]``
    (range [0, 1]), uniform μ. ``key`` may carry batch axes ``[B]`` (then every leaf does).

    Small concentrations (< 1) give sparse rows (few likely successors), 1 gives uniform
    distributions on the simplex.
    """
    for name, v in (("n_states", n_states), ("n_actions", n_actions)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    if not 0.0 < gamma < 1.0:
        raise ValueError(f"gamma must lie in (0, 1), got {gamma!r}")
    if not concentration > 0:
        raise ValueError(f"concentration must be > 0, got {concentration!r}")
    return _random_mdp_fn(int(n_states), int(n_actions), float(gamma), float(concentration))(key)


@lru_cache(maxsize=16)
def _random_mdp_fn(S: int, A: int, gamma: float, concentration: float):
    """The jitted sampler for one configuration (cached: compiled once per shape of key)."""

    @jax.jit
    def sample(key):
        def one(k):
            k_p, k_c = jax.random.split(k)
            alpha = jnp.full((S,), concentration, dtype=jnp.float64)
            P = jax.random.dirichlet(k_p, alpha, (S, A), dtype=jnp.float64)
            P = P / jnp.sum(P, axis=-1, keepdims=True)
            C = jax.random.uniform(k_c, (S, A), dtype=jnp.float64)
            return FiniteMDP(P, C, _f64(gamma), jnp.full((S,), 1.0 / S), _f64(0.0), _f64(1.0))

        f = one
        for _ in range(key.ndim):
            f = jax.vmap(f)
        return f(key)

    return sample


_MOVES = np.array([(-1, 0), (0, 1), (1, 0), (0, -1)])  # N, E, S, W


def gridworld(
    rows: int = 4,
    cols: int = 4,
    *,
    slip: float = 0.2,
    gamma: float = 0.95,
    goal: tuple[int, int] | None = None,
    holes: tuple[tuple[int, int], ...] = (),
    start: tuple[int, int] = (0, 0),
    step_cost: float = 0.1,
    hole_cost: float = 1.0,
) -> FiniteMDP:
    """A slippery gridworld. State ``r·cols + c``; actions N, E, S, W (0..3).

    The intended move happens with probability ``1 − slip``; otherwise the agent slides to one
    of the two perpendicular directions (``slip/2`` each); moves into the border stay put. The
    goal (default: the far corner) is absorbing with cost 0, holes are absorbing with cost
    ``hole_cost``, every other cell costs ``step_cost`` per step. Cost range
    ``[0, max(step_cost, hole_cost)]``; μ is the start cell.
    """
    if rows < 1 or cols < 1 or rows * cols < 2:
        raise ValueError(f"the grid needs at least 2 cells, got rows={rows}, cols={cols}")
    if not 0.0 <= slip <= 1.0:
        raise ValueError(f"slip must lie in [0, 1], got {slip!r}")
    goal = (rows - 1, cols - 1) if goal is None else tuple(goal)
    cells = [goal, tuple(start), *map(tuple, holes)]
    for cell in cells:
        if not (0 <= cell[0] < rows and 0 <= cell[1] < cols):
            raise ValueError(f"cell {cell} is outside the {rows}x{cols} grid")
    S = rows * cols
    P = np.zeros((S, 4, S))
    C = np.full((S, 4), float(step_cost))

    def index(r, c):
        return r * cols + c

    def moved(r, c, d):
        r2, c2 = r + _MOVES[d][0], c + _MOVES[d][1]
        return index(r2, c2) if (0 <= r2 < rows and 0 <= c2 < cols) else index(r, c)

    hole_ids = {index(*h) for h in holes}
    for r in range(rows):
        for c in range(cols):
            s = index(r, c)
            if (r, c) == goal or s in hole_ids:
                P[s, :, s] = 1.0
                C[s] = 0.0 if (r, c) == goal else float(hole_cost)
                continue
            for a in range(4):
                P[s, a, moved(r, c, a)] += 1.0 - slip
                for side in ((a + 1) % 4, (a + 3) % 4):
                    P[s, a, moved(r, c, side)] += slip / 2
    mu = np.zeros(S)
    mu[index(*start)] = 1.0
    return make_mdp(P, C, gamma, mu, 0.0, max(step_cost, hole_cost, 0.0))


TRAP_WALK, TRAP_JUMP = 0, 1


def trap_mdp(
    length: int = 6, *, slip: float = 0.2, gamma: float = 0.9, walk_cost: float = 0.5
) -> FiniteMDP:
    r"""The trap: where a rarely-explored region looks free to a learnt model.

    States: a corridor ``0 … length−1`` (start 0), the goal ``G = length`` (absorbing, cost 0),
    the lure ``ℓ = length + 1`` and the pit ``p = length + 2`` (absorbing, cost ``c_max = 1``).
    Actions: ``TRAP_WALK = 0`` moves one cell right with probability ``1 − slip`` and stays
    otherwise (cost ``walk_cost`` in the corridor); ``TRAP_JUMP = 1`` jumps from any corridor
    cell to the lure (cost 0). Every action at the lure costs 0 and falls into the pit.

    Truth: jumping from cell k costs ``γ²/(1−γ)`` (from then on), far more than walking, so the
    optimal policy π* walks (J* ≈ walk_cost × discounted steps to G).

    Why Batch falls in and DAgger does not, with ν = D_{μ,π_ε} of the base policy "walk, but
    take a uniformly random action with probability ε" (the paper's "base policy with random
    exploration in the actions") and learnt models whose prior for an unseen pair (s, a) is
    "stay in s" (the count estimator's and the classifier's default in
    :mod:`loopid.experiments.families.mdp.agent`):

    - ν reaches the lure only after one of its rare random jumps (ν(ℓ) ≈ γ(1−γ)ε/2 per unit
      of corridor occupancy), and then mostly takes the walk action there, so the lure's jump
      pair has mass ≈ ν(ℓ)·ε/2 (1.2·10⁻⁷ with the defaults). Until every (ℓ, a) has been
      sampled, the model believes some lure action keeps the agent at ℓ at cost 0 forever, so
      value iteration on it jumps. After M ν-draws that happens with probability ≥
      1 − Π_a (1 − (1 − ν(ℓ, a))^M) (exact; > 0.9999 for ε = 10⁻³, γ = 0.9, M = 1450, the
      ``mdp-trap`` budget). The learnt policy then sends all its future mass where ν has almost
      none: ``c_ν^π̂ ≥ D_{μ,π̂}(p, ·)/ν(p, ·)`` is in the thousands, Theorem 3.1's bound is vacuous
      and the policy's J is ``γ²/(1−γ)`` (8.1 at γ = 0.9) instead of J* (≈ 2.7).
    - DAgger's policy half is drawn from ``D_{μ,π_n}``: a policy that walks k cells and jumps
      puts mass ≈ (1−γ)γ^k on the unseen pair it relies on (a jump, then a lure action), so
      that pair's true outcome is seen within an iteration or two and the model stops
      believing in it. Each of the ≤ length + 2 such pairs is corrected at most once, after
      which walking is optimal on the model too (about 10 iterations of 50 samples with the
      defaults). ``c_ν^{π*}`` stays small (ν follows π* but for ε), so Lemma 4.1's bound only needs
      the model to be right where ν and the policies go.

    The walk's slip makes the system stochastic, so a deterministic model class (the classifier)
    is misspecified there: the agnostic case, with non-zero modelling error on walking pairs.
    """
    if isinstance(length, bool) or not isinstance(length, int) or length < 1:
        raise ValueError(f"length must be a positive integer, got {length!r}")
    if not 0.0 <= slip < 1.0:
        raise ValueError(f"slip must lie in [0, 1), got {slip!r}")
    if not 0.0 <= walk_cost <= 1.0:
        raise ValueError(f"walk_cost must lie in [0, 1], got {walk_cost!r}")
    goal, lure, pit = length, length + 1, length + 2
    S = length + 3
    P = np.zeros((S, 2, S))
    C = np.zeros((S, 2))
    for k in range(length):
        P[k, TRAP_WALK, k + 1] += 1.0 - slip
        P[k, TRAP_WALK, k] += slip
        P[k, TRAP_JUMP, lure] = 1.0
        C[k, TRAP_WALK] = walk_cost
    P[goal, :, goal] = 1.0
    P[lure, :, pit] = 1.0
    P[pit, :, pit] = 1.0
    C[pit] = 1.0
    mu = np.zeros(S)
    mu[0] = 1.0
    return make_mdp(P, C, gamma, mu, 0.0, 1.0)
