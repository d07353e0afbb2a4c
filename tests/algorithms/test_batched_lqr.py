"""The time-invariant solve of every lane at once (``model_based.batched_gains``), the path an
accelerator takes: on a batch that mixes models whose steady-state LQR converges with models that
cannot be stabilised, each converging lane's gain is SciPy's DARE gain (with the affine
feedforward in closed form), each failing lane gets the finite-horizon fallback and only those do;
and the agent's ``policies`` on that path equals the seed-by-seed path a CPU takes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from loopid.algorithms import model_based
from loopid.algorithms.model_based import batched_gains, finite_horizon_gains, linear_agent
from loopid.control.lqr_affine import dlqr_affine_unchecked
from loopid.learners import ftrl_least_squares
from loopid.models.linear_offset import LinearOffsetModel

NZ, M, HORIZON = 3, 2, 60
Q = np.diag([1.0, 2.0, 0.5, 0.0])  # no weight on the constant coordinate
R = np.diag([0.1, 0.3])


def _affine(F, G, c):
    """``A = [[F, c], [0, 1]]``, ``B = [[G], [0]]``."""
    A = np.zeros((NZ + 1, NZ + 1))
    A[:NZ, :NZ], A[:NZ, NZ], A[NZ, NZ] = F, c, 1.0
    B = np.zeros((NZ + 1, M))
    B[:NZ] = G
    return A, B


def _mixed_batch():
    """Six lanes: four controllable (two of them open-loop unstable) and two that cannot be
    stabilised (an unstable mode that B does not reach)."""
    rng = np.random.default_rng(7)
    lanes, stabilisable = [], []
    for i in range(6):
        F = np.eye(NZ) + 0.1 * rng.normal(size=(NZ, NZ))
        G = rng.normal(size=(NZ, M))
        c = 0.1 * rng.normal(size=NZ)
        ok = i not in (1, 4)
        if not ok:
            F = np.diag([1.3, 0.5, 0.4])
            G = np.zeros((NZ, M))
            G[1:, :] = rng.normal(size=(NZ - 1, M))  # the 1.3 mode gets no input
        lanes.append(_affine(F, G, c))
        stabilisable.append(ok)
    A = np.stack([a for a, _ in lanes])
    B = np.stack([b for _, b in lanes])
    return A, B, np.array(stabilisable)


def _scipy_gain(A, B):
    """The steady-state gain of the affine model from SciPy's DARE on the z block, and the
    feedforward of the value's linear term: ``(I − A_clᵀ) p = q + A_clᵀ P c``,
    ``k = (R + GᵀPG)⁻¹ Gᵀ(P c + p)``."""
    F, c, G = A[:NZ, :NZ], A[:NZ, NZ], B[:NZ]
    P = scipy.linalg.solve_discrete_are(F, G, Q[:NZ, :NZ], R)
    S = R + G.T @ P @ G
    Kz = np.linalg.solve(S, G.T @ P @ F)
    Acl = F - G @ Kz
    p = np.linalg.solve(np.eye(NZ) - Acl.T, Q[:NZ, NZ] + Acl.T @ P @ c)
    k = np.linalg.solve(S, G.T @ (P @ c + p))
    return np.concatenate([Kz, k[:, None]], axis=1)


def test_batched_solve_is_scipys_dare_where_it_converges_and_the_fallback_only_elsewhere():
    A, B, stabilisable = _mixed_batch()
    K, info = jax.jit(batched_gains, static_argnums=4)(A, B, Q, R, HORIZON)
    K = np.asarray(K)
    assert np.asarray(info.converged).tolist() == stabilisable.tolist()
    dare = np.asarray(dlqr_affine_unchecked(A, B, Q, R).K)
    for lane in np.flatnonzero(stabilisable):
        np.testing.assert_allclose(K[lane], _scipy_gain(A[lane], B[lane]), rtol=1e-8, atol=1e-10)
        assert np.array_equal(K[lane], dare[lane])  # untouched by the fallback's selection
        assert float(info.spectral_radius[lane]) < 1.0
    for lane in np.flatnonzero(~stabilisable):
        fallback = finite_horizon_gains(jnp.asarray(A[lane]), jnp.asarray(B[lane]), Q, R, HORIZON)
        np.testing.assert_allclose(K[lane], np.asarray(fallback[0]), rtol=1e-12, atol=1e-14)
        # the fallback is not the DARE gain (which does not exist here): it was applied
        assert np.all(np.isfinite(K[lane])) and np.abs(K[lane]).max() > 0


@pytest.mark.parametrize("lanes", [6])
def test_agent_policies_on_the_batched_path_equal_the_seed_by_seed_path(monkeypatch, lanes):
    """``linear_agent``'s ``policies`` with the accelerator's batched solve equals the CPU's
    seed-by-seed ``lax.map`` lane by lane (gains and solver info)."""
    A, B, _ = _mixed_batch()
    nominal = LinearOffsetModel(jnp.asarray(A[0]), jnp.asarray(B[0]))
    agent = linear_agent(nominal, ftrl_least_squares(1e-3), Q, R, HORIZON)
    state = agent.init()
    # each lane's learned offset moves the nominal to that lane's model: W = [A − A₀, B − B₀]ᵀ
    W = np.concatenate([A - A[0], B - B[0]], axis=2).swapaxes(1, 2)
    states = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (lanes, *a.shape)), state)
    states = states._replace(W=jnp.asarray(W))
    monkeypatch.setattr(model_based, "solve_in_batch", lambda: False)
    K_map, info_map = jax.jit(agent.policies)(states)
    monkeypatch.setattr(model_based, "solve_in_batch", lambda: True)
    K_batch, info_batch = jax.jit(agent.policies)(states)
    assert K_batch.shape == K_map.shape == (lanes, HORIZON, M, NZ + 1)
    np.testing.assert_allclose(np.asarray(K_batch), np.asarray(K_map), rtol=1e-9, atol=1e-12)
    assert np.array_equal(np.asarray(info_batch.converged), np.asarray(info_map.converged))
    np.testing.assert_allclose(
        np.asarray(info_batch.spectral_radius), np.asarray(info_map.spectral_radius), rtol=1e-9
    )
