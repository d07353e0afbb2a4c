"""A family that lives in its own installed package, as the "Add a new kind of system" guide
says: found through its ``loopid.families`` entry point by the command line, by worker
processes and by Ray's workers, with nothing of it in loopid.

The test makes the package: the guide's family (its ``python`` block as a module, less the
``register(...)`` call and the ``__main__`` run) and a ``pyproject.toml`` with the entry point
``linear = "loopid_linear:FAMILY"``, and installs it with pip (offline, ``--target`` a
temporary directory). Every run is a subprocess with that directory and loopid's sources on
``PYTHONPATH``, as an installed package would be on ``sys.path``; they share the session's JAX
compilation cache (``cache``), so only the first run of a program compiles.

The package builds with its own few-line backend (``backend-path``), not setuptools: building a
wheel with setuptools needs the ``wheel`` package on older setuptools, and an offline pip
without build isolation cannot fetch it.
"""

import os
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from test_readme_family import guide_block

SRC = Path(__file__).resolve().parents[2] / "src"
MAIN = 'if __name__ == "__main__":'

#: A PEP 517 backend for these test packages alone: a pure-Python wheel of the project's
#: top-level ``*.py`` modules, with the entry points of its ``pyproject.toml``.
BACKEND = r"""
import base64
import hashlib
import tomllib
import zipfile
from pathlib import Path


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    project = tomllib.loads(Path("pyproject.toml").read_text())["project"]
    name, version = project["name"].replace("-", "_"), project["version"]
    info = f"{name}-{version}.dist-info"
    groups = project.get("entry-points", {})
    files = {p.name: p.read_bytes() for p in sorted(Path().glob("*.py"))}
    files[f"{info}/METADATA"] = (
        f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {version}\n"
    ).encode()
    files[f"{info}/WHEEL"] = (
        b"Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n"
    )
    files[f"{info}/entry_points.txt"] = "".join(
        f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items()) + "\n"
        for group, entries in groups.items()
    ).encode()
    record = [
        f"{path},sha256="
        + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        + f",{len(data)}"
        for path, data in files.items()
    ]
    files[f"{info}/RECORD"] = "\n".join([*record, f"{info}/RECORD,,", ""]).encode()
    wheel = f"{name}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(Path(wheel_directory) / wheel, "w") as z:
        for path, data in files.items():
            z.writestr(path, data)
    return wheel
"""


def family_module() -> str:
    """The guide's family as a module of its own package: its block without the ``__main__``
    run, and ``FAMILY`` the family itself instead of ``register(...)``'s return (a packaged
    family is found through its entry point; ``register`` is for a script's). The block's
    import of ``register`` stays, unused."""
    code = guide_block()
    assert code.count(MAIN) == 1, f"the guide's block has no single {MAIN!r}"
    code = code.split(MAIN)[0].rstrip() + "\n"
    code, n = re.subn(r"^FAMILY = register\((.+)\)$", r"FAMILY = \1", code, flags=re.MULTILINE)
    assert n == 1, "the guide's block has no single FAMILY = register(...)"
    return code


def install(tmp: Path, name: str, entry: str, module: str, code: str) -> Path:
    """Write the package ``tmp/name`` (one module ``module``.py holding ``code``, the entry
    point ``entry`` of group ``loopid.families``) and pip-install it into ``tmp/site-name``:
    that directory."""
    package = tmp / name
    (package / "backend").mkdir(parents=True)
    (package / "backend" / "backend.py").write_text(BACKEND)
    (package / f"{module}.py").write_text(code)
    (package / "pyproject.toml").write_text(
        textwrap.dedent(f"""\
            [build-system]
            requires = []
            build-backend = "backend"
            backend-path = ["backend"]

            [project]
            name = "{name}"
            version = "0.1.0"

            [project.entry-points."loopid.families"]
            {entry}
            """)
    )
    site = tmp / f"site-{name}"
    r = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation",
         "--no-index", "--disable-pip-version-check", "--quiet", "--target", site, package],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    return site


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The guide's family installed as the package ``linearpkg``: its ``--target`` directory."""
    return install(
        tmp_path_factory.mktemp("linear"),
        "linearpkg",
        'linear = "loopid_linear:FAMILY"',
        "loopid_linear",
        family_module(),
    )


def environment(site: Path, cache: Path | None = None) -> dict[str, str]:
    """This process's environment with ``site`` and loopid's sources on ``PYTHONPATH`` (and
    ``cache`` as the JAX compilation cache)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), str(SRC)]))
    if cache is not None:
        env["LOOPID_JAX_CACHE"] = str(cache)
    return env


def python(code: str, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=environment(site),
        timeout=300,
    )  # fmt: skip


def loopid(*args, site: Path, cache: Path) -> subprocess.CompletedProcess:
    """``python -m loopid ARGS`` with the package installed (``site``), finished."""
    return subprocess.run(
        [sys.executable, "-m", "loopid", *map(str, args)], capture_output=True, text=True,
        env=environment(site, cache), timeout=900,
    )  # fmt: skip


def test_the_installed_family_comes_after_loopids_own(site):
    r = python(
        "from loopid.experiments.families import families, family_named\n"
        "print(' '.join(families()), type(family_named('linear')).__module__)",
        site,
    )
    assert r.returncode == 0, r.stderr
    *names, module = r.stdout.split()
    assert names[:3] == ["helicopter", "mdp", "gym"] and "linear" in names[3:], names
    assert module == "loopid_linear"


def test_an_entry_point_that_is_not_a_family_is_refused(tmp_path):
    broken = install(
        tmp_path, "brokenpkg", 'broken = "loopid_broken:FAMILY"', "loopid_broken", "FAMILY = 3\n"
    )
    r = python(
        "from loopid.experiments.families import families\n"
        "try:\n    families()\nexcept TypeError as e:\n    print(e)\n"
        "else:\n    print('accepted')",
        broken,
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("\n") == 1, r.stdout  # one line, naming the entry point
    assert "broken = 'loopid_broken:FAMILY'" in r.stdout and "not a Family" in r.stdout


def test_run_help_lists_the_installed_scenario(site, cache):
    r = loopid("run", "--help", site=site, cache=cache)
    assert r.returncode == 0, r.stderr
    assert "linear: linear" in " ".join(r.stdout.split())  # "family: its scenarios"


ARGS = ["run", "linear", "--seeds", "2", "--iterations", "3", "--samples", "50",
        "--test-trajectories", "5", "--quiet"]  # fmt: skip


@pytest.fixture(scope="module")
def local_run(site, cache, tmp_path_factory):
    """``loopid run linear`` in two worker processes: ``(finished process, run directory)``."""
    out = tmp_path_factory.mktemp("runs") / "local"
    return loopid(*ARGS, "--workers", "2", "--out", out, site=site, cache=cache), out


@pytest.mark.slow
def test_worker_processes_run_the_installed_family(local_run):
    r, out = local_run
    assert r.returncode == 0, r.stderr
    for name in ("results.parquet", "config.toml", "figure.png", "report.md"):
        assert (out / name).is_file(), name
    assert tomllib.loads((out / "config.toml").read_text())["run"]["family"] == "linear"
    assert pq.read_table(out / "results.parquet").num_rows == 2 * 2 * 3  # methods, seeds, its


@pytest.mark.slow
def test_ray_workers_run_the_installed_family_to_the_local_table(local_run, site, cache):
    pytest.importorskip("ray")
    r, local = local_run
    assert r.returncode == 0, r.stderr
    out = local.parent / "ray"
    r = loopid(*ARGS, "--executor", "ray", "--out", out, site=site, cache=cache)
    assert r.returncode == 0, r.stderr
    # the same seeds give the same table; the schema's metadata holds the cells' wall times
    expected = pq.read_table(local / "results.parquet").replace_schema_metadata(None)
    assert pq.read_table(out / "results.parquet").replace_schema_metadata(None).equals(expected)
    assert (out / "report.md").is_file()
