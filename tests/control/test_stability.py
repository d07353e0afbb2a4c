"""The spectral radius (loopid.control.stability) against NumPy's eigenvalues: both paths
(inside the program, and the host callback an accelerator takes) on a batch with stable,
unstable, complex-pair, defective and non-finite matrices, under jit and vmap; on this machine's
backend the path it picks. On a GPU the same file checks the callback where it runs."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.control.stability import _on_device, _on_host, spectral_radius


def _batch() -> np.ndarray:
    rng = np.random.default_rng(7)
    M = rng.normal(size=(7, 5, 5)) / 3.0
    M[1] = np.diag([0.5, -0.9, 0.1, 0.0, 0.2])  # stable, a real eigenvalue sets ρ
    M[2] = 0.0
    M[2][0, 1], M[2][1, 0] = 1.2, -1.2  # a complex pair ±1.2i
    M[3] = np.eye(5) + np.diag(np.ones(4), 1)  # one Jordan block of eigenvalue 1
    M[4, 2, 3] = np.nan
    M[5, 0, 0] = np.inf
    return M


def _expected(M: np.ndarray) -> np.ndarray:
    out = np.full(M.shape[0], np.inf)
    for i, m in enumerate(M):
        if np.isfinite(m).all():
            out[i] = np.abs(np.linalg.eigvals(m)).max()
    return out


#: inside the program is what a CPU runs; an accelerator runs the callback (cuSOLVER's geev,
#: which ``_on_device`` would call there, is not what loopid uses, and is not checked)
IN_PROGRAM = pytest.param(
    _on_device,
    marks=pytest.mark.skipif(jax.default_backend() != "cpu", reason="a CPU's path"),
)


@pytest.mark.parametrize("path", [IN_PROGRAM, _on_host, spectral_radius], ids=lambda f: f.__name__)
def test_the_spectral_radius_is_numpys_on_every_matrix_and_infinite_where_not_finite(path):
    M = _batch()
    expected = _expected(M)
    assert expected[1] == 0.9 and expected[2] == pytest.approx(1.2) and expected[3] == 1.0
    batched = np.asarray(jax.jit(path)(jnp.asarray(M)))
    mapped = np.asarray(jax.jit(jax.vmap(path))(jnp.asarray(M)))  # one callback for the batch
    for got in (batched, mapped):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)
        assert np.isinf(got[4]) and np.isinf(got[5])
    one = np.asarray(jax.jit(path)(jnp.asarray(M[2])))
    assert one.shape == () and one == pytest.approx(1.2, rel=1e-12)


def test_the_host_callback_runs_once_for_a_whole_vmapped_batch(monkeypatch):
    import loopid.control.stability as sr

    calls = []
    original = sr._host_rho

    def counted(M):
        calls.append(np.shape(M))
        return original(M)

    monkeypatch.setattr(sr, "_host_rho", counted)
    M = jnp.asarray(_batch()[:3])
    jax.block_until_ready(jax.jit(jax.vmap(jax.vmap(sr._on_host)))(jnp.stack([M, M])))
    assert calls == [(2, 3, 5, 5)]
