"""The spectral radius ρ(M) = max |λᵢ(M)| of square matrices, batched, on any backend.

The LQR's stability test (:mod:`loopid.control.lqr`: a gain is accepted only where the closed
loop ``A - BK`` has ρ < 1) needs the eigenvalues of a general (nonsymmetric) matrix, for every
lane of a batch at once. Where the eigenvalues are computed depends on the backend:

- **CPU**: ``jnp.linalg.eigvals``, LAPACK's ``geev`` inside the compiled program.
- **Accelerator**: one host callback (:func:`jax.pure_callback`) that hands the whole batch to
  NumPy's ``eigvals`` (LAPACK ``geev`` on the host) and returns ρ per matrix. JAX's own GPU
  ``eig`` calls cuSOLVER's ``geev`` once per matrix of the batch; measured on one H200
  (``benchmarks/spectral_radius.py``), the hover's batched LQR solve took 1.4x as long with it
  at 140 and 1,000 lanes (21 and 106 ms against 15 and 76 ms), and the same at 20 lanes.

Both are LAPACK's ``geev`` on the same matrices; the two backends' tables differ in their last
bits anyway (another compiler, other math libraries). A matrix with a non-finite entry, or whose
eigenvalues LAPACK cannot converge, has ρ = ∞ on either path (never a NaN that travels on).
"""

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = ["spectral_radius"]


def _on_device(M: Array) -> Array:
    """ρ of ``M [..., n, n]`` from the eigenvalues computed inside the program."""
    rho = jnp.max(jnp.abs(jnp.linalg.eigvals(M)), axis=-1)
    return jnp.where(jnp.isfinite(rho), rho, jnp.inf)


def _host_rho(M: np.ndarray) -> np.ndarray:
    """ρ of ``M [..., n, n]`` with NumPy (runs on the host, the whole batch in one call)."""
    M = np.asarray(M)
    batch = M.reshape(-1, *M.shape[-2:])
    rho = np.full(batch.shape[0], np.inf)
    finite = np.isfinite(batch).all(axis=(1, 2))
    try:
        rho[finite] = np.abs(np.linalg.eigvals(batch[finite])).max(axis=-1, initial=0.0)
    except np.linalg.LinAlgError:  # one matrix did not converge: the rest one by one
        for i in np.flatnonzero(finite):
            try:
                rho[i] = np.abs(np.linalg.eigvals(batch[i])).max(initial=0.0)
            except np.linalg.LinAlgError:
                pass
    return rho.reshape(M.shape[:-2]).astype(M.dtype)


def _on_host(M: Array) -> Array:
    """ρ of ``M [..., n, n]`` from one host callback for the whole batch (under ``vmap`` too)."""
    out = jax.ShapeDtypeStruct(M.shape[:-2], M.dtype)
    return jax.pure_callback(_host_rho, out, M, vmap_method="broadcast_all")


def spectral_radius(M: Array) -> Array:
    """ρ(M) = max |λᵢ(M)| of ``M [..., n, n]``: ``[...]``, ∞ where it cannot be computed.

    Inside the compiled program on a CPU, from one host callback for the whole batch on an
    accelerator (the module docstring says why); chosen when the program is lowered
    (:func:`jax.lax.platform_dependent`), so one traced function serves both."""
    return jax.lax.platform_dependent(M, cpu=_on_device, default=_on_host)
