"""The tools the CodeActionBench catalog names are served by the core (its tool list,
``cab_core.tools.CATALOG``), in the catalog's order, with the catalog's group and charging.

The core owns the tool list; this suite depends on the paper's tools, so a change to the
core's list that drops, renames, reorders or regroups one of them fails here. A tool the core adds
beyond the paper's is not refused: the suite's tasks and budgets use only the tools its catalog names.
"""
from __future__ import annotations

import pytest

from cab_core.tools import TOOLS
from cab_suite_codeaction import catalog

CATALOG_TOOLS = catalog.load_catalog()["tools"]
NAMES = [t["name"] for t in CATALOG_TOOLS]
GROUP = {"termination": "control"}  # the catalog's group name where the core's differs
# The catalog's robot actions, which consume simulated time (its budgets_rule): the motion group, and
# capture_motion_pair, the geometry tool that moves the wrist camera between its two images.
ACTS = {t["name"] for t in CATALOG_TOOLS if t["group"] == "motion"} | {"capture_motion_pair"}


def test_the_catalog_names_each_tool_once():
    assert NAMES and len(NAMES) == len(set(NAMES))


def test_every_catalog_tool_is_served_by_the_core_in_the_catalog_order():
    assert [n for n in NAMES if n not in TOOLS] == []
    assert [n for n in TOOLS if n in NAMES] == NAMES


def test_the_catalog_ends_with_the_host_tools_as_the_core_does():
    assert NAMES[-2:] == list(TOOLS)[-2:] == ["run_code", "done"]


@pytest.mark.parametrize("entry", CATALOG_TOOLS, ids=lambda e: e["name"])
def test_group_and_charging_follow_the_catalog(entry):
    t = TOOLS[entry["name"]]
    assert t.group == GROUP.get(entry["group"], entry["group"])
    assert t.advances_physics == (t.name in ACTS)
    assert t.charged == (t.name != "done")  # budgets_rule: every call costs one, done is free
    if t.name in ACTS:
        assert t.destructive and not t.read_only
    elif t.group in ("observation", "geometry"):
        assert t.read_only and not t.destructive
