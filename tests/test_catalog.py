"""The suite's task catalog: identical to the shared spec, complete and well-formed; the core's
task lookups (``cab_core.plugins.task_info``/``task_names``) come from the installed suites."""
from __future__ import annotations

from pathlib import Path

import pytest

from cab_core import plugins
from cab_core.contracts.task import TaskInfo
from cab_core.errors import ConfigError
from cab_suite_codeaction import catalog
from cab_suite_codeaction.tasks import TASK_MODULES

SHARED = Path(__file__).resolve().parents[1].parent / "shared/spec/catalog.yaml"
PACKAGED = Path(catalog.__file__).resolve().parent / "data" / "catalog.yaml"


def test_packaged_copy_equals_shared_spec():
    if not SHARED.is_file():
        pytest.skip("the shared spec (../shared/spec/catalog.yaml beside the checkout) is not present")
    assert PACKAGED.read_bytes() == SHARED.read_bytes(), "cab_suite_codeaction/data/catalog.yaml drifted from shared/spec"


def test_the_catalog_names_each_task_module_once():
    names = catalog.task_names()
    assert len(names) == len(set(names))
    assert sorted(names) == sorted(TASK_MODULES)


@pytest.mark.parametrize("name", catalog.task_names())
def test_task_entry_well_formed(name):
    info = catalog.task_info(name)
    assert isinstance(info, TaskInfo)
    assert info.name == name
    assert info.instruction.strip()
    assert isinstance(info.seed, int) and info.seed >= 0
    assert info.scoring in {"final", "latch"}
    assert info.budget_tool_calls > 0 and info.budget_sim_s > 0
    assert info.budget_wall_s == 60 * info.budget_tool_calls
    assert info.category
    # the reference solution fits its own budgets (paper, "Reference solutions and budget feasibility")
    assert 0 < info.reference_solution_api_calls <= info.budget_tool_calls
    assert 0 < info.reference_solution_sim_s <= info.budget_sim_s
    assert len(info.subgoals) >= 1
    assert all({"name", "arm", "condition_cm", "prerequisite"} <= set(c) for c in info.spatial_checkpoints)


def test_counts_match_lists():
    for t in catalog.load_catalog()["tasks"]:
        assert t["subgoal_count"] == len(t["subgoals"]), t["name"]
        assert t["spatial_count"] == len(t["spatial_checkpoints"]), t["name"]


def test_sim_budget_rule_lower_bound():
    # B_sim = ceil_5s(max(60, 5 * expert_sim)): at least 60 s and a multiple of 5
    for name in catalog.task_names():
        b = catalog.task_info(name).budget_sim_s
        assert b >= 60 and b % 5 == 0, name


def test_known_entries_verbatim():
    info = catalog.task_info("open_microwave")
    assert info.instruction == "Use one arm to open the microwave door wide."
    assert (info.seed, info.scoring, info.budget_tool_calls, info.budget_sim_s) == (0, "final", 56, 140.0)
    hammer = catalog.task_info("beat_block_hammer")
    assert hammer.scoring == "latch" and hammer.budget_tool_calls == 42


def test_latch_tasks_are_the_four_event_tasks():
    latch = {n for n in catalog.task_names() if catalog.task_info(n).scoring == "latch"}
    assert latch == {"beat_block_hammer", "click_bell", "press_stapler", "dump_bin_bigbin"}


def test_unknown_task_lists_choices():
    with pytest.raises(ConfigError) as e:
        catalog.task_info("no_such_task")
    assert "choices" in str(e.value) and "open_microwave" in str(e.value)


def test_load_catalog_returns_a_copy():
    a = catalog.load_catalog()
    n = len(a["tasks"])
    a["tasks"].clear()
    assert len(catalog.load_catalog()["tasks"]) == n > 0


def test_core_lookups_come_from_the_installed_suite():
    assert sorted(plugins.task_names()) == sorted(catalog.task_names())
    assert all(plugins.task_info(n) == catalog.task_info(n) for n in catalog.task_names())


def test_core_lookup_of_an_unknown_task_is_one_line_with_the_choices():
    with pytest.raises(ConfigError) as e:
        plugins.task_info("block_on_pad")
    assert str(e.value) == f"unknown task 'block_on_pad'; choices: {', '.join(sorted(catalog.task_names()))}"


def test_the_core_names_no_catalog():
    import importlib.util

    assert importlib.util.find_spec("cab_core.catalog") is None
