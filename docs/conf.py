"""Sphinx configuration of loopid's documentation (MyST Markdown, the furo theme).

Built offline and strictly: ``make docs`` runs ``sphinx-build -n -W --keep-going``, so a broken
cross-reference, a missing image or a page outside the navigation fails the build.
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent / "src"))
sys.path.insert(0, str(DOCS / "_ext"))

import loopid  # noqa: E402  (turns on float64, as for every user)

project = "loopid"
author = "the loopid authors"
copyright = "2026, the loopid authors"
release = loopid.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx.ext.mathjax",
    # MathJax served from the built site (_static/mathjax), not from a CDN: maths reads offline
    "sphinx-mathjax-offline",
    # names documented where users import them, docstrings as napoleon expects (docs/_ext)
    "importable_names",
]
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

# Docstrings are Google style (Args:, Returns:, Attributes:) in reStructuredText, read by
# napoleon; the summary tables are autosummary's, without generated stub pages.
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
autosummary_generate = False

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
    ("py:class", r"optional (int|dict)|observation|ObsType"),
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


def setup(app):
    app.connect("builder-inited", write_cli_reference)
