"""The documentation: the site builds strictly, documents every public name, its Python blocks
and the README's run, the README stays short, and no user-facing text points at internal notes.

The strict build (``sphinx-build -n -W --keep-going -E``, as ``make docs``) fails on a broken
cross-reference, a missing image or a page left out of the navigation. It runs in a subprocess
(``docs_build.py``, shared with ``test_html.py``) started when this module starts, so it overlaps
the code blocks, which run in this process.
"""

import ast
import importlib
import pkgutil
import re
from pathlib import Path

import pytest
from docs_build import docs_build_fixture  # noqa: F401  (the one build of the site, a fixture)

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
SRC = ROOT / "src" / "loopid"

# The packages whose __all__ is the public API: every name in it must be on an API page.
PACKAGES = [
    "loopid",
    "loopid.control",
    "loopid.learners",
    "loopid.models",
    "loopid.systems",
    "loopid.systems.helicopter",
    "loopid.algorithms",
    "loopid.settings",
    "loopid.experiments",
    "loopid.systems.mdp_bounds",  # a module with its own __all__
    "loopid.rounds",
]

# A Python block whose first line is this comment is shown, not run (it needs a run directory,
# or takes minutes). Every other ```python block of the README and of docs/ runs.
ILLUSTRATIVE = "# illustrative"

# Blocks run, and checked in depth, by another test: (file, index of its python block).
RUN_ELSEWHERE = {
    ("docs/guides/new-system.md", 0): "tests/experiments/test_readme_family.py",
}

# Where internal notes may be named: the history keeps its references.
HISTORY = {"CHANGELOG.md", "docs/changelog.md", "docs/paper/notes.md"}

# Files whose docstrings (or, for TOML, comments) may still name the internal specification or
# an issue number while they are being edited elsewhere; none now. Remove a path once it is
# clean; the test fails on a listed path that is already clean.
PENDING: set[str] = set()

# "SPEC" in capitals (the reading `spec` is a name users type); "issue 19", "Issue #3".
INTERNAL = re.compile(r"\bSPEC\b|\b[Ii]ssue\s+#?\d+")


@pytest.fixture(scope="module", autouse=True)
def start_build(docs_build):
    """Start the build (``docs_build.py``) before the first test of this module, so that it runs
    while the code blocks do."""


@pytest.fixture(scope="module")
def build(docs_build):
    return docs_build


def markdown_files() -> list[Path]:
    skip = {DOCS / "_build", DOCS / "_generated"}
    pages = [p for p in DOCS.rglob("*.md") if not any(s in p.parents for s in skip)]
    return [ROOT / "README.md", *sorted(pages)]


def python_blocks(path: Path) -> list[str]:
    text = path.read_text(encoding="utf-8")
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.MULTILINE | re.DOTALL)


def runnable_blocks() -> list[tuple[str, str]]:
    """``(id, code)`` of every block to run, once per distinct code."""
    seen, blocks = set(), []
    for path in markdown_files():
        name = path.relative_to(ROOT).as_posix()
        for i, code in enumerate(python_blocks(path)):
            if code.startswith(ILLUSTRATIVE) or (name, i) in RUN_ELSEWHERE or code in seen:
                continue
            seen.add(code)
            blocks.append((f"{name}[{i}]", code))
    return blocks


BLOCKS = runnable_blocks()


@pytest.mark.parametrize("code", [c for _, c in BLOCKS], ids=[i for i, _ in BLOCKS])
def test_python_block_runs(code, tmp_path, monkeypatch):
    """Run as a reader would, as a script in a fresh directory."""
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "<docs block>", "exec"), {"__name__": "__main__"})


def test_blocks_are_found():
    """The collector sees the blocks it should: the README's quickstart runs, the guide's family
    example is left to its own test, and an illustrative block is skipped."""
    ids = [i for i, _ in BLOCKS]
    assert any(i.startswith("README.md[") for i in ids)
    assert all(not i.startswith("docs/guides/new-system.md") for i in ids)
    for (name, index), test in RUN_ELSEWHERE.items():
        assert len(python_blocks(ROOT / name)) > index, name
        assert (ROOT / test).is_file(), test
    saved = python_blocks(DOCS / "guides" / "saved.md")
    assert saved and all(c.startswith(ILLUSTRATIVE) for c in saved)


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; keep it at most 200"


def test_readme_starts_with_the_two_commands():
    """``make reproduce`` and ``make test`` are on the first screen."""
    first_screen = "\n".join((ROOT / "README.md").read_text(encoding="utf-8").splitlines()[:40])
    assert "make reproduce" in first_screen and "make test" in first_screen


def internal_references(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if INTERNAL.search(line)]


def test_no_internal_references_in_user_facing_pages():
    found = {}
    for path in markdown_files():
        name = path.relative_to(ROOT).as_posix()
        if name not in HISTORY and (hits := internal_references(path.read_text("utf-8"))):
            found[name] = hits
    assert not found, f"user-facing pages name internal notes or issue numbers: {found}"


def docstrings(path: Path) -> str:
    """Every docstring of a module (module, classes, functions), or a TOML file's whole text."""
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".toml":
        return text
    tree = ast.parse(text)
    nodes = [tree, *ast.walk(tree)]
    kinds = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    return "\n".join(ast.get_docstring(n) or "" for n in nodes if isinstance(n, kinds))


def test_no_internal_references_in_docstrings():
    found, clean_pending = {}, []
    for path in sorted([*SRC.rglob("*.py"), *SRC.rglob("*.toml")]):
        name = path.relative_to(ROOT).as_posix()
        hits = internal_references(docstrings(path))
        if name in PENDING:
            if not hits:
                clean_pending.append(name)
        elif hits:
            found[name] = hits
    assert not found, f"docstrings name internal notes or issue numbers: {found}"
    assert not clean_pending, f"clean now, remove from PENDING: {clean_pending}"


def test_strict_build(build):
    code, warnings, html = build()
    assert code == 0, f"sphinx-build -n -W failed:\n{warnings}"
    assert (html / "index.html").is_file()
    cli = (html / "guides" / "cli.html").read_text(encoding="utf-8")
    assert "loopid run" in cli and "--readings" in cli  # the generated CLI reference is there


def documented_as(package: str, name: str) -> set[str]:
    """The ids under which ``package.name`` may be documented: the name a user imports, a module
    of that name, or, for a function that shares its name with its module
    (``loopid.control.ilqr``: Sphinx keeps one object a full name), the module's function."""
    full = f"{package}.{name}"
    return {full, f"module-{full}", f"{full}.{name}"}


def api_pages(html: Path) -> list[Path]:
    return sorted((html / "api").glob("*.html"))


def test_every_public_name_is_documented(build):
    """Every name of a listed package's ``__all__`` is documented on an API page under the name
    a user imports it by (``loopid.control.dlqr``, not ``loopid.control.lqr.dlqr``)."""
    code, warnings, html = build()
    assert code == 0, warnings
    ids = set()
    for page in api_pages(html):
        ids.update(re.findall(r'id="([^"]+)"', page.read_text(encoding="utf-8")))
    missing = []
    for package in PACKAGES:
        for name in getattr(importlib.import_module(package), "__all__", ()):
            if not documented_as(package, name) & ids:
                missing.append(f"{package}.{name}")
    assert not missing, f"public names without documentation under their package: {missing}"


def test_every_package_page_has_its_summary_table(build):
    """Every public name of a package is a line of a summary table (autosummary) that links to
    its entry."""
    code, warnings, html = build()
    assert code == 0, warnings
    listed = set()
    for page in api_pages(html):
        for table in re.findall(
            r'<table class="autosummary.*?</table>', page.read_text("utf-8"), re.S
        ):
            listed.update(re.findall(r'<a class="reference internal" href="[^"]*#([^"]+)"', table))
    missing = [
        f"{package}.{name}"
        for package in PACKAGES
        if hasattr(importlib.import_module(package), "__path__")
        for name in importlib.import_module(package).__all__
        if not documented_as(package, name) & listed
    ]
    assert not missing, f"public names missing from the summary tables: {missing}"


def test_every_public_module_is_documented(build):
    """Every module of the listed packages whose name does not start with ``_`` has its section
    on an API page (a new module needs its ``automodule`` in ``docs/api/``)."""
    code, warnings, html = build()
    assert code == 0, warnings
    ids = set()
    for page in api_pages(html):
        ids.update(re.findall(r'id="module-([^"]+)"', page.read_text(encoding="utf-8")))
    modules = set(PACKAGES)
    for package in PACKAGES:
        module = importlib.import_module(package)
        if hasattr(module, "__path__"):
            for info in pkgutil.walk_packages(module.__path__, package + "."):
                if not any(part.startswith("_") for part in info.name.split(".")):
                    modules.add(info.name)
    assert not sorted(modules - ids), f"modules without an API section: {sorted(modules - ids)}"
