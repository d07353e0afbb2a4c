"""The tests mirror the package: a test of the core (``tests/algorithms``, ``control``,
``learners``, ``models``, ``systems`` and the core's top-level ``tests/test_*.py`` named in
:data:`CORE_FILES`) imports nothing of the experiments layer or the command line, at its top or
inside a function. A test that needs a scenario, a family or a run directory
belongs in ``tests/experiments`` (or ``tests/test_cli*.py``)."""

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
CORE_DIRS = ("algorithms", "control", "learners", "models", "systems")
CORE_FILES: tuple[str, ...] = ()
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


SRC = TESTS.parent / "src" / "loopid"


def module_getattrs_and_deprecations(root: Path) -> list[str]:
    """``FILE:LINE`` of every module-level ``__getattr__`` (a function or an assignment) and
    every ``DeprecationWarning`` named in the Python files below ``root``."""
    found = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            named = (isinstance(node, ast.FunctionDef) and node.name == "__getattr__") or (
                isinstance(node, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == "__getattr__" for t in node.targets)
            )
            if named:
                found.append(f"{path.relative_to(root)}:{node.lineno}")
        for node in ast.walk(tree):
            if isinstance(node, ast.Name) and node.id == "DeprecationWarning":
                found.append(f"{path.relative_to(root)}:{node.lineno}")
    return found


def test_an_unreleased_package_keeps_no_old_names():
    """loopid has never been released: no name is kept for compatibility, so no module answers
    unknown names (``__getattr__``) and nothing warns ``DeprecationWarning``."""
    assert module_getattrs_and_deprecations(SRC) == []


def test_the_old_names_check_sees_both_forms(tmp_path):
    (tmp_path / "a.py").write_text("def __getattr__(name):\n    raise AttributeError(name)\n")
    (tmp_path / "b.py").write_text("__getattr__ = len\n")
    (tmp_path / "c.py").write_text("import warnings\nwarnings.warn('x', DeprecationWarning)\n")
    assert module_getattrs_and_deprecations(tmp_path) == ["a.py:1", "b.py:1", "c.py:2"]


# The package's layers: the engine knows no experiment, the pipeline knows no family.
ENGINE = ("systems", "models", "learners", "control", "algorithms", "rounds", "settings")
REGISTRY = ("loopid.experiments.families", "loopid.experiments.families.base")


def family_modules(names: set[str]) -> set[str]:
    """The names in ``names`` inside one family's package (``loopid.experiments.families.X``
    and below, for a package or module X of ``families/`` other than the registry's ``base``)."""
    prefix = "loopid.experiments.families."
    root = SRC / "experiments" / "families"
    found = {p.stem for p in root.iterdir() if p.suffix == ".py" or (p / "__init__.py").is_file()}
    packages = found - {"__init__", "base"}
    return {n for n in names if n.startswith(prefix) and n[len(prefix) :].split(".")[0] in packages}


def pipeline_files() -> list[Path]:
    """The experiment pipeline's modules (``experiments/`` outside ``families/``) and the
    command line, which may use the family registry but no family."""
    exp = SRC / "experiments"
    files = [p for p in sorted(exp.rglob("*.py")) if "families" not in p.relative_to(exp).parts]
    return [*files, SRC / "cli.py"]


def test_the_pipeline_and_the_command_line_name_no_family():
    offenders = {
        str(p.relative_to(SRC)): sorted(family_modules(imported_modules(p)))
        for p in pipeline_files()
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_the_engine_imports_no_experiment():
    files = [p for d in ENGINE for p in sorted((SRC / d).rglob("*.py"))]
    assert len(files) > 40
    offenders = {
        str(p.relative_to(SRC)): sorted(above_the_core(imported_modules(p))) for p in files
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_the_layer_checks_see_a_family_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from loopid.experiments.families import family_named\n"
        "from loopid.experiments.families.base import Family\n"
        "def f():\n    from loopid.experiments.families.helicopter import scenario\n"
    )
    assert family_modules(imported_modules(bad)) == {
        "loopid.experiments.families.helicopter",
        "loopid.experiments.families.helicopter.scenario",
    }


#: The modules every family package has, one per part of the family interface: its config,
#: its runs, its report and figures, its saved policies and models.
FAMILY_LAYOUT = ("scenario.py", "run.py", "report.py", "saved.py")


def families_missing_layout(families: Path) -> dict[str, list[str]]:
    """``{family: [missing module, ...]}`` for every family package under ``families`` (each
    folder with an ``__init__.py``) that lacks one of :data:`FAMILY_LAYOUT`."""
    missing = {}
    for package in sorted(p for p in families.iterdir() if (p / "__init__.py").is_file()):
        lacks = [name for name in FAMILY_LAYOUT if not (package / name).is_file()]
        if lacks:
            missing[package.name] = lacks
    return missing


def test_every_family_package_has_the_layout_modules():
    families = SRC / "experiments" / "families"
    packages = [p.name for p in families.iterdir() if (p / "__init__.py").is_file()]
    assert {"helicopter", "mdp", "gym"} <= set(packages)
    assert families_missing_layout(families) == {}


def test_the_layout_check_sees_a_family_lacking_a_module(tmp_path):
    (tmp_path / "__init__.py").write_text("")
    (tmp_path / "base.py").write_text("")  # a module of the registry, not a family
    (tmp_path / "notes").mkdir()  # a folder without __init__.py is no family
    for family, modules in {
        "whole": FAMILY_LAYOUT,
        "nosaved": ("scenario.py", "run.py", "report.py"),
        "bare": (),
    }.items():
        (tmp_path / family).mkdir()
        for name in ("__init__.py", *modules):
            (tmp_path / family / name).write_text("")
    (tmp_path / "reportdir").mkdir()  # report.py as a folder is not the module
    for name in ("__init__.py", "scenario.py", "run.py", "saved.py"):
        (tmp_path / "reportdir" / name).write_text("")
    (tmp_path / "reportdir" / "report.py").mkdir()
    assert families_missing_layout(tmp_path) == {
        "bare": list(FAMILY_LAYOUT),
        "nosaved": ["saved.py"],
        "reportdir": ["report.py"],
    }


def test_no_module_is_over_400_lines():
    sizes = {str(p.relative_to(SRC)): len(p.read_text().splitlines()) for p in SRC.rglob("*.py")}
    assert {k: n for k, n in sizes.items() if n > 400} == {}
