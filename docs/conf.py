"""Sphinx configuration of loopid's documentation (MyST Markdown, the furo theme).

Built offline and strictly: ``make docs`` runs ``sphinx-build -n -W --keep-going``, so a broken
cross-reference, a missing image or a page outside the navigation fails the build.
"""

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent / "src"))

import loopid  # noqa: E402  (turns on float64, as for every user)

project = "loopid"
author = "the loopid authors"
copyright = "2026, the loopid authors"
release = loopid.__version__

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.mathjax"]
source_suffix = {".md": "markdown"}
root_doc = "index"
# _generated holds pages written at build time and included by others (the CLI reference)
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store"]
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

html_theme = "furo"
html_title = f"loopid {release}"

autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "signature"
autodoc_preserve_defaults = True

# Third-party names in signatures and docstrings: no intersphinx (the build is offline), so they
# cannot resolve; everything of loopid's own must.
nitpick_ignore_regex = [
    (
        "py:.*",
        r"(jax|jaxlib|jnp|np|numpy|scipy|optax|gymnasium|gym|pyarrow|pa|typer|click|ray"
        r"|matplotlib|collections|typing|types|pathlib|os|dataclasses|enum|concurrent)(\..*)?",
    ),
    (
        "py:.*",
        r"(Array|ArrayLike|ndarray|PRNGKey|Path|Callable|Sequence|Mapping|Iterable"
        r"|Iterator|NamedTuple|Any|Protocol|Env|Space|Table|DTypeLike|Shape)",
    ),
    # gymnasium's own docstrings, inherited by loopid's environments
    ("py:attr", r"np_random_seed|observation_space"),
]


def write_cli_reference(app) -> None:
    """``_generated/cli.md``: every command's ``--help``, exactly as the program prints it, so
    the page cannot drift from the program (included by ``guides/cli.md``)."""
    import click
    import typer
    from typer.testing import CliRunner

    from loopid.cli import app as cli_app

    root = typer.main.get_command(cli_app)
    runner = CliRunner()

    def help_of(*args: str) -> str:
        result = runner.invoke(cli_app, [*args, "--help"], env={"COLUMNS": "100"})
        if result.exit_code != 0:
            raise RuntimeError(f"loopid {' '.join(args)} --help failed: {result.output}")
        return result.output.rstrip()

    lines = ["```text", help_of(), "```", ""]
    for name in root.list_commands(click.Context(root)):
        lines += [f"### `loopid {name}`", "", "```text", help_of(name), "```", ""]
        group = root.get_command(click.Context(root), name)
        if hasattr(group, "list_commands"):  # a group (loopid round): each subcommand too
            for sub in group.list_commands(click.Context(group)):
                lines += [f"#### `loopid {name} {sub}`", "", "```text", help_of(name, sub)]
                lines += ["```", ""]
    out = DOCS / "_generated" / "cli.md"
    out.parent.mkdir(exist_ok=True)
    text = "\n".join(lines)
    if not out.is_file() or out.read_text(encoding="utf-8") != text:
        out.write_text(text, encoding="utf-8")


def resolve_as_python_does(app, env, node, contnode):
    """A ``py`` reference that names an object through another path (``:func:`dlqr``` in
    :mod:`loopid.control`, which imports it from :mod:`loopid.control.lqr`) resolves to where
    the object is defined and documented, found the way Python finds it: the name looked up from
    the referring module, its packages, the top level, then the modules of its own package that
    define it. A name that Python finds but that has no documentation of its own (a constant, a
    private helper) stays as code text, unlinked; a name Python does not find is still an error.
    """
    if node.get("refdomain") != "py":
        return None
    import importlib
    import inspect

    target = node["reftarget"].lstrip(".~")
    module = node.get("py:module") or ""
    parts = module.split(".") if module else []
    bases = [".".join(parts[:i]) for i in range(len(parts), 0, -1)] + [""]
    bases += _siblings_defining(module, target.split(".")[0])
    domain = env.get_domain("py")
    for base in bases:
        obj = _lookup(importlib, f"{base}.{target}" if base else target)
        if obj is _MISSING:
            continue
        if inspect.ismodule(obj):
            name = obj.__name__
        else:
            owner = getattr(obj, "__module__", None)
            qualname = getattr(obj, "__qualname__", None)
            if not (owner and qualname):
                continue
            name = f"{owner}.{qualname}"
        found = domain.objects.get(name) or domain.modules.get(name)
        if found is not None:
            return _make_ref(app, node, found.docname, name, contnode)
    for base in bases:
        if _lookup(importlib, f"{base}.{target}" if base else target) is not _MISSING:
            return contnode
    return None


_MISSING = object()


def _siblings_defining(module: str, name: str) -> list[str]:
    """The modules of ``module``'s package that define ``name`` themselves (a docstring naming
    a neighbour's function without its module)."""
    package = module.rpartition(".")[0]
    return [
        other
        for other, mod in sorted(sys.modules.items())
        if package
        and other.startswith(package + ".")
        and getattr(getattr(mod, name, None), "__module__", None) == other
    ]


def _lookup(importlib, dotted: str):
    """The object ``dotted`` names: the longest importable module prefix, then attributes."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except Exception:
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return _MISSING
        return obj
    return _MISSING


def _make_ref(app, node, docname, name, contnode):
    from sphinx.util.nodes import make_refnode

    anchor = name if name in app.env.get_domain("py").objects else f"module-{name}"
    return make_refnode(app.builder, node["refdoc"], docname, anchor, contnode, name)


def plain_text_docstring(app, what, name, obj, options, lines) -> None:
    """Docstrings are written to be read as plain text first. A few habits of that text are markup
    to reStructuredText and are made literal here: a lone ``*`` (``x*``, the target), ``|x|`` (a
    norm), ``word_`` (a subscript), and a change of indentation with no blank line between (a
    continued formula or a list of fields), which becomes a block of its own."""
    out, item = [], None  # item: the text column of the list item being continued
    for line in lines:
        line = _escape(line)
        previous = out[-1] if out else ""
        indent = _indent(line)
        if line.lstrip().startswith(("- ", "* ", "\\* ")) and line.strip():
            bullet = 2 if line.lstrip().startswith(("- ", "* ")) else 3
            continued, item = False, indent + bullet
        else:
            continued = item is not None and indent == item
            if line.strip() and not continued:
                item = None
        if (
            previous.strip()
            and line.strip()
            and indent != _indent(previous)
            and not continued
            and not previous.rstrip().endswith("::")
        ):
            out.append("")
        out.append(line)
    lines[:] = out


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def _escape(line: str) -> str:
    """Outside inline literals and roles: a ``*`` that is not part of ``**``, every ``|``, and
    a ``_`` that ends a word become literal characters."""
    parts = line.split("`")
    for i in range(0, len(parts), 2):  # even parts are outside backquotes
        s = parts[i].replace("**", "\0").replace("*", "\\*").replace("\0", "**")
        s = re.sub(r"(?<=\w)_(?=\W|$)", r"\\_", s.replace("|", "\\|"))
        parts[i] = s
    return "`".join(parts)


def setup(app):
    app.connect("builder-inited", write_cli_reference)
    app.connect("autodoc-process-docstring", plain_text_docstring)
    app.connect("missing-reference", resolve_as_python_does)
