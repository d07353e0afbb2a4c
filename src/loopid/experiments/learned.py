"""What a run learned, rebuilt in the coordinates of its system: models and controllers.

- :class:`GainController`: the time-varying affine policy of the loop,
  ``action_t = a_op − K_t Δx_t`` with ``Δx_t`` the system's error coordinates of the observation
  at step t (the helicopter: ``to_error(x_t, x*_t)``, action = the control change Δu; a Gymnasium
  env: ``[o_t[observe] − o*; 1]``). Under the helicopter's ``latency`` reading of the delay
  (``delay_mode``) it acts on the error observed ``delay`` steps earlier, as the loop's
  controller did, and so keeps those steps in memory (:meth:`GainController.reset` at an
  episode's start; step 0 resets it).
- :class:`ReplanningController`: model-predictive control on a saved model, one step at a time:
  what a helicopter cell that flew MPC flew (:mod:`loopid.algorithms.mpc_plant`).
- :class:`TableController`: a finite MDP's policy, the action of highest probability in a state.
- :class:`LinearModel`: the linear offset model, nominal plus learned offsets ``W``; its
  :meth:`LinearModel.predict` is the learner's own prediction
  (:func:`loopid.models.linear_offset.predict`), bit for bit.
- :class:`FeatureModel`: a feature model (:mod:`loopid.models.feature_model`), nominal plus
  ``W_featuresᵀ φ(Δx, Δu)``; its :meth:`FeatureModel.predict` is the learner's prediction.
- :class:`TableModel`: a finite MDP's learned transition probabilities ``T̂ [S, A, S]``.

Each family's ``load`` builds them from a cell's saved arrays; :func:`loopid.load` finds those.
"""

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from loopid.models import feature_model
from loopid.models.linear_offset import LinearOffsetModel, predict, to_matrices


class LinearModel(NamedTuple):
    """``Δx' = (A + A')Δx + (B + B')Δu``: the nominal ``(A, B)`` ([n, n], [n, m], or with a
    leading time axis [T, ...]) and the learned ``W = [A' B']ᵀ`` ([(T,) n+m, n])."""

    nominal: LinearOffsetModel
    W: np.ndarray

    def predict(self, dx, du, t=None) -> np.ndarray:
        """The predicted next error state ``[b, n]`` of rows ``dx [b, n]``, ``du [b, m]`` (and
        each row's step ``t [b]`` for a time-varying model)."""
        return np.asarray(predict(self.nominal, self.W, dx, du, t))

    def as_nominal(self) -> LinearOffsetModel:
        """The learned model ``(Â, B̂) = (A + A', B + B')`` as a nominal to start another run's
        learner from (:func:`loopid.algorithms.model_based.linear_agent`)."""
        A, B = to_matrices(self.nominal, self.W)
        return LinearOffsetModel(A, B)


class FeatureModel(NamedTuple):
    """``Δx' = AΔx + BΔu + Wᵀφ(Δx, Δu)``: the nominal ``(A, B)``, the feature map ``fmap`` and
    the learned ``W [F, n]`` (one for every step)."""

    nominal: LinearOffsetModel
    fmap: Any
    W: np.ndarray

    def predict(self, dx, du, t=None) -> np.ndarray:
        """The predicted next error state ``[b, n]`` of rows ``dx [b, n]``, ``du [b, m]``."""
        return np.asarray(feature_model.predict(self.nominal, self.fmap, self.W, dx, du, t))


class TableModel(NamedTuple):
    """A finite MDP's learned transition probabilities ``T_hat [S, A, S]``."""

    T_hat: np.ndarray

    def predict(self, s: int, a: int) -> np.ndarray:
        """The predicted distribution of the next state ``[S]``."""
        return self.T_hat[s, a]


class GainController:
    """``action = a_op − K_t Δx_t`` (module docstring). ``K [T, m, n]``; ``error(obs, t) ->
    Δx [n]``; ``a_op [m]``; ``delay``: act on the error of ``delay`` steps earlier (zeros before
    the first one), with ``K`` of that step."""

    def __init__(self, K, error: Callable[[Any, int], np.ndarray], a_op, delay: int = 0):
        self.K = np.asarray(K, np.float64)
        self.error = error
        self.a_op = np.asarray(a_op, np.float64)
        self.delay = int(delay)
        self.reset()

    @property
    def horizon(self) -> int:
        return self.K.shape[0]

    def reset(self) -> None:
        """Forget the remembered errors (an episode starts)."""
        self._seen: list[np.ndarray] = []

    def __call__(self, obs, t: int) -> np.ndarray:
        """The action at step ``t`` (0-based) for observation ``obs``."""
        t = int(t)
        if t < 0:
            raise ValueError(f"the step index t must be >= 0, got {t}")
        dx = np.asarray(self.error(np.asarray(obs, np.float64), t), np.float64)
        if self.delay == 0:
            return self.a_op - self.K[min(t, self.horizon - 1)] @ dx
        if t == 0:
            self.reset()
        self._seen.append(dx)
        s = t - self.delay
        if s < 0:
            return self.a_op.copy()
        return self.a_op - self.K[min(s, self.horizon - 1)] @ self._seen[s]

    def as_gymnasium_policy(self, action_space=None) -> "GymnasiumPolicy":
        """A policy for a Gymnasium env: ``policy(obs) -> action``, counting steps itself
        (:meth:`GymnasiumPolicy.reset` after ``env.reset``); actions clipped to
        ``action_space`` when given."""
        return GymnasiumPolicy(self, action_space)


class ReplanningController:
    """``action_t = a_op + Δu_t`` by MPC on a learned model: at t = 0 and every ``every`` steps
    after it plans ``H`` steps ahead from ``Δx_t = error(obs, t)`` (iLQR, warm-started from the
    previous plan; :func:`loopid.control.mpc.replan`), and in between applies the plan's
    feedback ``Δu = U_j − K_j(Δx − X_j)``: the controller a cell's MPC plant flew
    (:mod:`loopid.algorithms.mpc_plant`), one call a step. ``replanner``:
    :func:`loopid.control.replanner`; ``params``: the model's parameters; ``n``: the size of
    ``Δx``. Step 0 starts an episode (:meth:`reset`)."""

    def __init__(self, replanner, params, error: Callable[[Any, int], np.ndarray], a_op, n: int):
        import jax

        from loopid.control.mpc import empty_plan, local_action, replan

        self.replanner, self.params, self.error = replanner, params, error
        self.a_op = np.asarray(a_op, np.float64)
        r = replanner
        self._replan = jax.jit(lambda p, x, t, prev, fresh, shift: replan(r, p, x, t, prev, fresh,
                                                                          shift))  # fmt: skip
        self._act = jax.jit(lambda plan, x, j: local_action(r, plan, x, j))
        self._empty = empty_plan(r, int(n))
        self.reset()

    def reset(self) -> None:
        """Forget the plan (an episode starts)."""
        self._plan, self._t_plan = None, 0

    def __call__(self, obs, t: int) -> np.ndarray:
        """The action at step ``t`` (0-based) for observation ``obs``."""
        t = int(t)
        if t < 0:
            raise ValueError(f"the step index t must be >= 0, got {t}")
        dx = np.asarray(self.error(np.asarray(obs, np.float64), t), np.float64)
        if t == 0 or self._plan is None:
            self._plan = self._replan(self.params, dx, t, self._empty, True, 0)
            self._t_plan = t
        elif t - self._t_plan >= self.replanner.every:
            self._plan = self._replan(self.params, dx, t, self._plan, False, t - self._t_plan)
            self._t_plan = t
        return self.a_op + np.asarray(self._act(self._plan, dx, t - self._t_plan))


class TableController:
    """A finite MDP's policy ``K [S, A]``: the most probable action in state ``s``."""

    def __init__(self, K):
        self.K = np.asarray(K, np.float64)

    def __call__(self, s, t: int = 0) -> int:
        return int(np.argmax(self.K[int(s)]))

    def as_gymnasium_policy(self, action_space=None) -> "GymnasiumPolicy":
        return GymnasiumPolicy(self, None)


class GymnasiumPolicy:
    """A controller driven by a Gymnasium loop: ``action = policy(obs)``; step count kept."""

    def __init__(self, controller, action_space=None):
        self.controller = controller
        self.action_space = action_space
        self.t = 0

    def reset(self) -> None:
        self.t = 0
        if hasattr(self.controller, "reset"):
            self.controller.reset()

    def __call__(self, obs):
        action = self.controller(obs, self.t)
        self.t += 1
        space = self.action_space
        if space is not None and hasattr(space, "low"):
            action = np.clip(action, space.low, space.high).astype(space.dtype)
        return action
