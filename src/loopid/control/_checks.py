"""Input checks shared by the solvers, run in Python before any tracing.

Shape checks read ``.shape`` only, so they also run on JAX tracers (inside ``jit``, ``vmap`` or
``lax.scan`` the shapes are static). Value checks (symmetry, eigenvalues, finiteness) need
numbers; they run on concrete arrays and are skipped for tracers, so every public solver can be
called from inside jitted code without a separate entry point.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

__all__ = [
    "check_batch",
    "check_finite",
    "check_psd",
    "check_shape",
    "check_square",
    "is_concrete",
    "shape_of",
]


def is_concrete(x: Any) -> bool:
    """True when ``x`` holds numbers (not a JAX tracer), so its values can be checked."""
    return not isinstance(x, jax.core.Tracer)


def shape_of(name: str, x: Any) -> tuple[int, ...]:
    """The shape of an array-like argument; TypeError naming ``name`` when it has none."""
    if x is None:
        raise TypeError(f"{name} is required, got None")
    shape = getattr(x, "shape", None)
    if shape is None:
        try:
            shape = np.shape(x)
        except Exception as exc:  # ragged lists and the like
            raise TypeError(f"{name} must be an array, got {type(x).__name__}") from exc
    return tuple(int(s) for s in shape)


def check_square(name: str, x: Any, *, min_ndim: int = 2) -> tuple[int, ...]:
    """Check the last two axes are equal; returns the shape."""
    shape = shape_of(name, x)
    if len(shape) < min_ndim or shape[-1] != shape[-2]:
        raise ValueError(f"{name} must be square in its last two axes, got shape {shape}")
    return shape


def check_shape(name: str, x: Any, core: tuple[int | None, ...]) -> tuple[int, ...]:
    """Check the trailing axes of ``x`` match ``core`` (None: any size); returns the shape."""
    shape = shape_of(name, x)
    k = len(core)
    tail = shape[len(shape) - k :]
    ok = len(shape) >= k and all(c is None or s == c for s, c in zip(tail, core, strict=True))
    if not ok:
        want = "[..., " + ", ".join("*" if c is None else str(c) for c in core) + "]"
        raise ValueError(f"{name} must have shape {want}, got shape {shape}")
    return shape


def check_batch(shapes: dict[str, tuple[int, ...]], core_ndim: dict[str, int]) -> tuple[int, ...]:
    """Broadcast the leading (batch) axes of several arguments; ValueError naming them if not."""
    batch = {name: shape[: len(shape) - core_ndim[name]] for name, shape in shapes.items()}
    try:
        return tuple(np.broadcast_shapes(*batch.values()))
    except ValueError:
        desc = ", ".join(f"{n} {s}" for n, s in batch.items())
        raise ValueError(f"batch axes do not broadcast: {desc}") from None


def check_finite(name: str, x: Any) -> None:
    """ValueError when a concrete array holds NaN or inf."""
    if x is None or not is_concrete(x):
        return
    a = np.asarray(x)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got non-finite entries (shape {a.shape})")


def check_psd(
    name: str, x: Any, *, definite: bool = False, rtol: float = 1e-9, atol: float = 1e-12
) -> None:
    """ValueError when a concrete symmetric matrix (or batch) is not symmetric or not PSD / PD.

    Symmetry is checked to ``rtol`` relative to the largest entry; the smallest eigenvalue must be
    at least ``-rtol * max|eig| - atol`` (PSD) or strictly positive (``definite=True``).
    """
    if x is None or not is_concrete(x):
        return
    check_finite(name, x)
    a = np.asarray(x, dtype=np.float64)
    scale = max(float(np.max(np.abs(a), initial=0.0)), 1e-300)
    asym = float(np.max(np.abs(a - np.swapaxes(a, -1, -2)), initial=0.0))
    if asym > rtol * scale + atol:
        raise ValueError(
            f"{name} must be symmetric, got max |{name} - {name}^T| = {asym:.3g} (shape {a.shape})"
        )
    eig = np.linalg.eigvalsh(0.5 * (a + np.swapaxes(a, -1, -2)))
    lo = float(np.min(eig))
    hi = float(np.max(np.abs(eig)))
    if definite and lo <= 0.0:
        raise ValueError(f"{name} must be positive definite, got smallest eigenvalue {lo:.3g}")
    if lo < -rtol * hi - atol:
        raise ValueError(f"{name} must be positive semidefinite, got smallest eigenvalue {lo:.3g}")
