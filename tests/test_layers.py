"""The tests mirror the package: a test of the core (``tests/algorithms``, ``control``,
``learners``, ``models``, ``systems`` and the top-level modules' ``tests/test_*.py`` of the
core, e.g. ``test_theory.py``) imports nothing of the experiments layer or the command line,
at its top or inside a function. A test that needs a scenario, a family or a run directory
belongs in ``tests/experiments`` (or ``tests/test_cli*.py``)."""

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
CORE_DIRS = ("algorithms", "control", "learners", "models", "systems")
CORE_FILES = ("test_theory.py",)
ABOVE_THE_CORE = ("loopid.experiments", "loopid.cli")


def imported_modules(path: Path) -> set[str]:
    """Every module an ``import``/``from ... import`` in ``path`` names (``from a import b``
    names both ``a`` and ``a.b``, since ``b`` may be a module)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}
    return names


def above_the_core(names: set[str]) -> set[str]:
    return {n for n in names if any(n == m or n.startswith(m + ".") for m in ABOVE_THE_CORE)}


def core_test_files() -> list[Path]:
    files = [p for d in CORE_DIRS for p in sorted((TESTS / d).glob("*.py"))]
    return files + [TESTS / f for f in CORE_FILES]


def test_the_check_sees_an_import_of_the_experiments_layer(tmp_path):
    bad = tmp_path / "test_bad.py"
    bad.write_text(
        "def test():\n    from loopid.experiments import families\n"
        "from loopid.algorithms import loop\n"
    )
    assert above_the_core(imported_modules(bad)) == {
        "loopid.experiments",
        "loopid.experiments.families",
    }


def test_every_core_test_directory_exists():
    for d in CORE_DIRS:
        assert (TESTS / d).is_dir(), d
    assert all((TESTS / f).is_file() for f in CORE_FILES)


def test_core_tests_import_nothing_above_the_core():
    offenders = {
        str(p.relative_to(TESTS)): sorted(above_the_core(imported_modules(p)))
        for p in core_test_files()
    }
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, offenders
