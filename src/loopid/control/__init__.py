"""Optimal-control solvers: infinite-horizon LQR, time-varying LQR, iLQR, rollouts.

Problem convention shared by every solver (trajax style): ``dynamics(x, u, t) -> x_next``,
``cost(x, u, t) -> scalar``; shapes ``x [n]``, ``u [m]``, ``X [T+1, n]``, ``U [T, m]``, batch
axes first. Gains follow python-control and SciPy: u = -K x (time-varying: u_t = -K_t x_t - k_t).

Every public function checks shapes before tracing (also on tracers) and values (symmetry, PSD,
finiteness) on concrete inputs only, so the same function is called from plain Python and from
inside ``jit``/``vmap``/``lax.scan``. Numerical failure is a status field (``converged``),
never NaN.

- :func:`dlqr` / :func:`dlqr_affine` -> :class:`LQRSolution` (hover; the affine variant for
  error coordinates with a constant last entry)
- :func:`tvlqr` -> :class:`TVLQRSolution` (funnel on a learned time-varying model; also the
  fallback when ``dlqr`` does not converge, SPEC §4.4)
- :func:`ilqr` -> :class:`ILQRSolution` (the funnel expert on the true simulator)
- :func:`rollout`, :func:`linear_rollout`, :func:`tracking_rollout` -> trajectories
"""

from loopid.control.ilqr import ILQRSolution, Quadratization, ilqr, quadratize, trajectory_cost
from loopid.control.lqr import LQRSolution, dlqr, dlqr_affine
from loopid.control.rollout import Rollout, linear_rollout, rollout, tracking_rollout
from loopid.control.tvlqr import TVLQRSolution, tvlqr

__all__ = [
    "ILQRSolution",
    "LQRSolution",
    "Quadratization",
    "Rollout",
    "TVLQRSolution",
    "dlqr",
    "dlqr_affine",
    "ilqr",
    "linear_rollout",
    "quadratize",
    "rollout",
    "tracking_rollout",
    "trajectory_cost",
    "tvlqr",
]
