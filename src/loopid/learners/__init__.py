"""Online learners as pure ``init``/``update``/``weights`` triples (optax style).

The paper's DAgger reduces model-based RL to no-regret online learning (section 4): each
iteration's batch of transitions is one round of an online least-squares problem, and any
no-regret learner may pick the models. Provided:

- :func:`ftrl_least_squares`: Follow-the-Regularised-Leader, the refit on all data so far with
  the paper's (λ/√n)||W||²_F regulariser, kept as sufficient statistics (:class:`FTRLState`).
- :func:`ogd`: online projected gradient descent with step η/√t (:class:`OGDState`).
- :func:`indexed`: any learner stacked over T time steps (time-varying models);
  :func:`touched_weights` re-solves only the steps an update reached.
- :func:`count_estimator`: the empirical transition estimator of a finite MDP (no-regret in L1).
- :func:`online_hinge`: a deterministic next-state classifier (multi-class hinge, AdaGrad).
- :func:`online_loss`, :func:`hindsight_loss`, :func:`regret_curve`: regret bookkeeping.
"""

from loopid.learners.base import Learner
from loopid.learners.counts import CountState, count_estimator
from loopid.learners.ftrl import FTRLState, ftrl_least_squares, ftrl_solve
from loopid.learners.hinge import HingeState, hinge_loss, online_hinge
from loopid.learners.indexed import indexed, touched_weights
from loopid.learners.ogd import OGDState, ogd
from loopid.learners.regret import RegretCurve, hindsight_loss, online_loss, regret_curve

__all__ = [
    "CountState",
    "FTRLState",
    "HingeState",
    "Learner",
    "OGDState",
    "RegretCurve",
    "count_estimator",
    "ftrl_least_squares",
    "ftrl_solve",
    "hindsight_loss",
    "hinge_loss",
    "indexed",
    "ogd",
    "online_hinge",
    "online_loss",
    "regret_curve",
    "touched_weights",
]
