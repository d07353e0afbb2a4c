"""The strict build of the site, made once for a whole test run and read by every test of
``tests/docs`` (the build takes about half a minute).

Under pytest-xdist each worker is a session of its own, so the build is claimed through the
file system: the first worker to create the run's ``docs-build`` folder starts it, in a
subprocess that writes its exit status last; every worker waits for that file.

Not a ``conftest.py``: the suite's own ``tests/conftest.py`` is imported by name (``from conftest
import cli``), and a second module of that name would shadow it. A test module imports the
fixture: ``from docs_build import docs_build_fixture``.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[2] / "docs"
TIMEOUT_S = 600


@pytest.fixture(scope="session", name="docs_build")
def docs_build_fixture(tmp_path_factory):
    """The strict build (``sphinx-build -n -W --keep-going -E``, as ``make docs``), started at
    once in a subprocess; yields a function that waits for it and returns ``(returncode,
    warnings, html directory)``."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # shared by the workers of this run, not by other runs
    out = base / "docs-build"
    html, status, warnings = out / "html", out / "returncode", out / "warnings.txt"
    process = None
    try:
        out.mkdir()
    except FileExistsError:
        pass  # another worker builds it
    else:
        cmd = [sys.executable, "-m", "sphinx", "-n", "-W", "--keep-going", "-E", "-q", "-j", "1"]
        cmd += ["-b", "html", "-d", str(out / "doctrees"), str(DOCS), str(html)]
        # the status is written after the warnings, under its final name in one step
        script = (
            "import os, subprocess, sys\n"
            f"with open({str(warnings)!r}, 'w') as err:\n"
            f"    code = subprocess.run({cmd!r}, stdout=subprocess.DEVNULL, stderr=err)\n"
            f"open({str(status)!r} + '.part', 'w').write(str(code.returncode))\n"
            f"os.replace({str(status)!r} + '.part', {str(status)!r})\n"
        )
        process = subprocess.Popen([sys.executable, "-c", script], start_new_session=True)

    def wait():
        deadline = time.monotonic() + TIMEOUT_S
        while not status.is_file():
            if time.monotonic() > deadline:
                raise TimeoutError(f"the docs build did not finish in {TIMEOUT_S} s ({out})")
            time.sleep(0.2)
        return int(status.read_text()), warnings.read_text(encoding="utf-8"), html

    yield wait
    if process is not None and process.poll() is None:  # a run stopped early: end the build
        os.killpg(process.pid, signal.SIGKILL)  # the wrapper and sphinx-build under it
        process.wait()
        status.write_text("-9")
