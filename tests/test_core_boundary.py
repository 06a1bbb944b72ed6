"""The core names none of the project's own plugins, and plugins depend on the core, not on each
other: what every harness shares (prompt, image rule, run_code limits, pricing) is the core's."""
import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest
import tomllib

import cab_core
from cab_core.apps.cli import wants_stdio_protocol
from cab_core.attempt.runner import attempt_spec
from cab_core.errors import ConfigError
from cab_core.kits.harness import prompts as agent_io
from cab_core.plugins import all_tasks, build_plugin_manager, registry
from cab_harness_mcp import harness as mcp
from cab_harness_reference import loop

CORE = Path(cab_core.__file__).parent

# Registered names that are also ordinary words or a protocol's name: not searched for as such.
AMBIGUOUS = {"reference", "mcp", "google", "openai", "anthropic", "pin", "inspect"}


ROOT = Path(__file__).resolve().parents[1]


def _project_names() -> tuple[set[str], set[str]]:
    """Every name the installed plugins of this project go by: distributions, modules, entry points,
    what they register (simulators, planners, robots, suites, harnesses, providers...) and tasks;
    (names searched as words, ordinary words searched only as a value the code could select)."""
    pm = build_plugin_manager()
    names = set()
    for ep in metadata.entry_points(group="cab"):
        if ep.module.split(".")[0] == "cab_core":
            continue
        names |= {ep.name, ep.dist.name, ep.module.split(".")[0]}
    for kind in ("simulators", "planners", "embodiments", "task_suites", "harnesses", "model_providers",
                 "context_policies", "record_observers"):
        names |= {n for n, f in registry(kind, pm).items() if not getattr(f, "__module__", "").startswith("cab_core")}
    names |= set(all_tasks(pm))
    # and the plugins of this repository the set-up does not install (planner_mplib: numpy<2 only)
    for project in ROOT.glob("plugins/*/pyproject.toml"):
        meta = tomllib.loads(project.read_text())["project"]
        cab = meta.get("entry-points", {}).get("cab", {})
        names |= {meta["name"], *cab, *(v.split(".")[0] for v in cab.values())}
    names |= {p.stem for p in ROOT.glob("plugins/*/cab_*/conf/planner/*.yaml")}
    return names - AMBIGUOUS, names & AMBIGUOUS


def _alternation(names) -> str:
    return "|".join(map(re.escape, sorted(names, key=len, reverse=True)))


def test_the_core_names_no_plugin_of_the_project():
    """In every source and config file of the core: no plugin name as a word, and none of the
    ambiguous ones as a value the code or a config could select by (a quoted string in Python
    that is not a dict key, a YAML value)."""
    words, values = _project_names()
    assert {"sapien", "mplib", "aloha_agilex", "cab-sim-mujoco", "click_bell", "claude_code"} <= words
    assert {"reference", "mcp"} <= values
    word = re.compile(r"(?<![\w-])(" + _alternation(words) + r")(?![\w-])", re.IGNORECASE)
    py_value = re.compile(r"""(?<!\[)(["'])(""" + _alternation(values) + r")\1")
    yaml_value = re.compile(r":\s*(" + _alternation(values) + r")\s*(#.*)?$")
    found = []
    files = sorted(p for p in CORE.rglob("*") if p.is_file() and p.suffix in (".py", ".yaml", ".yml", ".txt", ".toml"))
    assert len(files) > 50
    for path in files:
        rel = path.relative_to(CORE)
        value = py_value if path.suffix == ".py" else yaml_value
        for i, line in enumerate(path.read_text().splitlines(), 1):
            found += [f"{rel}:{i}: {m.group(0)}" for m in list(word.finditer(line)) + list(value.finditer(line))]
    assert found == [], "\n".join(found)


def test_harness_mcp_needs_no_other_harness():
    code = ("import sys, cab_harness_mcp.plugin, cab_harness_mcp.harness, cab_harness_mcp.launchers, "
            "cab_harness_mcp.server; print(sorted(m for m in sys.modules if m.startswith('cab_harness_reference')))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"
    requires = [re.split(r"[ ;<>=!\[]", q)[0] for q in metadata.requires("cab-harness-mcp") or []]
    assert "cab" in requires and "cab-harness-reference" not in requires


def test_both_harnesses_use_the_cores_prompt_and_image_rule():
    for name in ("system_prompt", "first_user_message", "result_images", "run_code_limits"):
        assert getattr(loop, name) is getattr(agent_io, name)
    assert mcp.prompts is agent_io  # the MCP harness calls them through the core's module (prompts.system_prompt)
    for name in ("system_prompt", "first_user_message", "result_images", "run_code_limits"):
        assert name not in vars(mcp), name  # and keeps no copy of its own


def test_a_model_config_without_a_harness_is_refused(tmp_path):
    cfg = {"task": {"name": "click_bell"}, "sim": {"name": "mujoco"}, "embodiment": {"name": "aloha_agilex"},
           "planner": {"name": "mplib"}, "harness": {"name": "auto"}, "model": {"name": "mine"}}
    with pytest.raises(ConfigError, match=r"^model 'mine' names no harness \(model.harness\); give one with harness="):
        attempt_spec(cfg, tmp_path)
    cfg["model"]["harness"] = "direct"
    assert attempt_spec(cfg, tmp_path).harness == "direct"


def test_a_harness_that_speaks_on_stdio_gets_stdout_by_its_own_declaration():
    """The core reserves stdout for a protocol when the selected harness says it speaks on stdio
    (not by the harness's name): here the MCP harness does, the direct one does not, and another
    transport given on the command line wins."""
    assert getattr(registry("harnesses")["mcp"], "speaks_on_stdio", False) is True
    assert wants_stdio_protocol(["task=click_bell", "harness=mcp"])
    assert wants_stdio_protocol(["+harness=mcp", "harness.transport=stdio"])
    assert not wants_stdio_protocol(["harness=mcp", "harness.transport=http"])
    assert not wants_stdio_protocol(["harness=direct"])
    assert not wants_stdio_protocol(["harness=no_such_harness"])
    assert not wants_stdio_protocol(["task=click_bell"])
