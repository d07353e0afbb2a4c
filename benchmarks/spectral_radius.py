"""The batched LQR solve of hover-sized models with the closed loop's spectral radius computed
inside the program (``jnp.linalg.eigvals``: the reference, what a CPU runs) against one host
callback for the whole batch (what an accelerator runs), at several batch widths, in one run.

Each side is the whole time-invariant solve of :func:`loopid.control.lqr.dlqr_affine` for ``S``
lanes (the hover's 21 x 21 affine error model, perturbed per lane; its Q and R), as the engine's
batched solve calls it, jitted and compiled before timing. Printed per width: each side's
milliseconds per solve (min / median / max of ``--runs``), the ratio of the medians (reference /
callback: above 1, the callback is faster), whether the two give the same gains and flags, and
how far apart their spectral radii are. On a GPU the reference is cuSOLVER's ``geev``, called
once per matrix of the batch.

    .venv/bin/python benchmarks/spectral_radius.py [--widths 20,140,1000] [--runs 7]
"""

import argparse
import statistics
import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

import loopid
from loopid.control import lqr
from loopid.control.stability import _on_device, _on_host
from loopid.systems import helicopter, tasks


def models(S: int):
    """``S`` perturbed copies of the hover's linearisation in error coordinates."""
    x = helicopter.hover_target()
    A, B = (np.asarray(a) for a in helicopter.linearize(x, x))
    rng = np.random.default_rng(0)
    dA, dB = 0.01 * rng.normal(size=(S, *A.shape)), 0.01 * rng.normal(size=(S, *B.shape))
    dA[:, -1], dB[:, -1] = 0.0, 0.0  # the constant coordinate stays constant
    return jnp.asarray(A[None] + dA), jnp.asarray(B[None] + dB)


def solver(rho):
    """The batched affine solve with ``rho`` as its spectral radius, traced afresh."""
    lqr.spectral_radius = rho  # read when the solve is traced
    f = partial(lqr._dlqr_affine_single, max_iter=64, tol=1e-13, rtol_residual=1e-8)
    return jax.jit(jax.vmap(f, in_axes=(0, 0, None, None)))


def timed(f, args, runs: int) -> list[float]:
    jax.block_until_ready(f(*args))  # compile
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        out.append(1e3 * (time.perf_counter() - t0))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", default="20,140,1000")
    parser.add_argument("--runs", type=int, default=7)
    opts = parser.parse_args()
    print(f"loopid {loopid.__version__}, JAX {jax.__version__} on {jax.devices()[0].device_kind}")
    Q, R = tasks.cost_matrices(tasks.HOVER_WEIGHTS)
    original = lqr.spectral_radius
    try:
        for S in (int(w) for w in opts.widths.split(",")):
            A, B = models(S)
            inside, callback = solver(_on_device), solver(_on_host)
            a, b = inside(A, B, Q, R), callback(A, B, Q, R)
            same = bool(jnp.array_equal(a.K, b.K) and jnp.array_equal(a.converged, b.converged))
            rho = float(jnp.max(jnp.abs(a.spectral_radius - b.spectral_radius) / a.spectral_radius))
            t_in = timed(inside, (A, B, Q, R), opts.runs)
            t_cb = timed(callback, (A, B, Q, R), opts.runs)
            ratio = statistics.median(t_in) / statistics.median(t_cb)
            print(
                f"S={S:5d}: in program {min(t_in):8.2f} / {statistics.median(t_in):8.2f} / "
                f"{max(t_in):8.2f} ms, callback {min(t_cb):8.2f} / {statistics.median(t_cb):8.2f}"
                f" / {max(t_cb):8.2f} ms, ratio {ratio:6.2f}, same gains and flags: {same}, "
                f"ρ up to {rho:.1e} relative",
                flush=True,
            )
    finally:
        lqr.spectral_radius = original


if __name__ == "__main__":
    main()
