"""The user pages, read as text (no build needed): how long a command takes is stated in one
place, the Performance page's table, and no user page cites a commit.

The table "How long things take" in ``docs/benchmarks.md`` gives each long command's time on two
cores. Anywhere else in the README or the docs, a passage (a paragraph, a list item, a table row
or a line of a code block) that names one of those commands and states a time must state one of
the table's figures for a command it names; the README links to the table instead of repeating
it. The development pages keep the dated record behind the table, and two pages are a run's
verbatim output with that run's own wall time; those are not checked.

Commit hashes belong to the history (the changelog and the development pages): a user page that
cites one (seven to forty hexadecimal digits, with a letter and a digit) fails.
"""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
PERFORMANCE = DOCS / "benchmarks.md"
TABLE_HEADING = "## How long things take"

# The commands whose time the table gives, and how a passage names each.
COMMANDS = {
    "loopid reproduce --quick": re.compile(r"reproduce --quick"),
    "loopid reproduce": re.compile(r"\breproduce\b(?! --quick)"),
    "make reproduce": re.compile(r"make reproduce"),
    "make test": re.compile(r"make test(?![-\w])"),
    "make test-fast": re.compile(r"\btest-fast\b"),
    "make test-science": re.compile(r"\btest-science\b"),
}

# Pages not checked for times: the record behind the table, and a run's verbatim output.
HISTORY = ("docs/development/", "docs/changelog.md", "CHANGELOG.md")
RUN_OUTPUT = {"docs/paper/report.md", "docs/study.md"}

UNIT = {"s": 1, "sec": 1, "second": 1, "seconds": 1, "min": 60, "minute": 60, "minutes": 60}
UNITS = r"(seconds?|sec|s|minutes?|min)\b"
NUMBER = r"(\d+(?:\.\d+)?)"
# "10 min 54 s", then "67-76 s" / "5 to 10 minutes", then "128 s".
COMPOUND = re.compile(r"\b(\d+)\s*min\s+(\d+)\s*s\b")
RANGE = re.compile(rf"\b{NUMBER}\s*(?:-|–|to)\s*{NUMBER}\s*{UNITS}")
SINGLE = re.compile(rf"\b{NUMBER}\s*{UNITS}")


def times(text: str) -> set[float]:
    """Every time a passage states, in seconds (a range gives both ends)."""
    found = set()
    for m in COMPOUND.finditer(text):
        found.add(float(m[1]) * 60 + float(m[2]))
    text = COMPOUND.sub(" ", text)
    for m in RANGE.finditer(text):
        found |= {float(m[1]) * UNIT[m[3]], float(m[2]) * UNIT[m[3]]}
    text = RANGE.sub(" ", text)
    for m in SINGLE.finditer(text):
        found.add(float(m[1]) * UNIT[m[2]])
    return found


def test_times_are_parsed():
    """The parser reads the forms the table uses, and ignores other units and counts."""
    assert times("10 min 54 s to 17 min 48 s") == {654.0, 1068.0}
    assert times("67-76 s") == {67.0, 76.0}
    assert times("about 5.5 min") == {330.0}
    assert times("5 to 10 minutes") == {300.0, 600.0}
    assert times("7-8 min") == {420.0, 480.0}
    assert times("171–220 µs, 45 ms, 20 seeds, 2 cores, 16-seed") == set()


def table() -> dict[str, set[float]]:
    """The Performance table: each command's stated times."""
    text = PERFORMANCE.read_text(encoding="utf-8")
    assert TABLE_HEADING in text, f"docs/benchmarks.md lost its section {TABLE_HEADING!r}"
    section = text.split(TABLE_HEADING, 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = times(line)
    return rows


def test_the_table_gives_every_command_a_time():
    rows = table()
    missing = [c for c in COMMANDS if not rows.get(c)]
    assert not missing, f"the Performance table gives no time for {missing}"


def passages(text: str) -> list[str]:
    """A page cut into passages: each line of a code block or table, each list item, and each
    other paragraph."""
    out, paragraph, fenced = [], [], False

    def flush():
        if paragraph:
            out.append(" ".join(paragraph))
            paragraph.clear()

    for line in text.splitlines():
        if line.startswith("```"):
            flush()
            fenced = not fenced
        elif fenced or line.lstrip().startswith("|"):
            out.append(line)
        elif not line.strip():
            flush()
        elif re.match(r"\s*([-*]|\d+\.)\s", line):
            flush()
            paragraph.append(line)
        else:
            paragraph.append(line)
    flush()
    return out


def user_pages() -> list[Path]:
    skip = {DOCS / "_build", DOCS / "_generated"}
    pages = [p for p in DOCS.rglob("*.md") if not any(s in p.parents for s in skip)]
    return [ROOT / "README.md", *sorted(pages)]


def stray_times(text: str, rows: dict[str, set[float]]) -> list[str]:
    """The passages of ``text`` that time a command with a figure the table does not give it."""
    bad = []
    for passage in passages(text):
        named = [c for c, pattern in COMMANDS.items() if pattern.search(passage)]
        stated = times(passage)
        if named and stated:
            allowed = set().union(*(rows[c] for c in named))
            if stated - allowed:
                bad.append(passage.strip()[:160])
    return bad


def test_time_figures_come_from_the_performance_table():
    rows = table()
    found = {}
    for path in user_pages():
        name = path.relative_to(ROOT).as_posix()
        if path == PERFORMANCE or name.startswith(HISTORY) or name in RUN_OUTPUT:
            continue
        if bad := stray_times(path.read_text(encoding="utf-8"), rows):
            found[name] = bad
    assert not found, (
        "times for the long commands that are not the Performance table's "
        f"(docs/benchmarks.md, {TABLE_HEADING!r}); link to it instead: {found}"
    )


@pytest.mark.parametrize(
    "text",
    [
        "make test        # the test suite (about 10 min on 2 cores)",
        "`make reproduce` runs it all. On two cores it takes about 6 minutes.",
        "| `loopid reproduce --quick` | 1-3 minutes |",
    ],
)
def test_a_stray_time_is_caught(text):
    """The check fails on the kinds of figure the README used to repeat."""
    assert stray_times(text, table())


def test_the_readme_links_to_the_table():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "docs/benchmarks.md#how-long-things-take" in readme


HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")


def test_no_commit_hashes_in_user_pages():
    found = {}
    for path in user_pages():
        name = path.relative_to(ROOT).as_posix()
        if name.startswith(HISTORY):
            continue
        lines = path.read_text(encoding="utf-8").splitlines()
        if hits := [
            f"{i}: {line.strip()[:100]}" for i, line in enumerate(lines, 1) if HASH.search(line)
        ]:
            found[name] = hits
    assert not found, f"user pages cite commits (history goes in the changelog): {found}"


def test_the_hash_pattern():
    assert HASH.search("at commit 1b6ec86, the same")
    assert HASH.search("a9fe6af")
    assert not HASH.search("cost_cap = 100000000.0, 2.355e+06, deadbeefcafe")
