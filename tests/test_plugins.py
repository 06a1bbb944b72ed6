import json
import types

import pytest

from cab_core import hookimpl
from cab_core.errors import ConfigError, PluginError
from cab_core.plugins import build_plugin_manager, create, registry


def _plugin(name, **hooks):
    mod = types.ModuleType(name)
    for k, v in hooks.items():
        setattr(mod, k, hookimpl(v))
    return mod


def test_register_and_create_lazily():
    made = []
    p = _plugin("fake_sim", cab_simulators=lambda: {"fake": lambda cfg: made.append(cfg) or "SIM"})
    pm = build_plugin_manager([p], autoload=False)
    assert list(registry("simulators", pm)) == ["fake"]
    assert made == []  # factories are not called at registration
    assert create("simulators", "fake", {"x": 1}, pm) == "SIM"
    assert made == [{"x": 1}]


def test_duplicate_names_fail():
    a = _plugin("a", cab_planners=lambda: {"p": object})
    b = _plugin("b", cab_planners=lambda: {"p": object})
    pm = build_plugin_manager([a, b], autoload=False)
    with pytest.raises(PluginError, match="registered twice"):
        registry("planners", pm)


def test_unknown_name_lists_choices():
    pm = build_plugin_manager([_plugin("a", cab_agents=lambda: {"oracle": object, "idle": object})], autoload=False)
    with pytest.raises(ConfigError, match="choices: idle, oracle"):
        create("agents", "nope", {}, pm)


def test_misspelled_hook_fails_at_startup():
    from pluggy import PluginValidationError

    with pytest.raises(PluginValidationError):
        build_plugin_manager([_plugin("bad", cab_simulatorz=lambda: {})], autoload=False)


def test_installed_entry_points_provide_the_core_plugins():
    pm = build_plugin_manager()
    assert {"sapien"} <= set(registry("simulators", pm))
    assert {"pin"} <= set(registry("planners", pm))
    assert {"aloha_agilex"} <= set(registry("embodiments", pm))
    assert {"codeaction"} <= set(registry("task_suites", pm))
    assert {"direct"} <= set(registry("harnesses", pm))
    assert {"oracle", "idle", "scripted"} <= set(registry("agents", pm))


def test_core_imports_no_simulator_sdk_or_mcp():
    import subprocess
    import sys

    code = ("import sys, cab_core, cab_core.plugins, cab_core.attempt.engine.episode, cab_core.attempt.runner, cab_core.tools;"
            "bad=[m for m in ('sapien','mplib','pinocchio','ompl','pybullet','mujoco','mcp','anthropic','openai') if m in sys.modules];"
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_cab_plugins_command_lists_plugins():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", "from cab_core.apps.cli import plugins_main; plugins_main()"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    for name in ("sim_sapien", "planner_pin", "suite_codeaction", "embodiment_aloha", "core"):
        assert name in r.stdout
    # what plain `cab` composes is marked: one simulator, embodiment and planner
    marked = [line.split() for line in r.stdout.splitlines() if "(default)" in line]
    assert sorted((m[0], m[m.index("(default)") - 1].rstrip(",")) for m in marked) == [
        ("embodiments", "aloha_agilex"), ("planners", "pin"), ("simulators", "sapien")], marked
    r = subprocess.run([sys.executable, "-c", "import sys; sys.argv[1:] = ['--json'];"
                        "from cab_core.apps.cli import plugins_main; plugins_main()"], capture_output=True, text=True)
    rows = {row["plugin"]: row for row in json.loads(r.stdout)}
    assert rows["planner_pin"]["defaults"] == {"planners": "pin"} and rows["core"]["defaults"] == {}
