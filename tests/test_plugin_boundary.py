"""The public surface a plugin builds on (docs/plugins.md, issue 27): every module under `plugins/`
and `examples/` (a plugin's own tests, `plugins/*/tests/`, aside) imports of `cab_core` only the
contracts, the kits, `errors` and `geometry`, and nothing outside the CodeActionBench suite imports
the suite. The imports are read from the source (ast), those inside functions included."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

try:
    import tomllib
except ImportError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

ROOT = Path(__file__).resolve().parents[1]

#: what a plugin may import of cab_core: these modules and the modules under them
PUBLIC = ("cab_core.contracts", "cab_core.kits", "cab_core.errors", "cab_core.geometry")
SUITE = "cab_suite_codeaction"
SUITE_DIR = "plugins/suite_codeaction"

#: imports outside the public surface that the contracts and the kits cannot give yet, each entry
#: saying what it uses and why (issue 27): {file: {module or package, ...}} (a package allows what
#: is under it, so that its own moves inside the engine need no edit here)
IN_PROGRESS: dict[str, set[str]] = {}  # none left: the harnesses ask the kits (kits.harness.catalog, kits.registry)

#: other known imports outside the public surface: {file: {module, ...}}. None is left: the entry
#: modules that imported the package root for ``@cab_core.hookimpl`` now write
#: ``from cab_core.contracts.hookspecs import hookimpl``. An entry added here and no longer needed
#: fails ``test_the_allow_list_names_only_what_is_still_imported``
ALLOWED: dict[str, set[str]] = {
    # inspect_cab (issue 29) is a reader of cab's records and a launcher of its attempts, as cab-report
    # and the sweep are: it reads result.json and the failure stage as cab-report does, names attempt
    # folders in the sweep's layout, and lists the installed suites and their seed sets
    "plugins/inspect_cab/inspect_cab/attempt.py": {"cab_core.analysis.attempts", "cab_core.attempt.records.result_format"},
    "plugins/inspect_cab/inspect_cab/scoring.py": {"cab_core.analysis.attempts", "cab_core.analysis.failure",
                                                   "cab_core.analysis.measures"},
    "plugins/inspect_cab/inspect_cab/task.py": {"cab_core.config", "cab_core.plugins", "cab_core.sweep.layout"},
    # the reference agent names its model configuration as a folder, as the sweep's layout does
    "plugins/inspect_cab/inspect_cab/reference.py": {"cab_core.sweep.layout"},
}


def under(module: str, packages: set[str]) -> bool:
    """Whether ``module`` is one of ``packages`` or under one of them."""
    return any(module == p or module.startswith(p + ".") for p in packages)


def plugin_sources() -> list[Path]:
    """Every .py of a plugin or an example, relative to the root, without the plugins' own tests,
    the test configuration beside them (``plugins/conftest.py``), build folders and installed
    metadata."""
    out = []
    for top in ("plugins", "examples"):
        for p in sorted((ROOT / top).rglob("*.py")):
            rel = p.relative_to(ROOT)
            if top == "plugins" and (len(rel.parts) == 2 or rel.parts[2] == "tests"):
                continue
            if any(part == "build" or part.endswith(".egg-info") for part in rel.parts):
                continue
            out.append(rel)
    return out


def imported_modules(source: str) -> set[str]:
    """The absolute modules ``source`` imports (``from cab_core import x`` counts as ``cab_core.x``,
    ``import cab_core`` as ``cab_core``), at any depth."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module in ("cab_core", SUITE):
                out.update(f"{node.module}.{a.name}" for a in node.names)
            else:
                out.add(node.module)
    return out


def offences(rel: Path, modules: set[str]) -> set[str]:
    """The modules of ``modules`` that the file ``rel`` may not import."""
    bad = set()
    for m in modules:
        if under(m, {"cab_core"}) and not under(m, set(PUBLIC)):
            bad.add(m)
        if under(m, {SUITE}) and not rel.as_posix().startswith(SUITE_DIR + "/"):
            bad.add(m)
    return bad


def test_the_sources_are_found():
    files = {p.as_posix() for p in plugin_sources()}
    assert "examples/block_on_pad/cab_example_block_on_pad/task.py" in files
    assert "plugins/suite_codeaction/cab_suite_codeaction/tasks/click_bell.py" in files
    assert not any("/tests/" in f for f in files if f.startswith("plugins/"))


@pytest.mark.parametrize("rel", plugin_sources(), ids=lambda p: p.as_posix())
def test_a_plugin_imports_only_the_public_surface(rel: Path):
    file = rel.as_posix()
    bad = offences(rel, imported_modules((ROOT / rel).read_text(encoding="utf-8")))
    bad = {m for m in bad if m not in ALLOWED.get(file, set()) and not under(m, IN_PROGRESS.get(file, set()))}
    assert not bad, (f"{rel} imports {', '.join(sorted(bad))}: a plugin imports of cab_core only "
                     f"{', '.join(PUBLIC)} (docs/plugins.md), and {SUITE} only within {SUITE_DIR}")


def test_the_allow_list_names_only_what_is_still_imported():
    """An entry of ``ALLOWED`` whose import is gone is taken out of the list, so that it shrinks."""
    stale = {}
    for file, allowed in ALLOWED.items():
        path = ROOT / file
        now = offences(Path(file), imported_modules(path.read_text(encoding="utf-8"))) if path.is_file() else set()
        if allowed - now:
            stale[file] = sorted(allowed - now)
    assert stale == {}


def test_the_checks_catch_what_they_are_for():
    src = ("import cab_core\nfrom cab_core import kits, plugins\nfrom cab_core.attempt.fork import ForkPoint\n"
           "from cab_core.kits.scene import base_scene\nfrom cab_core.geometry import quat_mul\n"
           "def f():\n    from cab_suite_codeaction.common import CodeActionTask\n")
    mods = imported_modules(src)
    assert offences(Path("examples/x/x/task.py"), mods) == {
        "cab_core", "cab_core.plugins", "cab_core.attempt.fork", "cab_suite_codeaction.common"}
    assert offences(Path("plugins/suite_codeaction/cab_suite_codeaction/x.py"), mods) == {
        "cab_core", "cab_core.plugins", "cab_core.attempt.fork"}


def test_the_example_plugin_needs_no_other_plugin():
    """A third-party task needs cab alone: the example declares no dependency on a plugin of this tree."""
    meta = tomllib.loads((ROOT / "examples/block_on_pad/pyproject.toml").read_text(encoding="utf-8"))
    names = {d.split(";")[0].split("[")[0].strip().split("<")[0].split(">")[0].split("=")[0].strip().lower()
             for d in meta["project"]["dependencies"]}
    plugins = {tomllib.loads(p.read_text(encoding="utf-8"))["project"]["name"].lower()
               for p in (ROOT / "plugins").glob("*/pyproject.toml")}
    assert "cab" in names and not names & plugins
