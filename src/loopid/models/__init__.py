"""Model classes fitted by the online learners.

- :mod:`loopid.models.linear_offset`: Δx' ≈ (A + A')Δx + (B + B')Δu around a nominal (A, B)
  (hover), and its time-varying form with one offset pair per step (funnel).
- :mod:`loopid.models.feature_model`: Δx' ≈ AΔx + BΔu + Wᵀφ(Δx, Δu) with a fixed feature map
  (:mod:`loopid.models.feature_maps`: :func:`polynomial`, :func:`random_fourier`), still linear
  in W, so FTRL/OGD fit it.
- :mod:`loopid.models.mlp`: Δx' ≈ AΔx + BΔu + MLP_θ(Δx, Δu), trained online with optax (Adam);
  non-convex, no regret claim.
"""

from loopid.models.feature_maps import FeatureMap, polynomial, random_fourier
from loopid.models.linear_offset import (
    LinearOffsetModel,
    features,
    hover_nominal,
    per_sample_loss,
    predict,
    residual_targets,
    time_varying_nominal,
    to_matrices,
)
from loopid.models.mlp import MLPLearner, MLPState, mlp_learner

__all__ = [
    "FeatureMap",
    "LinearOffsetModel",
    "MLPLearner",
    "MLPState",
    "features",
    "hover_nominal",
    "mlp_learner",
    "per_sample_loss",
    "polynomial",
    "predict",
    "random_fourier",
    "residual_targets",
    "time_varying_nominal",
    "to_matrices",
]
