"""The README and the pages under docs/ link only to files and headings that exist, and the README,
the front door, links every page of docs/ exactly once.

Links are read as GitHub renders Markdown: inline links and images (``[text](target)``,
``![alt](target)``) and reference definitions (``[name]: target``), outside fenced code blocks and
inline code. A target with a scheme (``https:``, ``mailto:``) is not checked. An anchor
(``page.md#heading``) must be the slug GitHub gives one of the target page's headings."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]

_FENCE = re.compile(r"^\s*(```|~~~)")
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
_INLINE = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$")
_HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
_SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def _prose_lines(text: str) -> list[str]:
    """The lines of a Markdown text outside fenced code blocks, inline code removed."""
    lines, fenced = [], False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            lines.append(_CODE_SPAN.sub("", line))
    return lines


def links(page: Path) -> list[str]:
    """Every link target of a page, in order, as written."""
    found = []
    for line in _prose_lines(page.read_text(encoding="utf-8")):
        found += _INLINE.findall(line)
        ref = _REFERENCE.match(line)
        if ref:
            found.append(ref.group(1))
    return found


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text without Markdown marks, lower case, punctuation
    other than ``-`` and ``_`` removed, spaces turned into ``-``."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link keeps its text
    text = text.replace("`", "").replace("*", "")
    text = re.sub(r"[^\w\- ]", "", text.lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The anchors of a page's headings, numbered as GitHub numbers repeated ones (``-1``, ...)."""
    seen: dict[str, int] = {}
    out = set()
    for line in _prose_lines(page.read_text(encoding="utf-8")):
        m = _HEADING.match(line)
        if not m:
            continue
        base = slug(m.group(2))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken_links(page: Path) -> list[str]:
    """The relative links of a page whose file or heading does not exist, with the reason."""
    broken = []
    for target in links(page):
        if _SCHEME.match(target):
            continue
        path_part, _, anchor = target.partition("#")
        dest = (page.parent / path_part).resolve() if path_part else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif anchor and dest.is_file() and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target}: no heading with that anchor")
    return broken


def test_the_pages_are_found():
    names = {p.relative_to(ROOT).as_posix() for p in PAGES}
    assert {"README.md", "docs/reference.md", "docs/architecture.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_points_at_an_existing_file_and_heading(page):
    assert broken_links(page) == []


def test_the_readme_links_every_docs_page_exactly_once():
    readme = ROOT / "README.md"
    counts: dict[str, int] = {}
    for target in links(readme):
        path_part = target.partition("#")[0]
        if _SCHEME.match(target) or not path_part:
            continue
        dest = (ROOT / path_part).resolve()
        if dest.suffix == ".md" and DOCS in dest.parents:
            key = dest.relative_to(ROOT).as_posix()
            counts[key] = counts.get(key, 0) + 1
    pages = {p.relative_to(ROOT).as_posix() for p in DOCS.glob("*.md")}
    pages |= {p.relative_to(ROOT).as_posix() for p in DOCS.glob("*/README.md")}
    assert {page: counts.get(page, 0) for page in sorted(pages)} == {page: 1 for page in sorted(pages)}


def test_slugs_follow_githubs_rule():
    assert slug("The API (`cab-bench`)") == "the-api-cab-bench"
    assert slug("Sweeps: on one machine, on Ray, on SLURM") == "sweeps-on-one-machine-on-ray-on-slurm"
    assert slug("SLURM (copy, adapt the marked values, paste)") == "slurm-copy-adapt-the-marked-values-paste"
    assert slug("Paired comparison of two configurations (`--compare A B`)") == (
        "paired-comparison-of-two-configurations---compare-a-b")
    assert slug("Where SAPIEN's start-up went") == "where-sapiens-start-up-went"


def test_a_link_to_a_missing_file_or_heading_is_reported(tmp_path):
    (tmp_path / "other.md").write_text("# A heading\n\n## A heading\n")
    page = tmp_path / "page.md"
    page.write_text(
        "[ok](other.md) [ok](other.md#a-heading) [ok](other.md#a-heading-1) [ok](#here)\n"
        "# Here\n"
        "[gone](missing.md) [bad anchor](other.md#nowhere) [web](https://example.org/x.md)\n"
        "`[in code](missing-too.md)`\n"
        "```\n[in a fence](missing-three.md)\n```\n"
        "[ref]: missing-four.md\n"
    )
    assert broken_links(page) == [
        "missing.md: no such file",
        "other.md#nowhere: no heading with that anchor",
        "missing-four.md: no such file",
    ]
