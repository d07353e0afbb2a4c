"""Model classes fitted by the online learners.

- :mod:`loopid.models.linear_offset`: Δx' ≈ (A + A')Δx + (B + B')Δu around a nominal (A, B)
  (hover), and its time-varying form with one offset pair per step (funnel), SPEC §4.2.
"""

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

__all__ = [
    "LinearOffsetModel",
    "features",
    "hover_nominal",
    "per_sample_loss",
    "predict",
    "residual_targets",
    "time_varying_nominal",
    "to_matrices",
]
