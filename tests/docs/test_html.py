"""The built site as a reader's browser sees it, read from the strict build that
``test_docs.py`` also reads (the ``docs_build`` fixture of ``docs_build.py``: one build a run).

It fails on what the strict build lets through: a backslash shown before ``_``, ``*``, ``|`` or
``{`` (an escape that leaked into text or code), a role shown as its markup, a link or
``#anchor`` to nothing, a script or stylesheet from the network (the site must read offline,
maths included), an image in ``docs/`` that no page shows, and a MyST role in a Markdown page
that is read on GitHub, where it shows as raw text. Each check is a small function of one page,
tried first on tiny inputs that must make it fail (``test_check_catches``) and one that must
pass.
"""

import hashlib
import re
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
from docs_build import docs_build_fixture  # noqa: F401  (the one build of the site, a fixture)

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
IMAGES = {".png", ".gif", ".jpg", ".jpeg", ".svg", ".webp"}
NOT_SOURCES = {"_build", "_generated"}  # folders of docs/ that hold build output, not pages


class Page(HTMLParser):
    """One HTML page: its text outside maths, scripts and styles; the ids it defines; the links
    it follows (``<a href>``) and the resources it loads (scripts, stylesheets, images)."""

    def __init__(self, html: str):
        super().__init__(convert_charrefs=True)
        self.text: list[str] = []
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.loads: list[str] = []
        self.images: list[str] = []
        self._skip: list[str] = []  # the tags of the open elements whose text is not read
        self.feed(html)
        self.close()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for key in ("id", "name"):
            if a.get(key) and (key == "id" or tag == "a"):
                self.ids.add(a[key])
        if tag == "a" and a.get("href") is not None:
            self.links.append(a["href"])
        if tag in ("script", "img", "iframe", "source") and a.get("src"):
            self.loads.append(a["src"])
        if (
            tag == "link"
            and a.get("href")
            and {"stylesheet", "preload", "modulepreload"} & set((a.get("rel") or "").split())
        ):
            self.loads.append(a["href"])
        if tag == "img" and a.get("src"):
            self.images.append(a["src"])
        if tag in ("img", "link", "meta", "br", "hr", "input", "source", "wbr"):
            return  # void elements: no end tag
        maths = "math" in (a.get("class") or "").split()
        if self._skip or maths or tag in ("script", "style"):
            self._skip.append(tag)

    def handle_endtag(self, tag):
        if self._skip and self._skip[-1] == tag:
            self._skip.pop()

    def handle_data(self, data):
        if not self._skip:
            self.text.append(data)


# A backslash before one of these characters is an escape of the docstring's markup that was
# meant to be consumed and was shown instead.
ESCAPED = re.compile(r"\\[_*|{]")


def escapes(html: str) -> list[str]:
    """Every backslash before ``_``, ``*``, ``|`` or ``{`` in the text and code a reader sees
    (maths, which MathJax typesets, is left out), with a few characters around it."""
    text = "".join(Page(html).text)
    return [text[max(m.start() - 20, 0) : m.end() + 20] for m in ESCAPED.finditer(text)]


# A Sphinx role written where reStructuredText does not read it (a literal block) shows as is;
# so do double backquotes that do not close (nested, or after a character such as ∝ or ±).
RAW_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|obj|exc|ref|doc):`[^`]*`")


def raw_roles(html: str) -> list[str]:
    """Every role shown as its markup (``:attr:`x```) in the text and code a reader sees."""
    return RAW_ROLE.findall("".join(Page(html).text))


def raw_literals(html: str) -> list[str]:
    """Every pair of backquotes shown, with a few characters around it (in the API pages, where
    no docstring means to show one)."""
    text = "".join(Page(html).text)
    return [text[max(m.start() - 20, 0) : m.end() + 20] for m in re.finditer("``", text)]


def network_loads(html: str) -> list[str]:
    """The scripts, stylesheets and images a page loads from another host."""
    return [url for url in Page(html).loads if urlsplit(url).scheme or url.startswith("//")]


def dead_links(page: Path, site: Path, pages: dict[Path, Page]) -> list[str]:
    """The internal links of ``page`` (built under ``site``) to a file that is not there or to
    an ``#anchor`` that the file does not define. ``pages``: the parsed pages, by path."""
    dead = []
    for href in pages[page].links:
        parts = urlsplit(href)
        if parts.scheme or href.startswith("//") or not (parts.path or parts.fragment):
            continue  # another site, mailto:, or a bare "#"
        target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
        if not target.is_relative_to(site.resolve()) and target != page:
            dead.append(f"{href} (outside the site)")
        elif target.is_dir():
            target = target / "index.html"
        if not target.is_file():
            dead.append(href)
        elif parts.fragment and target.suffix == ".html":
            ids = pages[target].ids if target in pages else Page(_read(target)).ids
            if unquote(parts.fragment) not in ids:
                dead.append(href)
    return dead


def unshown_images(sources: list[Path], site: Path, pages: dict[Path, Page]) -> list[str]:
    """The images of ``sources`` that no built page shows in an ``<img>``: compared by content,
    since Sphinx copies each shown image into ``_images/`` (renaming it on a clash)."""
    shown = set()
    for path, page in pages.items():
        for src in page.images:
            parts = urlsplit(src)
            file = (path.parent / unquote(parts.path)).resolve()
            if not parts.scheme and file.is_file():
                shown.add(hashlib.sha256(file.read_bytes()).hexdigest())
    return [
        str(image)
        for image in sources
        if hashlib.sha256(image.read_bytes()).hexdigest() not in shown
    ]


FENCE = re.compile(r"^(```+|~~~+).*?^\1\s*$", re.MULTILINE | re.DOTALL)
# a role, or a code span (which may quote one): whichever starts first on the line
ROLE_OR_CODE = re.compile(r"(?P<role>\{[a-z][\w:+-]*\}`[^`]+`)|(?P<ticks>`+).+?(?P=ticks)")


def myst_roles(markdown: str) -> list[str]:
    """The MyST roles (``{func}`...```) of a Markdown text outside its code, which GitHub shows
    as raw text; a role quoted inside a code span or block is an example, not markup."""
    found = []
    for line in FENCE.sub("", markdown).splitlines():
        found += [m["role"] for m in ROLE_OR_CODE.finditer(line) if m["role"]]
    return found


# Pages the README links to that are written for the site only: the API reference is autodoc's
# directives and roles, which no Markdown viewer renders.
SITE_ONLY = {"docs/api/index.md"}


def github_pages() -> list[Path]:
    """The README and the Markdown pages it links to: read on GitHub as much as on the site."""
    readme = ROOT / "README.md"
    pages = [readme]
    for target in re.findall(r"\]\(([^)\s#]+\.md)(?:#[^)]*)?\)", readme.read_text("utf-8")):
        path = (ROOT / target).resolve()
        if path.is_file() and path not in pages and target not in SITE_ONLY:
            pages.append(path)
    return pages


def image_sources() -> list[Path]:
    """The images kept in ``docs/``, outside its build and generated folders."""
    return sorted(
        p
        for p in DOCS.rglob("*")
        if p.suffix.lower() in IMAGES
        and not NOT_SOURCES & set(p.relative_to(DOCS).parts)
        and "_static" not in p.relative_to(DOCS).parts
    )


def _read(path: Path) -> str:
    return path.read_text(encoding="utf-8")


# --- the checks on tiny inputs: each bad one must fail, the clean one must pass ---------------

CLEAN = """<html><head><link rel="stylesheet" href="_static/furo.css">
<script src="_static/mathjax/tex-chtml.js"></script></head><body>
<p id="top">The cost <span class="math">\\(\\sum_{t} x_{t}\\)</span>, code
<code class="literal"><span class="pre">e_{(s,a)}</span></code>, a path C:\\runs.</p>
<a href="#top">up</a> <a href="other.html#there">there</a> <a href="https://example.org">x</a>
<img src="_images/a.png"></body></html>"""


@pytest.mark.parametrize(
    ("check", "bad"),
    [
        ("escapes", '<p>code <code><span class="pre">e\\_{(s,a)}</span></code></p>'),
        ("escapes", "<p>update\\|export</p>"),
        ("escapes", "<p>[n_x, \\*B]</p>"),
        ("markup", "<pre>cells/S__M.npz    the arrays of :attr:`Trace.final`</pre>"),
        ("literal", "<p>probability ∝ ``gamma``^k</p>"),
        ("network", '<script src="https://cdn.example.org/mathjax/tex-chtml.js"></script>'),
        ("network", '<link rel="stylesheet" href="//fonts.example.org/a.css">'),
        ("dead", '<p id="top"></p><a href="#nowhere">x</a>'),
        ("dead", '<a href="other.html#nowhere">x</a>'),
        ("dead", '<a href="missing.html">x</a>'),
        ("image", "<p>no image</p>"),
        ("role", "See {func}`loopid.control.dlqr`."),
    ],
)
def test_check_catches(check, bad, tmp_path):
    """Each check fails on its defect and passes the clean page (in the same setting)."""
    site = tmp_path / "site"
    (site / "_images").mkdir(parents=True)
    (site / "_images" / "a.png").write_bytes(b"shown")
    (site / "other.html").write_text('<p id="there"></p>', encoding="utf-8")
    image = tmp_path / "a.png"
    image.write_bytes(b"shown")

    def run(html: str) -> list[str]:
        page = site / "index.html"
        page.write_text(html, encoding="utf-8")
        pages = {p: Page(_read(p)) for p in site.glob("*.html")}
        return {
            "escapes": lambda: escapes(html),
            "markup": lambda: raw_roles(html),
            "literal": lambda: raw_literals(html),
            "network": lambda: network_loads(html),
            "dead": lambda: dead_links(page, site, pages),
            "image": lambda: unshown_images([image], site, pages),
            "role": lambda: myst_roles(html),
        }[check]()

    assert run(bad), f"{check} let this through: {bad}"
    assert not run(CLEAN), f"{check} fails a clean page: {run(CLEAN)}"


def test_roles_in_code_are_examples():
    """A role quoted in a code span or a fenced block is shown on purpose."""
    assert not myst_roles("Write ``{func}`name` `` or\n\n```md\n{func}`name`\n```\n")
    assert myst_roles("A role {mod}`loopid` after `code`.")


# --- the built site ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def site(docs_build):
    code, warnings, html = docs_build()
    assert code == 0, f"sphinx-build -n -W failed:\n{warnings}"
    pages = {p.resolve(): Page(_read(p)) for p in sorted(html.rglob("*.html"))}
    return html.resolve(), pages


def _report(found: dict[str, list[str]]) -> str:
    more = lambda hits: f" and {len(hits) - 5} more" if len(hits) > 5 else ""  # noqa: E731
    return "\n".join(f"{name}: {hits[:5]}{more(hits)}" for name, hits in found.items())


def test_no_escapes_shown(site):
    html, pages = site
    found = {}
    for path in pages:
        if "_modules" not in path.relative_to(html).parts:  # source code, shown as written
            if hits := escapes(_read(path)):
                found[path.relative_to(html).as_posix()] = hits
    assert not found, f"backslashes shown before _ * | {{:\n{_report(found)}"


def test_no_markup_shown(site):
    """No role shown as markup on any page, and no double backquotes on the API pages."""
    html, pages = site
    found = {}
    for path in pages:
        name = path.relative_to(html).as_posix()
        if not name.startswith("_modules/"):
            hits = raw_roles(_read(path))
            hits += raw_literals(_read(path)) if name.startswith("api/") else []
            if hits:
                found[name] = hits
    assert not found, f"markup shown as text (inside a literal block?):\n{_report(found)}"


def test_no_dead_links(site):
    html, pages = site
    found = {p.relative_to(html).as_posix(): d for p in pages if (d := dead_links(p, html, pages))}
    assert not found, f"links to nothing:\n{_report(found)}"


def test_nothing_loaded_from_the_network(site):
    html, pages = site
    found = {p.relative_to(html).as_posix(): n for p in pages if (n := network_loads(_read(p)))}
    assert not found, f"pages that need the network:\n{_report(found)}"
    css = {
        p.relative_to(html).as_posix(): hits
        for p in html.rglob("*.css")
        if (hits := re.findall(r"(?:@import|url\()\s*['\"]?(?:https?:)?//[^)'\"\s]+", _read(p)))
    }
    assert not css, f"stylesheets that load from the network: {css}"


def test_every_image_is_shown(site):
    html, pages = site
    assert not unshown_images(image_sources(), html, pages), "images in docs/ that no page shows"


def test_no_myst_roles_on_github_pages():
    pages = {p.relative_to(ROOT).as_posix(): myst_roles(_read(p)) for p in github_pages()}
    found = {name: hits for name, hits in pages.items() if hits}
    assert not found, f"MyST roles that GitHub shows as raw text:\n{_report(found)}"
