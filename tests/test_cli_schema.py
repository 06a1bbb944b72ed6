"""The schema of cab's own keys (cab_core/conf/schema.py): registered in Hydra's ConfigStore, in
agreement with the core's settings (cab_core/conf/cab.yaml), and strict about types although
OmegaConf converts some values (the composed configuration keeps them as given)."""
import pytest
import yaml
from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

import cab_core.conf
from cab_core.apps.cmdline import check_command_line
from cab_core.conf.schema import OWN_KEYS, SCHEMA_NAME, CabConfig, check_basics, checked_view
from cab_core.errors import ConfigError


def core_settings() -> dict:
    from pathlib import Path

    with open(Path(cab_core.conf.__file__).parent / "cab.yaml") as f:
        return {k: v for k, v in yaml.safe_load(f).items() if k not in ("defaults", "hydra")}


def test_the_schema_is_in_hydras_config_store():
    node = ConfigStore.instance().load(f"{SCHEMA_NAME}.yaml").node
    assert OmegaConf.get_type(node) is CabConfig
    assert list(node) == list(OWN_KEYS) == ["seed", "seed_set", "attempt", "budget", "sandbox", "record", "perturb",
                                            "fork", "sweep"]


def test_the_schema_declares_the_core_settings_keys_and_defaults():
    """Every key of cab.yaml is in the schema with the yaml's value as its default (fork.from, a
    Python keyword, is the one key the view adds), and the schema declares no other key."""
    settings = core_settings()
    assert list(settings) == list(OWN_KEYS)
    typed = OmegaConf.to_container(checked_view({}), resolve=False)
    typed["sandbox"]["mode"] = typed["sandbox"]["mode"].value
    typed["fork"]["planner"] = typed["fork"]["planner"].value
    assert typed == settings


@pytest.mark.parametrize("override, line", [
    ("record.video=yes", "record.video must be true or false, got 'yes'"),
    ("record.video=1", "record.video must be true or false, got 1"),
    ("seed='5'", "seed must be a non-negative integer, or null (the task's fixed seed), got '5'"),
    ("sandbox.timeout_s='30'", "sandbox.timeout_s must be a positive number of seconds (wall clock per run_code "
                               "program), got '30'"),
    ("attempt=2.0", "attempt must be a positive integer (1, 2, ...: the repetition of the attempt), got 2.0"),
    ("sandbox={mode:bogus}", "sandbox.mode must be one of required, auto, off, got 'bogus'"),
    ("sweep.warm_workers=maybe", "sweep.warm_workers must be true or false, got 'maybe'"),
    ("sweep.hang_timeout_s=0", "sweep.hang_timeout_s must be a positive number of seconds, got 0"),
    ("perturb.position_m=abc", "perturb.position_m must be a number of metres, got 'abc'"),
    ("+foo.bar=1", "unknown key 'foo'; valid top-level keys: seed, seed_set, attempt, budget, sandbox, record, perturb, "
                   "fork, sweep, embodiment, experiment, harness, model, planner, randomize, sim, task"),
])
def test_values_omegaconf_would_convert_or_the_schema_refuses(override, line):
    with pytest.raises(ConfigError) as e:
        check_command_line([override])
    assert str(e.value) == line


@pytest.mark.parametrize("overrides", [
    ["sandbox.timeout_s=30", "sweep.hang_timeout_s=60.5", "perturb.seed=3", "perturb.position_m=0.002"],
    ["sandbox={mode:off,timeout_s:30}", "budget={tool_calls:5}", "fork.from=null", "seed_set=null"],
    ["experiment=paper"],
    ["experiment=smoke"],
])
def test_values_of_the_declared_types_pass(overrides):
    check_command_line(overrides)


def test_a_yaml_value_of_another_type_is_refused_when_the_attempt_is_specified():
    """The composed configuration (an experiment's or a project's yaml) is checked as given."""
    with pytest.raises(ConfigError) as e:
        checked_view({"record": {"video": "no"}})
    assert str(e.value) == "record.video must be true or false, got 'no'"
    with pytest.raises(ConfigError) as e:
        checked_view({"budget": {"tool_calsl": 5}})
    assert str(e.value) == ("unknown key 'budget.tool_calsl'; did you mean budget.tool_calls? valid keys under budget: "
                            "tool_calls, sim_seconds, wall_seconds, run_code_max_internal_calls, cost_usd")


@pytest.mark.parametrize("group, option, line", [
    ("model", {"name": "x", "harness": 5}, "model.harness must be the name of the harness the model runs in "
                                           "(harness=auto), or null, got 5"),
    ("model", {"name": 5}, "model.name must be the name of the model configuration (a string), got 5"),
    ("harness", {"name": ["a"]}, "harness.name must be the name of the harness (a string), got ['a']"),
])
def test_the_model_and_harness_basics_are_typed(group, option, line):
    with pytest.raises(ConfigError) as e:
        check_basics({group: option})
    assert str(e.value) == line


def test_the_model_and_harness_groups_stay_open():
    """An option's own keys (a provider's, a vendor's) are not the schema's business."""
    check_basics({"model": {"name": "x", "harness": "reference", "model_id": "m", "vendor": {"env": {}, "extra_args": []},
                            "pricing": {"input_per_mtok": 1.0}},
                  "harness": {"name": "mcp", "transport": "http", "port": 0}})
    for name in ("cab_schema_model", "cab_schema_harness"):
        assert ConfigStore.instance().load(f"{name}.yaml").node is not None
