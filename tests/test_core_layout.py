"""The house a newcomer meets: ``cab_core`` in wings, measured on its import graph.

The graph is grimp's (the library behind import-linter): every import of one ``cab_core`` module by
another, at module level or inside a function, and the imports under ``if TYPE_CHECKING:`` too (a
type a module names is a dependency a reader follows, even though it never runs). On it:

* no import loop anywhere;
* the wings are layered: a module imports only from its own wing or the wings below it
  (:data:`WINGS`, top to bottom), never back up;
* every module is in a wing.

The levels are counted on the imports Python executes (type-only imports left out): a module that
imports no other ``cab_core`` module is on level 1, any other on one more than the highest module it
imports; at most 7. Counted with the type-only imports as well, the chain is longer (13 on
2026-11-27) only because the contracts name one another's types for the type checker
(``contracts.task -> verifier -> simulator -> embodiment -> scene``), which costs no start-up time
and forms no loop.
"""
from __future__ import annotations

import graphlib

import pytest

grimp = pytest.importorskip("grimp")

PACKAGE = "cab_core"
MAX_LEVELS = 7
#: the task kit's modules, named one by one: the package ``cab_core.kits`` also holds the harness kit,
#: which sits higher (a wing names a package with everything below it)
TASK_KIT = ("cab_core.kits.assets", "cab_core.kits.jsonfiles", "cab_core.kits.margins", "cab_core.kits.oracle",
            "cab_core.kits.scene", "cab_core.kits.stages", "cab_core.kits.task")
#: packages with no code of their own (a docstring), in no wing
NO_CODE = {"cab_core.kits"}
# top to bottom; wings on one line are siblings (they may import each other)
WINGS = (
    ("cab_core.apps", "cab_core.testing"),  # the command-line programs; the conformance suites
    ("cab_core.analysis",),  # reports, the viewer, measures over records
    ("cab_core.sweep",),  # many attempts: manifest, layout, supervisor, child
    ("cab_core.attempt",),  # one attempt: spec, world, serving, finishing, records
    # the harness kit and the registry's kit: what a harness (or any plugin) asks of the engine's tool
    # catalog and plugin registry, below the engine that imports the harness kit, above what it asks
    ("cab_core.kits.harness", "cab_core.kits.registry"),
    ("cab_core.tools", "cab_core.sandbox"),  # the tools the agent calls; the confined run_code
    ("cab_core.config", "cab_core.conf", "cab_core.plugins"),  # Hydra configuration; the plugin registry
    TASK_KIT,  # what plugin authors build tasks and oracles with
    ("cab_core.contracts",),  # what plugins implement and tasks are written with
    ("cab_core.errors", "cab_core.geometry", "cab_core.numerics"),  # errors, pose and camera math, numerics
)


# cache_dir=None everywhere: grimp's cache goes by the files' modification times, and the installed
# package is a tree of links (scripts/install.sh) whose times do not change when a file is edited, so a
# cached graph can describe code that is gone


@pytest.fixture(scope="module")
def graph():
    """Every import, type-only ones included."""
    return grimp.build_graph(PACKAGE, exclude_type_checking_imports=False, cache_dir=None)


@pytest.fixture(scope="module")
def run_graph():
    """The imports Python executes (type-only ones left out): what the levels count."""
    return grimp.build_graph(PACKAGE, exclude_type_checking_imports=True, cache_dir=None)


def _imports(graph) -> dict[str, set[str]]:
    """Module -> the cab_core modules it imports (a package's own ``__init__`` imports included)."""
    return {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}


def levels(graph) -> dict[str, int]:
    order = graphlib.TopologicalSorter(_imports(graph)).static_order()  # imported before importer
    imp, lv = _imports(graph), {}
    for m in order:
        lv[m] = 1 + max((lv[t] for t in imp.get(m, ())), default=0)
    return lv


def longest_chain(graph, lv: dict[str, int]) -> list[str]:
    imp = _imports(graph)
    m = max(lv, key=lambda k: (lv[k], k))
    chain = [m]
    while lv[m] > 1:
        m = max((t for t in imp[m]), key=lambda t: (lv[t], t))
        chain.append(m)
    return chain


def test_no_import_loop(graph):
    try:
        graphlib.TopologicalSorter(_imports(graph)).prepare()
    except graphlib.CycleError as e:
        pytest.fail(f"import loop: {' -> '.join(e.args[1])}")


def test_no_import_loop_in_any_package_of_the_tree(monkeypatch):
    """The plugins of this repository too (each package on its own graph; cab_core's own is above).
    A plugin the set-up does not install (planner_mplib: numpy<2 only) is read from its folder."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    packages = {p.name: p.parent for p in (root / "plugins").glob("*/cab_*") if (p / "__init__.py").is_file()}
    names = sorted(set(packages) | {"hydra_plugins", "cab_conf"})
    for n in names:
        if importlib.util.find_spec(n) is None and n in packages:
            monkeypatch.syspath_prepend(str(packages[n]))  # grimp reads the source; nothing is imported
    missing = [n for n in names if importlib.util.find_spec(n) is None]
    assert not missing, f"not found: {missing}"
    assert len(names) >= 10
    for name in names:
        g = grimp.build_graph(name, exclude_type_checking_imports=False, cache_dir=None)
        ours = "hydra_plugins.cab_searchpath" if name == "hydra_plugins" else name  # a namespace shared with others
        imports = {m: {t for t in ts if t.startswith(ours)} for m, ts in _imports(g).items() if m.startswith(ours)}
        try:
            graphlib.TopologicalSorter(imports).prepare()
        except graphlib.CycleError as e:
            pytest.fail(f"import loop in {name}: {' -> '.join(e.args[1])}")


def test_at_most_seven_levels(run_graph):
    lv = levels(run_graph)
    chain = longest_chain(run_graph, lv)
    assert max(lv.values()) <= MAX_LEVELS, f"{max(lv.values())} levels: {' -> '.join(chain)}"
    assert len(run_graph.modules) > 60  # the whole core was measured


def test_no_arrow_back_up(graph):
    layers = [grimp.Layer(*w, independent=False) for w in WINGS]
    bad = graph.find_illegal_dependencies_for_layers(layers=layers)
    lines = [f"{d.importer} imports {d.imported}: "
             + "; ".join(" -> ".join([*sorted(r.heads), *r.middle, *sorted(r.tails)]) for r in d.routes) for d in bad]
    assert not lines, "\n".join(lines)


def test_every_module_is_in_a_wing(graph):
    wings = {w for layer in WINGS for w in layer}
    outside = sorted(m for m in graph.modules
                     if m != PACKAGE and m not in NO_CODE and not any(m == w or m.startswith(w + ".") for w in wings))
    assert not outside, f"modules in no wing of LAYERS: {outside}"
