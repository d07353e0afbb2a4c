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
  fallback when ``dlqr`` does not converge on a learned model)
- :func:`ilqr` -> :class:`ILQRSolution` (the funnel expert on the true simulator)
- :func:`plan` (iLQR on a learned model whose parameters are traced), :func:`as_gains` (its
  policy as the loop's gains ``K [T, m, n]``), :func:`mpc_rollout` / :class:`MPCController`
  (receding-horizon iLQR in JAX and for Gymnasium envs), :func:`replanner` (its re-planning step
  for controllers inside a compiled loop), :class:`Penalized`,
  :func:`quadratic_cost`, :func:`action_penalty`: the planner of nonlinear models
  (:mod:`loopid.control.plan`, :mod:`loopid.control.mpc`, :mod:`loopid.control.mpc_controller`,
  :mod:`loopid.control.costs`; their parts :mod:`loopid.control.plan_settings` and
  :mod:`loopid.control.receding_horizon`)
- :func:`rollout`, :func:`linear_rollout`, :func:`tracking_rollout` -> trajectories
- :func:`value_iteration`, :func:`policy_iteration`, :func:`evaluate`, :func:`occupancy`: finite
  MDPs (batched), exact policy evaluation and discounted occupancy D_{μ,π}
"""

from loopid.control.costs import Penalized, QuadraticCost, action_penalty, quadratic_cost
from loopid.control.ilqr import ILQRSolution, Quadratization, ilqr, quadratize, trajectory_cost
from loopid.control.lqr import LQRSolution, dlqr
from loopid.control.lqr_affine import dlqr_affine
from loopid.control.mpc import Replanner, mpc_rollout, replanner
from loopid.control.mpc_controller import MPCController
from loopid.control.plan import as_gains, plan
from loopid.control.receding_horizon import MPCRollout
from loopid.control.rollout import Rollout, linear_rollout, rollout, tracking_rollout
from loopid.control.tvlqr import TVLQRSolution, tvlqr
from loopid.control.value_iteration import (
    PIResult,
    VIResult,
    evaluate,
    greedy,
    occupancy,
    policy_iteration,
    q_values,
    value_iteration,
)

__all__ = [
    "ILQRSolution",
    "LQRSolution",
    "MPCController",
    "MPCRollout",
    "PIResult",
    "Penalized",
    "QuadraticCost",
    "Quadratization",
    "Replanner",
    "Rollout",
    "TVLQRSolution",
    "VIResult",
    "action_penalty",
    "as_gains",
    "dlqr",
    "dlqr_affine",
    "evaluate",
    "greedy",
    "ilqr",
    "linear_rollout",
    "mpc_rollout",
    "occupancy",
    "plan",
    "policy_iteration",
    "q_values",
    "quadratic_cost",
    "quadratize",
    "replanner",
    "rollout",
    "tracking_rollout",
    "trajectory_cost",
    "tvlqr",
    "value_iteration",
]
