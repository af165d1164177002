"""README.md and docs/: every relative link and anchor resolves, every table has one column count.

The README is the user's way in and docs/ holds the sessions' evidence it links to; a moved section
or a renamed heading must not leave a dead link, and a table whose rows split into different cell
counts (an unescaped ``|``, also inside a code span, splits a GFM cell) does not render as a table.
"""

import re
import unicodedata
from pathlib import Path

import pytest

from .conftest import ROOT

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^\s*(```|~~~)")
LINK = re.compile(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
CODE_SPAN = re.compile(r"(`+)(.+?)\1")


def _prose_lines(text):
    """(line number, line) outside fenced code blocks."""
    fenced = False
    for n, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield n, line


def slug(heading):
    """GitHub's anchor of a heading's text (github-slugger: lower case, punctuation dropped, spaces to -)."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)        # a link's text
    text = text.replace("`", "").replace("*", "")
    text = "".join(c for c in text.lower()
                   if c in " -_" or unicodedata.category(c)[0] in "LN")
    return text.replace(" ", "-")


def anchors(path):
    """Every heading's anchor in a Markdown file, repeated headings numbered -1, -2 as GitHub does."""
    seen, out = {}, set()
    for _, line in _prose_lines(path.read_text(encoding="utf-8")):
        m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        base = slug(m.group(2))
        k = seen.get(base, 0)
        seen[base] = k + 1
        out.add(base if k == 0 else f"{base}-{k}")
    return out


def _cells(row):
    """Cell count of a GFM table row: split on every unescaped pipe (code spans do not protect one)."""
    body = row.strip()
    body = body[1:] if body.startswith("|") else body
    body = body[:-1] if body.endswith("|") and not body.endswith("\\|") else body
    return len(re.split(r"(?<!\\)\|", body))


def test_the_slug_is_githubs():
    # github-slugger's rules: lower case, punctuation (apostrophes, commas, backticks) dropped, spaces to -
    assert slug("Calibration (`workbench calibrate`)") == "calibration-workbench-calibrate"
    assert slug("Session 31, the other sensor's lag at a bar") == "session-31-the-other-sensors-lag-at-a-bar"
    assert slug("Issue 17, reliability and speed") == "issue-17-reliability-and-speed"
    assert slug("MIMO export, nonlinear verification and the commands") == \
        "mimo-export-nonlinear-verification-and-the-commands"


@pytest.mark.parametrize("path", DOCS, ids=[str(p.relative_to(ROOT)) for p in DOCS])
def test_every_relative_link_and_anchor_resolves(path):
    dead = []
    for n, line in _prose_lines(path.read_text(encoding="utf-8")):
        for target in LINK.findall(CODE_SPAN.sub("", line)):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):      # http:, https:, mailto:
                continue
            file_part, _, anchor = target.partition("#")
            dest = (path.parent / file_part).resolve() if file_part else path
            if not dest.exists():
                dead.append(f"{path.name}:{n}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                dead.append(f"{path.name}:{n}: {target} (no such heading)")
    assert not dead, "\n".join(dead)


@pytest.mark.parametrize("path", DOCS, ids=[str(p.relative_to(ROOT)) for p in DOCS])
def test_every_table_has_one_column_count(path):
    bad, table = [], []
    for n, line in [*_prose_lines(path.read_text(encoding="utf-8")), (None, "")]:
        if line.lstrip().startswith("|"):
            table.append((n, line))
            continue
        if len(table) >= 2 and re.match(r"^\s*\|?\s*:?-{3,}", table[1][1]):
            want = _cells(table[0][1])
            bad += [f"{path.name}:{m}: {_cells(row)} cells, header {want}"
                    for m, row in table[1:] if _cells(row) != want]
        table = []
    assert not bad, "\n".join(bad)


def test_the_readme_is_a_readable_size_and_links_its_evidence():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.encode()) <= 100_000
    for doc in ("docs/physics.md", "docs/history/floors.md", "docs/history/calibration.md"):
        assert f"]({doc}" in readme, doc
