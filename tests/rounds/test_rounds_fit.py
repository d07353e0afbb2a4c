"""After k rounds the model is FTRL's closed form on all the data (ridge with λ√n on the sums), in
the columns scaled by the first round's standard deviations (or in the log's units under
``scale = "none"``), and the controller is the steady-state LQR of that model in the log's units
(SciPy's Riccati solution as oracle); the C header computes the Python controller's actions."""

import json
import shutil
import subprocess

import numpy as np
import pytest
import scipy.linalg
from rounds_helpers import transitions as random_rows
from rounds_helpers import write_config, write_round

from loopid import rounds
from loopid.control import dlqr_affine
from loopid.rounds.api import controller_arrays

TARGET, A_OP, LAM = np.array([0.5, 0.0]), np.array([0.1]), 0.01
Qa, R = np.diag([1.0, 0.1, 0.0]), np.diag([0.01])


def ridge(all_rows: list[dict], scaled: bool) -> tuple:
    """W [n + m, n] of (ZᵀZ + λ√N I) W = ZᵀY on every row, in Δx = D_x⁻¹[o − o*; 1],
    Δu = D_u⁻¹(a − a_op), y = Δx' − Δx (nominal A = I, B = 0), D the first round's standard
    deviations (and 1 on the constant), or I when not ``scaled``; and (A, B) in the log's units."""
    first = all_rows[0]
    d = np.array([np.std(first["p"]), np.std(first["v"]), 1.0]) if scaled else np.ones(3)
    su = np.std(first["f"]) if scaled else 1.0
    c = {k: np.concatenate([r[k] for r in all_rows]) for k in ("p", "v", "f", "next_p", "next_v")}
    one = np.ones_like(c["p"])
    dx = np.stack([c["p"] - TARGET[0], c["v"] - TARGET[1], one], 1) / d
    dxn = np.stack([c["next_p"] - TARGET[0], c["next_v"] - TARGET[1], one], 1) / d
    Z = np.concatenate([dx, (c["f"] - A_OP[0])[:, None] / su], 1)
    Y = dxn - dx
    W = np.linalg.solve(Z.T @ Z + LAM * np.sqrt(len(Z)) * np.eye(4), Z.T @ Y)
    A_s, B_s = np.eye(3) + W[:3].T, W[3:].T
    return W, A_s * d[:, None] / d[None, :], B_s * d[:, None] / su


def lqr_oracle(A, B) -> np.ndarray:
    """[K_z, k] by SciPy's DARE on the state block and the affine feedforward's linear solve."""
    Fz, c, Gz = A[:2, :2], A[:2, 2], B[:2]
    P = scipy.linalg.solve_discrete_are(Fz, Gz, Qa[:2, :2], R)
    S = R + Gz.T @ P @ Gz
    Kz = np.linalg.solve(S, Gz.T @ P @ Fz)
    Acl = Fz - Gz @ Kz
    p = np.linalg.solve(np.eye(2) - Acl.T, Acl.T @ P @ c)
    k = np.linalg.solve(S, Gz.T @ (P @ c + p))
    return np.concatenate([Kz, k[:, None]], 1)


@pytest.mark.parametrize("scale", ["std", "none"])
def test_model_is_ridge_on_all_data_and_controller_is_dlqr(tmp_path, scale):
    rng = np.random.default_rng(0)
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml", rounds=f'scale = "{scale}"'))
    given = []
    for k in range(1, 4):
        given.append(random_rows(rng, 40))
        done = rounds.update(root, write_round(tmp_path / f"r{k}.parquet", given[-1]))
        assert done.round == k + 1
        arrays = controller_arrays(root)
        W, A, B = ridge(given, scale == "std")
        np.testing.assert_allclose(arrays["model_W"], W, rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(arrays["A"], A, rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(arrays["B"], B, rtol=1e-11, atol=1e-13)
        K = arrays["K"]
        assert K.shape == (30, 1, 3) and np.all(K == K[0])
        np.testing.assert_allclose(K[0], lqr_oracle(A, B), rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(K[0], np.asarray(dlqr_affine(A, B, Qa, R).K), atol=1e-12)
    assert (root / "data" / "round-003.parquet").is_file()
    assert "| 3 | 20 | 20 |" in (root / "round.md").read_text()


@pytest.mark.parametrize("time_varying", [False, True])
def test_c_header_gives_the_python_actions(tmp_path, time_varying):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler")
    rng = np.random.default_rng(1)
    root = tmp_path / "dir"
    model = "time_varying = true" if time_varying else ""
    rounds.init(root, write_config(tmp_path / "c.toml", model=model, samples=200))
    rounds.update(root, write_round(tmp_path / "r.csv", random_rows(rng, 200, t=time_varying)))
    header = rounds.export(root, "c")
    assert header.name == "controller-002.h"
    policy = rounds.controller(root)
    X = rng.normal(size=(50, 2)) * 3
    T = rng.integers(-5, 40, size=50)  # beyond the horizon: clamped
    arrays = controller_arrays(root)
    A, B = arrays["A"], arrays["B"]
    dump = (  # the model's arrays, every entry, then the Python controller's and model's use
        "  for (t = 0; t < (int)(sizeof loopid_A / sizeof(double)); ++t)\n"
        '    printf("%.17g\\n", ((const double *)loopid_A)[t]);\n'
        "  for (t = 0; t < (int)(sizeof loopid_B / sizeof(double)); ++t)\n"
        '    printf("%.17g\\n", ((const double *)loopid_B)[t]);\n'
    )
    main = tmp_path / "main.c"
    main.write_text(
        f'#include <stdio.h>\n#include "{header}"\n'
        "int main(void) { double x[2], u[1], xn[2]; int t;\n" + dump +
        '  while (scanf("%lf %lf %d", &x[0], &x[1], &t) == 3) {\n'
        "    loopid_action(x, t, u); loopid_predict(x, u, t, xn);\n"
        '    printf("%.17g %.17g %.17g\\n", u[0], xn[0], xn[1]); }\n  return 0; }\n'
    )  # fmt: skip
    exe = tmp_path / "main"
    flags = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror"]
    subprocess.run([cc, *flags, "-o", exe, main], check=True)
    lines = "".join(f"{float(x[0])!r} {float(x[1])!r} {t}\n" for x, t in zip(X, T, strict=True))
    got = subprocess.run([exe], input=lines, capture_output=True, text=True, check=True).stdout
    got = np.array(got.split(), float)
    np.testing.assert_array_equal(got[: A.size], A.ravel())  # exact: the one float64 array
    np.testing.assert_array_equal(got[A.size : A.size + B.size], B.ravel())
    got = got[A.size + B.size :].reshape(-1, 3)
    want = np.array([policy.action(x, t)[0] for x, t in zip(X, T, strict=True)])
    np.testing.assert_allclose(got[:, 0], want, rtol=0, atol=1e-12)
    for (x, t), (u, *xn) in zip(zip(X, T, strict=True), got, strict=True):
        At = A[min(max(t, 0), 29)] if time_varying else A
        Bt = B[min(max(t, 0), 29)] if time_varying else B
        dx = np.append(x - TARGET, 1.0)
        np.testing.assert_allclose(xn, TARGET + (At @ dx + Bt @ [u - A_OP[0]])[:2], atol=1e-12)
    K = controller_arrays(root)["K"]
    assert bool(np.all(K == K[0])) is not time_varying
    assert ("loopid_K[30][1][3]" in header.read_text()) is time_varying
    saved = json.loads(rounds.export(root, "json").read_text())
    assert saved["time_varying"] is time_varying and saved["round"] == 2
    np.testing.assert_array_equal(saved["K"], K if time_varying else K[0])  # exact round trip
    with np.load(rounds.export(root, "npz", out=tmp_path / "c.npz")) as z:
        np.testing.assert_array_equal(z["K"], K)
        assert list(z["states"]) == ["p", "v"] and z["target"].tolist() == [0.5, 0.0]


@pytest.mark.parametrize("time_varying", [False, True])
def test_model_export_gives_the_one_array_back_in_every_format(tmp_path, time_varying):
    """JSON, npz (and the C header, above) hold the controller's A and B to the last bit, in
    the log's units (the ridge oracle of the first test checks those arrays' values)."""
    rng = np.random.default_rng(4)
    root = tmp_path / "dir"
    model = "time_varying = true" if time_varying else ""
    rounds.init(root, write_config(tmp_path / "c.toml", model=model))
    rounds.update(root, write_round(tmp_path / "r.csv", random_rows(rng, 40, t=time_varying)))
    arrays = controller_arrays(root)
    A, B = arrays["A"], arrays["B"]
    assert A.dtype == B.dtype == np.float64
    assert A.shape == ((30, 3, 3) if time_varying else (3, 3))
    auto = rounds.export(root, "model")
    assert auto.name == "model-002.json"
    saved = json.loads(auto.read_text())
    assert saved["time_varying"] is time_varying and saved["states"] == ["p", "v"]
    np.testing.assert_array_equal(np.array(saved["A"]), A)
    np.testing.assert_array_equal(np.array(saved["B"]), B)
    with np.load(rounds.export(root, "model-npz")) as z:
        np.testing.assert_array_equal(z["A"], A)
        np.testing.assert_array_equal(z["B"], B)
        assert z["A"].dtype == np.float64 and int(z["round"]) == 2
    assert rounds.export(root, "model-json", out=tmp_path / "m.json").read_text() == (
        auto.read_text()
    )


def test_model_export_refuses_a_nonlinear_model(tmp_path):
    model = 'kind = "features"\ndegree = 2\n[planner]\nkind = "ilqr"'
    root = tmp_path / "dir"
    rounds.init(root, write_config(tmp_path / "c.toml", model=model))
    with pytest.raises(ValueError, match="controller 1 has no A and B") as err:
        rounds.export(root, "model")
    assert "\n" not in str(err.value) and not list(root.glob("model-*"))
    assert "loopid_predict" not in rounds.export(root, "c").read_text()
