"""cab's conformance suites as a pytest plugin (entry point ``pytest11: cab`` of the core
distribution, so it is active wherever cab is installed; it adds nothing unless asked).

``pytest --cab-conformance`` adds to the run, parametrised over what is installed (the plugin
registry, :mod:`cab_core.plugins`):

* group ``sims``: every simulator x every check of :mod:`cab_core.testing.sim_conformance`
  (``test_simulator[<sim>-<check>]``, on a rendering build; without a renderer on a physics-only
  build, the checks that need pictures skipped with the diagnosis), and every simulator x every
  check that needs no pictures on a physics-only build (``test_simulator_physics_only[...]``),
  and every simulator builds one world with and without rendering that steps bit for bit alike
  (``test_simulator_render_independent[<sim>]``);
* group ``tasks``: every task x every simulator: at the task's catalog seed the oracle succeeds
  within its budgets and attains its subgoals, the idle agent fails, both record consistent
  margins (``test_task[<task>-<sim>]``, :mod:`cab_core.testing.task_conformance`). The attempts of
  all selected items run in one batch, ``--cab-jobs`` at a time in warm workers, when the first one
  runs;
* group ``determinism``: every task x every simulator, on the task's world at its catalog seed set
  up as an attempt sets it up: two builds in one process give identical privileged snapshots after
  settling and after the same arm motion, and a saved state restores exactly and replays the motion
  (``test_task_determinism[<task>-<sim>]``, about a second each, in this process).

Options: ``--cab-conformance[=GROUPS]`` (comma-separated: ``sims``, ``tasks``, ``determinism``;
``all`` is every group; the bare option is every group, or with ``--cab-tasks`` the groups over
tasks only, ``tasks`` and ``determinism``), ``--cab-sims=A,B`` and ``--cab-tasks=X,Y`` (restrict to these; default: every installed
one; an unknown name is a usage error listing the installed ones), ``--cab-jobs=N`` (parallel
attempts of the task checks; default: the number of cores). The items carry the marker
``cab_conformance``; ``-k`` selects among them as usual.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from cab_core.plugins import all_tasks, registry
from cab_core.testing.selection import GROUPS, NODE, SELECTION, Selection, selection  # noqa: F401

#: the bare ``--cab-conformance`` (no ``=GROUPS``): every group, or the task groups with ``--cab-tasks``
BARE = "(default)"
#: the groups whose items are parametrised over tasks: what the bare option runs with ``--cab-tasks``
TASK_GROUPS = ("tasks", "determinism")


def pytest_addoption(parser: pytest.Parser) -> None:
    g = parser.getgroup("cab", "cab conformance suites (cab_core.testing)")
    g.addoption("--cab-conformance", nargs="?", const=BARE, default=None, metavar="GROUPS",
                help="add cab's conformance checks over the installed plugins: sims, tasks, determinism "
                     "or all (comma-separated; bare: all, or with --cab-tasks the task groups "
                     f"{', '.join(TASK_GROUPS)})")
    g.addoption("--cab-sims", default=None, metavar="A,B",
                help="only these simulators (default: every installed one)")
    g.addoption("--cab-tasks", default=None, metavar="X,Y",
                help="only these tasks (default: every installed one)")
    g.addoption("--cab-jobs", type=int, default=None, metavar="N",
                help="parallel attempts of the task checks (default: the number of cores)")


def _names(value: str | None) -> list[str] | None:
    return None if value is None else [v.strip() for v in value.split(",") if v.strip()]


def _restrict(kind: str, option: str, wanted: list[str] | None, installed: list[str]) -> tuple[str, ...]:
    if wanted is None:
        return tuple(installed)
    unknown = [w for w in wanted if w not in installed]
    if unknown or not wanted:
        raise pytest.UsageError(f"{option}: unknown {kind} {', '.join(unknown) or '(none given)'}; "
                                f"installed: {', '.join(installed) or '(none)'}")
    return tuple(wanted)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "cab_conformance: a check of cab's conformance suites (--cab-conformance)")
    value = config.getoption("cab_conformance")
    if value is None:
        for opt in ("cab_sims", "cab_tasks", "cab_jobs"):
            if config.getoption(opt) is not None:
                raise pytest.UsageError(f"--{opt.replace('_', '-')} needs --cab-conformance")
        return
    if value == BARE:  # naming tasks asks about those tasks: not every simulator check as well
        value = ",".join(TASK_GROUPS) if config.getoption("cab_tasks") is not None else "all"
    groups = _names(value) or []
    unknown = [g for g in groups if g not in (*GROUPS, "all")]
    if unknown or not groups:
        raise pytest.UsageError(
            f"--cab-conformance: unknown group {', '.join(unknown) or '(none given)'}; groups: "
            f"{', '.join(GROUPS)}, all (write --cab-conformance=GROUPS: a word after it is read as its value)")
    chosen = GROUPS if "all" in groups else tuple(g for g in GROUPS if g in groups)
    jobs = config.getoption("cab_jobs")
    if jobs is not None and jobs < 1:
        raise pytest.UsageError(f"--cab-jobs must be at least 1, got {jobs}")
    sims = _restrict("simulator", "--cab-sims", _names(config.getoption("cab_sims")), list(registry("simulators")))
    tasks: tuple[str, ...] = ()
    if {"tasks", "determinism"} & set(chosen) or config.getoption("cab_tasks") is not None:
        tasks = _restrict("task", "--cab-tasks", _names(config.getoption("cab_tasks")), list(all_tasks()))
    config.stash[SELECTION] = Selection(chosen, sims, tasks, jobs or os.cpu_count() or 1)


def pytest_report_header(config: pytest.Config) -> list[str] | None:
    sel = selection(config)
    if sel is None:
        return None
    return [f"cab conformance: {', '.join(sel.groups)}; simulators: {', '.join(sel.sims) or '(none)'}"
            + (f"; tasks: {len(sel.tasks)}" if sel.tasks else "")]


def _suite_module():
    """The module of the conformance checks, imported on first use: it imports the simulator and task
    checks (4-7 s measured with python -X importtime), which only a run with --cab-conformance needs."""
    from cab_core.testing import conformance_suite

    return conformance_suite


class _Suite(pytest.Module):
    """The plugin's own test module, imported by name (not from its path), under node id
    ``cab-conformance``."""

    def _getobj(self):
        return _suite_module()

    def collect(self):
        sel = selection(self.config)
        assert sel is not None, "the suite is collected only with --cab-conformance"
        groups = sel.groups
        return [n for n in super().collect() if _GROUP_OF.get(getattr(n, "originalname", ""), "") in groups]


# test functions of the suite module by group
_GROUP_OF = {"test_simulator": "sims", "test_simulator_physics_only": "sims",
             "test_simulator_render_independent": "sims", "test_task": "tasks",
             "test_task_determinism": "determinism"}


@pytest.hookimpl(tryfirst=True)  # before -k / -m deselect among the items
def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    sel = selection(config)
    if sel is None:
        return
    suite = _Suite.from_parent(session, path=Path(_suite_module().__file__), nodeid=NODE)
    for item in session.genitems(suite):
        item.add_marker("cab_conformance")
        items.append(item)
