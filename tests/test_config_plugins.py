"""Where cab's Hydra configuration comes from: the plugins' config dirs (hook ``cab_config_dirs``,
through the search path plugin in ``hydra_plugins/cab_searchpath``), a task option per installed
task, the core's primary config (no plugin named) and the project's composition in ``conf/``."""
from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_module
from hydra.core.override_parser.overrides_parser import OverridesParser

import cab_core
from cab_core import plugins
from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.runner import attempt_spec
from cab_core.config import default_selection, extend_search_path, is_cab_search_path
from cab_core.contracts.task import Task, TaskInfo
from cab_core.errors import ConfigError, PluginError
from cab_suite_codeaction import catalog

ROOT = Path(__file__).resolve().parents[1]
PAPER_MODELS = {"astra_codex", "opus5", "opus5_claude_code", "gemini36flash", "gpt56", "qwen38max", "grok46",
                "kimik3", "sonnet5"}


def _compose(overrides=(), config_name="config", hydra=False):
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        return compose(config_name=config_name, overrides=normalise_overrides(list(overrides)),
                       return_hydra_config=hydra)


@pytest.fixture
def conf_plugin(tmp_path, monkeypatch):
    """A plugin registered in-process whose config dir (a package on sys.path) ships sim/x.yaml and
    task/click_bell.yaml."""
    pkg = tmp_path / "cab_test_confplugin"
    (pkg / "conf" / "sim").mkdir(parents=True)
    (pkg / "conf" / "task").mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "conf" / "__init__.py").write_text("")
    (pkg / "conf" / "sim" / "x.yaml").write_text("name: x\nspeed: 3\n")
    (pkg / "conf" / "task" / "click_bell.yaml").write_text("name: click_bell\nnote: shipped\n")
    monkeypatch.syspath_prepend(str(tmp_path))

    class Plugin:
        @cab_core.hookimpl
        def cab_config_dirs(self):
            return ["pkg://cab_test_confplugin.conf"]

    pm = plugins.plugin_manager()
    plugin = Plugin()
    pm.register(plugin, name="test_confplugin")
    yield
    pm.unregister(plugin)
    _compose()  # the generated option of click_bell again, for the tests after this one


def test_a_plugins_config_dir_is_on_the_search_path(conf_plugin):
    cfg = _compose(["sim=x"], hydra=True)
    assert (cfg.sim.name, cfg.sim.speed) == ("x", 3)
    sources = [(s.provider, s.path) for s in cfg.hydra.runtime.config_sources]
    assert ("cab-plugins", "cab_test_confplugin.conf") in sources


def test_a_task_yaml_a_plugin_ships_is_the_option_without_a_schema_warning(conf_plugin):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Hydra's automatic schema matching would warn
        cfg = _compose(["task=click_bell"])
    assert dict(cfg.task) == {"name": "click_bell", "note": "shipped"}


def test_a_bad_config_dirs_result_is_a_plugin_error():
    class Bad:
        @cab_core.hookimpl
        def cab_config_dirs(self):
            return "pkg://not_a_list.conf"

    pm = plugins.build_plugin_manager(extra=[Bad()], autoload=False)
    with pytest.raises(PluginError, match="cab_config_dirs of .* must return a list of search paths"):
        plugins.config_dirs(pm)


def test_every_installed_task_has_a_generated_task_option():
    from hydra.core.config_store import ConfigStore

    names = plugins.task_names()
    assert names and len(names) == len(set(names))
    _compose()
    stored = ConfigStore.instance().repo["task"]
    for name in names:
        assert dict(_compose([f"task={name}"]).task) == {"name": name}
        assert stored[f"{name}.yaml"].provider == "cab"
    assert not any(ROOT.glob("**/conf/task/*.yaml"))  # no task ships a yaml: the suite is the source


def test_plain_cab_composes_todays_defaults(tmp_path):
    cfg = _compose(hydra=True)
    choices = cfg.hydra.runtime.choices
    assert {g: choices[g] for g in ("sim", "embodiment", "planner", "model", "harness", "task")} == {
        "sim": "sapien", "embodiment": "aloha_agilex", "planner": "pin", "model": "oracle", "harness": "auto",
        "task": "beat_block_hammer"}
    assert choices["hydra/launcher"] == "local" and choices["experiment"] is None
    assert cfg.hydra.mode is None  # a single run
    assert (cfg.sim.name, cfg.embodiment.name, cfg.planner.name, cfg.task.name) == (
        "sapien", "aloha_agilex", "pin", "beat_block_hammer")
    spec = attempt_spec(_compose(), tmp_path)
    assert (spec.sim, spec.embodiment, spec.planner, spec.model, spec.harness, spec.task, spec.seed) == (
        "sapien", "aloha_agilex", "pin", "oracle", "direct", "beat_block_hammer", 0)
    sources = [(s.provider, s.path) for s in cfg.hydra.runtime.config_sources]
    assert sources.index(("cab-project", "cab_conf")) < sources.index(("main", "cab_core.conf"))


def _sweep(cfg) -> dict[str, list]:
    params = cfg.hydra.sweeper.params
    parsed = OverridesParser.create().parse_overrides([f"{k}={v}" for k, v in params.items()])
    return {o.key_or_group: [str(v) for v in o.sweep_iterator()] for o in parsed}


def test_experiment_smoke_is_a_small_sweep_on_the_default_simulator():
    from hydra.types import RunMode

    cfg = _compose(["experiment=smoke"], hydra=True)
    assert cfg.hydra.mode == RunMode.MULTIRUN
    assert _sweep(cfg) == {"task": ["click_bell", "press_stapler"], "model": ["oracle", "idle"]}
    assert cfg.sim.name == "sapien" and cfg.record.video is False
    assert cfg.hydra.sweep.dir.startswith("multirun/smoke/")


def test_experiment_paper_is_nine_configurations_by_25_tasks_by_3_attempts():
    cfg = _compose(["+experiment=paper"], hydra=True)
    sweep = _sweep(cfg)
    assert set(sweep) == {"model", "task", "attempt"}
    assert len(sweep["model"]) == 9 and set(sweep["model"]) == PAPER_MODELS
    assert sweep["task"] == catalog.task_names()
    assert sweep["attempt"] == ["1", "2", "3"]
    assert cfg.sim.name == "sapien" and cfg.seed is None  # the paper's fixed scene seeds
    for model in PAPER_MODELS:  # each configuration composes (its option file is installed)
        assert _compose([f"model={model}"]).model.name == model


def test_the_cores_config_names_no_plugin_of_the_project():
    core_conf = Path(cab_core.__file__).parent / "conf"
    names = {p.stem for p in ROOT.glob("plugins/*/*/conf/*/*.yaml")} | set(plugins.task_names())
    assert {"sapien", "mujoco", "aloha_agilex", "pin", "opus5", "mcp"} <= names
    for f in core_conf.rglob("*.yaml"):
        text = f.read_text()
        words = set(text.replace(":", " ").replace(",", " ").split())
        assert not (words & names), (f.name, words & names)
    defaults = yaml.safe_load((core_conf / "config.yaml").read_text())["defaults"]
    assert {"sim": None, "embodiment": None, "planner": None, "task": None} == {
        k: v for d in defaults if isinstance(d, dict) for k, v in d.items() if k in ("sim", "embodiment", "planner", "task")}


def test_the_cores_primary_config_alone_needs_each_plugin_group_chosen(tmp_path, monkeypatch):
    from hydra_plugins.cab_searchpath import cab_searchpath

    monkeypatch.setattr(cab_searchpath, "PROJECT_PACKAGE", "cab_conf_not_installed")  # the core without the project
    cfg = _compose()
    assert "sim" not in cfg and "task" not in cfg and cfg.model.name == "oracle" and cfg.harness.name == "auto"
    with pytest.raises(ConfigError, match=r"^no task selected: add task=<option> \(installed: beat_block_hammer, "):
        attempt_spec(cfg, tmp_path)
    sims = ", ".join(sorted(plugins.registry("simulators")))  # mujoco, pybullet, sapien (CI's 3.13 check: no pybullet)
    assert "mujoco" in sims and "sapien" in sims
    with pytest.raises(ConfigError, match=rf"^no sim selected: add sim=<option> \(installed: {sims}\)$"):
        attempt_spec(_compose(["task=lift_pot"]), tmp_path)
    cfg = _compose(["sim=mujoco", "+embodiment=aloha_agilex", "planner=pin", "task=lift_pot"])
    spec = attempt_spec(cfg, tmp_path)
    assert (spec.sim, spec.task, spec.budget_tool_calls) == ("mujoco", "lift_pot", plugins.task_info("lift_pot").budget_tool_calls)


def test_other_hydra_apps_search_paths_are_left_alone():
    from hydra._internal.config_search_path_impl import ConfigSearchPathImpl

    sp = ConfigSearchPathImpl()
    sp.append("hydra", "pkg://hydra.conf")
    sp.append("main", "pkg://someone_else.conf")
    extend_search_path(sp)
    assert [e.path for e in sp.get_path()] == ["pkg://hydra.conf", "pkg://someone_else.conf"]
    sp.append("main", "pkg://cab_core/conf")
    assert is_cab_search_path(sp)


def test_default_selection_is_the_composed_defaults():
    assert default_selection() == {"sim": "sapien", "embodiment": "aloha_agilex", "planner": "pin"}
    assert default_selection(("task",)) == {"task": "beat_block_hammer"}


@pytest.fixture
def new_suite():
    """A task suite registered in-process with one task no file names: ``block_on_pad``."""
    class BlockOnPad(Task):
        info = TaskInfo(name="block_on_pad", instruction="Put the block on the pad.", seed=4, scoring="final",
                        budget_tool_calls=12, budget_sim_s=65.0)

        def build(self, seed, embodiment):
            raise NotImplementedError

        def verifier(self, instance):
            raise NotImplementedError

        def oracle(self, call, world):
            raise NotImplementedError

    class Suite:
        @cab_core.hookimpl
        def cab_task_suites(self):
            return {"pads": lambda: {"block_on_pad": BlockOnPad()}}

    pm = plugins.plugin_manager()
    suite = Suite()
    pm.register(suite, name="test_pads")
    plugins._installed_tasks.cache_clear()
    yield
    pm.unregister(suite)
    plugins._installed_tasks.cache_clear()


def test_a_new_suites_task_needs_no_yaml_and_no_core_edit(new_suite, tmp_path):
    assert plugins.task_info("block_on_pad").seed == 4
    cfg = _compose(["task=block_on_pad", "model=idle"])
    assert dict(cfg.task) == {"name": "block_on_pad"}
    spec = attempt_spec(cfg, tmp_path)
    assert (spec.task, spec.seed, spec.budget_tool_calls, spec.budget_sim_seconds, spec.budget_wall_seconds) == (
        "block_on_pad", 4, 12, 65.0, 720.0)


def test_a_harness_option_still_selects_its_model():
    cfg = _compose(["harness=mcp"])
    assert (cfg.harness.name, cfg.model.name) == ("mcp", "mcp_client")  # conf/harness/mcp.yaml of harness_mcp
