"""Hydra configs composed without running the app."""
import pytest
from hydra import compose, initialize_config_module
from hydra.errors import MissingConfigException

from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.runner import attempt_spec
from cab_core.errors import ConfigError
from cab_suite_codeaction.catalog import load_catalog


def _compose(overrides):
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        return compose(config_name="config", overrides=normalise_overrides(overrides))


def test_bare_defaults(tmp_path):
    cfg = _compose([])
    assert (cfg.sim.name, cfg.model.name, cfg.task.name) == ("sapien", "oracle", "beat_block_hammer")
    spec = attempt_spec(cfg, tmp_path)
    assert spec.harness == "direct"
    assert (spec.seed, spec.budget_tool_calls, spec.budget_sim_seconds, spec.budget_wall_seconds) == (0, 42, 60, 2520)


@pytest.mark.parametrize("plus", [True, False])
def test_plus_and_plain_group_overrides_both_work(plus, tmp_path):
    p = "+" if plus else ""
    cfg = _compose([f"{p}sim=sapien", f"{p}model=idle", f"{p}task=stack_blocks_three"])
    spec = attempt_spec(cfg, tmp_path)
    assert (spec.sim, spec.model, spec.task) == ("sapien", "idle", "stack_blocks_three")
    assert (spec.budget_tool_calls, spec.budget_sim_seconds) == (70, 130)


def test_unknown_option_lists_choices():
    with pytest.raises(MissingConfigException) as e:
        _compose(["model=nonexistent"])
    assert "oracle" in str(e.value) and "idle" in str(e.value)


def test_normalise_keeps_other_plus_overrides():
    assert normalise_overrides(["+sim=sapien", "+foo=1", "++bar=2", "task=x"]) == ["sim=sapien", "+foo=1", "++bar=2", "task=x"]


def test_seed_and_budget_overrides(tmp_path):
    spec = attempt_spec(_compose(["seed=7", "budget.tool_calls=5", "attempt=3"]), tmp_path)
    assert (spec.seed, spec.budget_tool_calls, spec.attempt) == (7, 5, 3)


@pytest.mark.parametrize("key", ["tool_calls", "sim_seconds", "wall_seconds", "run_code_max_internal_calls"])
def test_zero_budget_is_refused_never_the_catalogs(key, tmp_path):
    with pytest.raises(ConfigError, match=f"budget.{key} must be a positive .* got 0$"):
        attempt_spec(_compose([f"budget.{key}=0"]), tmp_path)
    spec = attempt_spec(_compose([f"budget.{key}=null"]), tmp_path)  # null: the catalog's (500 internal calls)
    assert (spec.budget_tool_calls, spec.budget_sim_seconds, spec.run_code_max_internal_calls) == (42, 60, 500)


def test_unknown_budget_key_added_with_plus_is_refused(tmp_path):
    with pytest.raises(ConfigError) as e:
        attempt_spec(_compose(["+budget.tool_calsl=5"]), tmp_path)
    assert str(e.value) == ("unknown key 'budget.tool_calsl'; did you mean budget.tool_calls? valid keys under budget: "
                            "tool_calls, sim_seconds, wall_seconds, run_code_max_internal_calls, cost_usd")


def test_bad_seed_is_a_typed_error(tmp_path):
    with pytest.raises(ConfigError, match="seed"):
        attempt_spec(_compose(["seed=-1"]), tmp_path)


def test_every_catalog_task_has_a_task_option():
    for t in load_catalog()["tasks"]:
        assert _compose([f"task={t['name']}"]).task.name == t["name"]
