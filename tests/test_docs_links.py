"""The README and the pages under docs/ link only to files and headings that exist, name only
files and modules of the repository that exist, and the README, the front door, links every page
of docs/ exactly once.

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


_REPO_PATH = re.compile(r"(?<![\w./-])((?:cab_core|plugins|tests|scripts|hydra_plugins|examples)/[\w./-]*\w)(?![\w<*])")
_MODULE = re.compile(r"(?<![\w./-])(cab_[a-z_]+(?:\.[A-Za-z_]\w*)+)")


def _packages() -> dict[str, Path]:
    """The top-level packages of the repository (the core, each plugin's, the examples'), by name."""
    found = {}
    for folder in [ROOT, *(p for p in ROOT.glob("plugins/*") if p.is_dir()), *ROOT.glob("examples/*")]:
        for p in folder.iterdir():
            if p.is_dir() and (p / "__init__.py").exists():
                found[p.name] = p
    return found


def _module_name_exists(dotted: str, packages: dict[str, Path]) -> bool:
    """Whether ``pkg.module[.name]`` is a module of the repository, or a name that module defines
    or imports (one name after the module is checked; what follows it is an attribute of it)."""
    parts = dotted.split(".")
    where = packages[parts[0]]
    rest = parts[1:]
    while rest and (where / rest[0]).is_dir():
        where = where / rest.pop(0)
    if rest and (where / f"{rest[0]}.py").is_file():
        where = where / f"{rest.pop(0)}.py"
    if not rest:
        return True
    source = (where / "__init__.py" if where.is_dir() else where).read_text(encoding="utf-8")
    name = re.escape(rest[0])
    return re.search(rf"^\s*(?:async\s+)?(?:def|class)\s+{name}\b|\b{name}\s*[:=]|\bimport\b.*\b{name}\b",
                     source, re.M) is not None


def missing_names(page: Path) -> list[str]:
    """The repository paths (``cab_core/...``, ``plugins/...``, ...) and modules of the repository
    (``cab_core.x.y``, ``cab_suite_codeaction.x``) that a page quotes in inline code and that do
    not exist. Paths with a placeholder (``<name>``, ``*``) are not checked."""
    packages = _packages()
    missing = []
    for line in page.read_text(encoding="utf-8").splitlines():
        for code in re.findall(r"`([^`]+)`", line):
            for path in _REPO_PATH.findall(code):
                if not (ROOT / path).exists():
                    missing.append(path)
            for dotted in _MODULE.findall(code):
                if dotted.split(".")[0] in packages and not _module_name_exists(dotted, packages):
                    missing.append(dotted)
    return missing


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_repository_path_and_module_a_page_quotes_exists(page):
    assert missing_names(page) == []


def test_a_quoted_path_or_module_that_moved_is_reported(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "`cab_core/geometry.py` `cab_core/no_such_module.py` `plugins/export_<name>`\n"
        "`cab_core.geometry` `cab_core.attempt.fork.ForkPoint` `cab_core.attempt.fork.no_such_name`\n"
        "`cab_core.no_such_module.thing` `python -m cab_core.sweep.worker`\n"
    )
    assert missing_names(page) == [
        "cab_core/no_such_module.py", "cab_core.attempt.fork.no_such_name", "cab_core.no_such_module.thing"]


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
