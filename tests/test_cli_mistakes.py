"""Every command-line mistake is one line on stderr, beginning with the program's name, with exit
status 2, before any simulator starts and before any attempt or sweep directory is written.
The ``cab`` cases run the installed entry point as a subprocess, as a user would."""
import dataclasses
import json
import os
import subprocess
import sys

import pytest

from cab_core.apps.cmdline import check_command_line
from cab_core.attempt.engine.builtin import ScriptedAgent
from cab_core.conf.schema import SweepConfig
from cab_core.errors import ConfigError

BIN = os.path.dirname(sys.executable)
BUDGET_KEYS = "tool_calls, sim_seconds, wall_seconds, run_code_max_internal_calls, cost_usd"
SWEEP_KEYS = ", ".join(f.name for f in dataclasses.fields(SweepConfig))  # the schema's order


def run(args, cwd):
    return subprocess.run([os.path.join(BIN, args[0])] + args[1:], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def refused(r, line: str, status: int = 2) -> None:
    assert (r.returncode, r.stderr) == (status, line + "\n"), (r.returncode, r.stderr)
    assert r.stdout == ""


def command_line_refusal(args: list[str]) -> str:
    """The message :func:`check_command_line` refuses ``args`` with (it must refuse them)."""
    with pytest.raises(ConfigError) as e:
        check_command_line(args)
    return str(e.value)


def cab_refuses(tmp_path, overrides, line, sweep=False):
    """``cab`` refuses ``overrides`` with ``line``, and writes neither a run nor a sweep folder."""
    out = tmp_path / "out"
    dirs = [f"hydra.sweep.dir={out}"] if sweep else [f"hydra.run.dir={out}"]
    r = run(["cab", *(["-m"] if sweep else []), *overrides, *dirs], tmp_path)
    refused(r, line)
    assert not out.exists() and not (tmp_path / "outputs").exists() and not (tmp_path / "multirun").exists()


# --- option names: the real list from Hydra's config search path ----------------------------

@pytest.mark.parametrize("overrides, line", [
    (["task=beat_blok_hammer"], "cab: unknown task 'beat_blok_hammer'; did you mean beat_block_hammer?"),
    (["sim=isaac"], "cab: unknown sim 'isaac'; valid: mujoco, pybullet, sapien"),
    (["+sim=isaac"], "cab: unknown sim 'isaac'; valid: mujoco, pybullet, sapien"),
    (["model=opus"], "cab: unknown model 'opus'; did you mean opus5?"),
    (["planner=pinn"], "cab: unknown planner 'pinn'; did you mean pin?"),
    (["embodiment=aloha_agilx"], "cab: unknown embodiment 'aloha_agilx'; did you mean aloha_agilex?"),
])
def test_unknown_option_is_one_line_with_the_closest_names(tmp_path, overrides, line):
    cab_refuses(tmp_path, overrides, line)


def test_unknown_option_in_a_sweep_is_refused_before_the_sweep_starts(tmp_path):
    cab_refuses(tmp_path, ["sim=mujoco,isaac", "model=idle"],
                "cab: unknown sim 'isaac'; valid: mujoco, pybullet, sapien", sweep=True)
    cab_refuses(tmp_path, ["task=lift_pot,click_bel", "model=idle"],
                "cab: unknown task 'click_bel'; did you mean click_bell?", sweep=True)


def test_options_come_from_the_config_search_path(tmp_path):
    """An option another config directory adds (as a plugin's search path would) is known."""
    (tmp_path / "extra" / "sim").mkdir(parents=True)
    (tmp_path / "extra" / "sim" / "isaac.yaml").write_text("name: isaac\nrender: true\n")
    cab_refuses(tmp_path, ["--config-dir", str(tmp_path / "extra"), "sim=isaca"],
                "cab: unknown sim 'isaca'; did you mean isaac?")
    r = run(["cab", "--config-dir", str(tmp_path / "extra"), "sim=isaac", "--cfg", "job"], tmp_path)
    assert r.returncode == 0 and "name: isaac" in r.stdout, r.stderr


# --- keys: refused with or without +, naming the valid ones ----------------------------------

def option_keys(option: str) -> list[str]:
    """The keys of a config option, as its file declares them."""
    import yaml

    import cab_harness_mcp

    assert option == "harness/mcp"  # the option files live with their plugins
    path = os.path.join(os.path.dirname(cab_harness_mcp.__file__), "conf", option + ".yaml")
    with open(path) as f:
        return [k for k in yaml.safe_load(f) if k != "defaults"]


@pytest.mark.parametrize("plus", ["", "+", "++"])
def test_unknown_budget_key_with_or_without_plus(tmp_path, plus):
    cab_refuses(tmp_path, [f"{plus}budget.tool_calsl=5", "model=idle", "sim=mujoco"],
                f"cab: unknown key 'budget.tool_calsl'; did you mean budget.tool_calls? valid keys under budget: {BUDGET_KEYS}")


def test_unknown_key_in_a_sweep(tmp_path):
    cab_refuses(tmp_path, ["+sandbox.mod=off", "task=lift_pot,click_bell", "model=idle"],
                "cab: unknown key 'sandbox.mod'; did you mean sandbox.mode? valid keys under sandbox: mode, timeout_s, memory_mb",
                sweep=True)


@pytest.mark.parametrize("overrides, line", [
    (["+record.vidoe=false"], "unknown key 'record.vidoe'; did you mean record.video? valid keys under record: "
                              "video, video_every_steps, video_size, observers"),
    (["sweep.max_retries=1"], "unknown key 'sweep.max_retries'; did you mean sweep.max_infra_retries? valid keys under "
                              f"sweep: {SWEEP_KEYS}"),
    (["sim=mujoco", "+sim.physic.impratio=2"], "unknown key 'sim.physic.impratio'; did you mean sim.physics? valid keys "
                                               "under sim (sim=mujoco): name, render, physics, slot_memory_mb"),
    (["sim=sapien", "+sim.physics.impratio=2"], "unknown key 'sim.physics.impratio'; valid keys under sim (sim=sapien): "
                                                "name, render, brdf_cache, slot_memory_mb"),
    (["harness=mcp", "harness.transprt=http"], "unknown key 'harness.transprt'; did you mean harness.transport? valid "
     f"keys under harness (harness=mcp): {', '.join(option_keys('harness/mcp'))}"),
    (["harness.transport=http"], "unknown key 'harness.transport'; valid keys under harness (harness=auto): name"),
    (["+seeds=3"], "unknown key 'seeds'; did you mean seed or seed_set or sweep? valid top-level keys: seed, seed_set, "
                   "attempt, budget, sandbox, record, perturb, fork, sweep, embodiment, experiment, harness, model, "
                   "planner, randomize, sim, task"),
    (["perturb.sed=3"], "unknown key 'perturb.sed'; did you mean perturb.seed? valid keys under perturb: seed, "
                        "position_m, angle_deg, physics_fraction"),
])
def test_unknown_keys_under_each_section(overrides, line):
    assert command_line_refusal(overrides) == line


def test_a_sweep_checks_keys_against_every_selected_option():
    line = command_line_refusal(["-m", "sim=pybullet,mujoco", "+sim.renderer=tiny"])
    assert line == ("unknown key 'sim.renderer'; did you mean sim.render? valid keys under sim (sim=mujoco): "
                    "name, render, physics, slot_memory_mb")


@pytest.mark.parametrize("overrides", [
    ["sim=mujoco", "+sim.physics.impratio=12"],  # sim.physics is open: the plugin checks its names
    ["sim=pybullet", "+sim.physics.solver_iterations=80", "sim.renderer=tiny"],
    ["+harness=mcp", "harness.transport=http", "harness.port=8765"],
    ["model=qwen_local", "model.base_url=http://127.0.0.1:8000/v1", "+model.pricing={input_per_mtok:1.0}"],
    ["budget.sim_seconds=null", "record.video=false", "sandbox.mode=off", "sweep.max_infra_retries=3"],
    ["-m", "task=beat_block_hammer,stack_blocks_three", "model=oracle,idle", "attempt=1,2", "budget.tool_calls=5,9"],
    ["-m", "task=glob(*)", "sim=glob(mu*)", "+sim.physics.impratio=3", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"],
])
def test_documented_overrides_pass(overrides):
    check_command_line(overrides)


# --- budgets: positive, or null for the catalog's --------------------------------------------

def test_zero_budget_is_refused_not_the_catalogs(tmp_path):
    cab_refuses(tmp_path, ["budget.tool_calls=0", "model=idle", "sim=mujoco"],
                "cab: budget.tool_calls must be a positive integer or null (the catalog's budget for the task), got 0")


@pytest.mark.parametrize("override, line", [
    ("budget.sim_seconds=-1", "budget.sim_seconds must be a positive number or null (the catalog's budget for the task), got -1"),
    ("budget.wall_seconds=0", "budget.wall_seconds must be a positive number or null (the catalog's budget for the task), got 0"),
    ("budget.run_code_max_internal_calls=0", "budget.run_code_max_internal_calls must be a positive integer or null "
                                             "(the default, 500), got 0"),
    ("budget.tool_calls=2.5", "budget.tool_calls must be a positive integer or null (the catalog's budget for the task), got 2.5"),
    ("budget.tool_calls=true", "budget.tool_calls must be a positive integer or null (the catalog's budget for the task), got True"),
])
def test_non_positive_budgets(override, line):
    assert command_line_refusal([override]) == line
    assert command_line_refusal(["-m", override.replace("=", "=5,")]) == line  # every value of a sweep


# --- the output folder -----------------------------------------------------------------------

def test_output_folder_that_cannot_be_created(tmp_path):
    (tmp_path / "afile").write_text("")
    r = run(["cab", "model=idle", "sim=mujoco", f"hydra.run.dir={tmp_path}/afile/x"], tmp_path)
    refused(r, f"cab: cannot create the output folder {tmp_path}/afile/x (hydra.run.dir): Not a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


# --- cab-report, cab-view, cab-schemas ------------------------------------------------------

def test_report_on_a_folder_without_attempts(tmp_path):
    (tmp_path / "empty" / "a").mkdir(parents=True)
    refused(run(["cab-report", str(tmp_path / "empty")], tmp_path),
            f"cab-report: no attempt found under {tmp_path}/empty (no result.json or events.jsonl below it); nothing written")
    assert sorted(p.name for p in (tmp_path / "empty").iterdir()) == ["a"]
    refused(run(["cab-report", str(tmp_path / "nope")], tmp_path), f"cab-report: {tmp_path}/nope does not exist")


def test_view_on_a_missing_folder_or_a_sweep(tmp_path):
    refused(run(["cab-view", str(tmp_path / "nope")], tmp_path), f"cab-view: {tmp_path}/nope does not exist")
    sweep = tmp_path / "sweep"
    for rel in ("lift_pot/idle/seed-0/attempt-1", "lift_pot/idle/seed-0/attempt-2"):
        (sweep / rel).mkdir(parents=True)
        (sweep / rel / "events.jsonl").write_text("")
    (sweep / "sweep.json").write_text("{}")
    refused(run(["cab-view", str(sweep)], tmp_path),
            f"cab-view: {sweep} is a sweep directory, not an attempt (no result.json); attempts: "
            "lift_pot/idle/seed-0/attempt-1, lift_pot/idle/seed-0/attempt-2")
    (sweep / "empty").mkdir()
    refused(run(["cab-view", str(sweep / "empty")], tmp_path),
            f"cab-view: {sweep}/empty: result.json is missing: it is not an attempt directory, and no attempt is below it")
    assert not list(tmp_path.rglob("view.html"))


def test_schemas_unknown_tool_names_the_closest_and_the_valid_ones(tmp_path):
    names = [t["name"] for t in json.loads(run(["cab-schemas"], tmp_path).stdout)]
    r = run(["cab-schemas", "reach_tpc"], tmp_path)
    refused(r, f"cab-schemas: unknown tool 'reach_tpc'; did you mean reach_tcp or reach_both_tcp? valid: {', '.join(names)}")
    r = run(["cab-schemas", "move_tcp_to"], tmp_path)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1
    assert r.stderr.startswith("cab-schemas: unknown tool 'move_tcp_to'; did you mean ")
    assert r.stderr.endswith(f"? valid: {', '.join(names)}\n")


# --- the scripted agent's items ------------------------------------------------------------

def _script(tmp_path, items) -> dict:
    p = tmp_path / "calls.jsonl"
    p.write_text("".join(json.dumps(i) + "\n" for i in items))
    return {"name": "scripted", "script": str(p)}


def test_script_items_take_args_or_arguments(tmp_path):
    agent = ScriptedAgent(_script(tmp_path, [{"tool": "move_delta", "args": {"arm": "left"}},
                                             {"tool": "done", "arguments": {"report": "r", "success_claim": False}}]))
    calls = []

    class Episode:
        def call(self, tool, args):
            calls.append((tool, args))
            return type("R", (), {"ended": tool == "done"})()

    agent.run(Episode())
    assert calls == [("move_delta", {"arm": "left"}), ("done", {"report": "r", "success_claim": False})]


@pytest.mark.parametrize("item, line", [
    ({"tool": "done", "argz": {}}, "script item 1 has unknown key 'argz'; did you mean args? valid keys: tool, args, arguments"),
    ({"tool": "done", "args": {}, "arguments": {}}, "script item 1 has both 'args' and 'arguments'; give one"),
    ({"name": "done"}, "script item 1 must be an object with a 'tool' key (valid keys: tool, args, arguments)"),
])
def test_script_item_with_another_key_is_refused(tmp_path, item, line):
    with pytest.raises(ConfigError) as e:
        ScriptedAgent(_script(tmp_path, [{"tool": "capture_head"}, item]))
    assert str(e.value) == line


def test_bad_script_is_one_line_before_the_simulator_starts(tmp_path):
    cfg = _script(tmp_path, [{"tool": "done", "argumnets": {"report": "r", "success_claim": False}}])
    r = run(["cab", "sim=mujoco", "model=scripted", f"model.script={cfg['script']}", f"hydra.run.dir={tmp_path}/d"],
            tmp_path)
    refused(r, "cab: script item 0 has unknown key 'argumnets'; did you mean arguments or args? valid keys: tool, args, arguments")
    assert not (tmp_path / "d" / "events.jsonl").exists() and not (tmp_path / "d" / "result.json").exists()


def test_an_unknown_record_observer_is_refused_with_the_command_line(tmp_path):
    """Before Hydra creates the run folder, as every other command-line mistake."""
    with pytest.raises(ConfigError, match=r"^unknown record observer 'no_such_observer'"):
        check_command_line(["record.observers=[no_such_observer]"])
    with pytest.raises(ConfigError, match=r"^record.observers must be null"):
        check_command_line(["record.observers=3"])
    check_command_line(["record.observers=[]"])
    check_command_line(["record.observers=null"])
    out = tmp_path / "run"
    r = run(["cab", "record.observers=[no_such_observer]", f"hydra.run.dir={out}"], tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("cab: unknown record observer 'no_such_observer'")
    assert not out.exists()


# --- seed sets: a sweep of each task's named seeds -------------------------------------------

def test_a_seed_set_becomes_the_sweeps_seeds():
    from cab_core.apps.cmdline import expand_seed_set

    argv = ["-m", "task=click_bell,lift_pot", "model=idle", "seed_set=heldout"]
    assert expand_seed_set(argv) == argv + ["seed=" + ",".join(str(s) for s in range(100, 120))]
    assert expand_seed_set(["-m", "task=lift_pot"]) == ["-m", "task=lift_pot"]  # no seed set: unchanged


@pytest.mark.parametrize("overrides, sweep, line", [
    (["seed_set=heldout"], False, "cab: seed_set=NAME sweeps a task's named seed set: add -m (or give one seed=S)"),
    (["seed_set=heldout", "seed=3"], True, "cab: give seed_set=NAME or seed=..., not both"),
    (["task=click_bell", "seed_set=nope"], True, "cab: task click_bell has no seed set 'nope'; its sets: catalog, heldout"),
])
def test_seed_set_mistakes(tmp_path, overrides, sweep, line):
    cab_refuses(tmp_path, overrides, line, sweep=sweep)
