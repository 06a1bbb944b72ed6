"""Issue 26, plugin-author traps: each says what is wrong in one line. A CodeActionTask subclass
without metadata names what is missing and how to declare it; a task name two suites define names
both (suite, plugin, distribution) and only that name is disabled; a conformance failure names the
failing predicate with its measured value, threshold and margin; ``--cab-conformance --cab-tasks``
runs the task groups only; ``cab-plugins`` lists each suite's tasks; the install routes of
docs/plugins.md (a ``--target`` folder on ``PYTHONPATH``) work as written."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import types
from pathlib import Path

import pytest

from cab_core import hookimpl, plugins
from cab_core.contracts.task import TaskInfo
from cab_core.errors import ConfigError, PluginError
from cab_core.plugins import all_tasks, build_plugin_manager, describe, load_suites
from cab_core.testing.task_conformance import PairResult, check_pair, failing_predicates
from cab_suite_codeaction import catalog
from cab_suite_codeaction.common import CodeActionTask
from cab_suite_codeaction.tasks import TASK_MODULES  # the suite's order (its modules are named after its tasks)
from cab_suite_codeaction.tasks.click_bell import TASK

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
INFO = TaskInfo(name="lift_cube", instruction="Lift the cube.", seed=3, scoring="final", budget_tool_calls=10,
                budget_sim_s=20.0)


def _plugin(name: str, **hooks) -> types.ModuleType:
    mod = types.ModuleType(name)
    for k, v in hooks.items():
        setattr(mod, k, hookimpl(v))
    return mod


def _env(site: Path | None = None, **extra) -> dict:
    """This environment without plugin switches; ``site`` first on PYTHONPATH."""
    e = {k: v for k, v in os.environ.items() if k not in ("CAB_DISABLE_PLUGINS", "CAB_DISABLE_PLUGIN_AUTOLOAD")}
    if site is not None:
        e["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    e.update(extra)
    return e


# -- a CodeActionTask subclass without metadata --------------------------------------------------

def _lift_cube_class(**attrs):
    return type("LiftCube", (CodeActionTask,), {"__module__": "my_cab_plugin.lift_cube", **attrs})


MISSING_METADATA = (
    "task 'lift_cube' (my_cab_plugin.lift_cube.LiftCube, a CodeActionTask) has no metadata: the suite's catalog, "
    "which gives its own tasks theirs, has no entry of that name; declare it on the class as info = "
    "TaskInfo(name=..., instruction=..., seed=..., scoring=..., budget_tool_calls=..., budget_sim_s=...) "
    "(cab_core.contracts.task; or set self.info in __init__, as examples/block_on_pad does)")


def test_a_codeaction_task_without_metadata_says_what_is_missing():
    cls = _lift_cube_class()
    assert cls.name == "lift_cube"  # the module's name, as the suite's own tasks get theirs
    with pytest.raises(PluginError) as e:
        cls()
    assert str(e.value) == MISSING_METADATA


def test_its_suite_is_named_with_the_line_and_how_to_leave_it_out():
    cls = _lift_cube_class()
    pm = build_plugin_manager([_plugin("my_cab_plugin", cab_task_suites=lambda: {"mine": lambda: {"lift_cube": cls()}})],
                              autoload=False)
    with pytest.raises(PluginError) as e:
        all_tasks(pm)
    assert str(e.value) == (f"task suite 'mine' (plugin my_cab_plugin) failed to load its tasks: {MISSING_METADATA}; "
                            "fix it, or disable the plugin with CAB_DISABLE_PLUGINS=my_cab_plugin")
    assert "\n" not in str(e.value)


def test_a_codeaction_task_declares_its_metadata_on_the_class():
    task = _lift_cube_class(info=INFO)()
    assert task.info is INFO and task.name == "lift_cube"


def test_the_suites_own_tasks_still_take_the_catalogs():
    assert TASK().info == catalog.task_info("click_bell")
    with pytest.raises(ConfigError):  # the catalog's own lookup of an unknown name is unchanged
        catalog.task_info("lift_cube")


# -- a task name two suites define -----------------------------------------------------------------

def _two_suites():
    a = _plugin("plug_a", cab_task_suites=lambda: {"suite_a": lambda: {"t1": "A1", "shared": "A-shared"}})
    b = _plugin("plug_b", cab_task_suites=lambda: {"suite_b": lambda: {"shared": "B-shared", "t2": "B2"}})
    return build_plugin_manager([a, b], autoload=False)


SHARED = ("task 'shared' is defined by two suites, 'suite_a' (plugin plug_a) and 'suite_b' (plugin plug_b): it is "
          "disabled until one of them is uninstalled or disabled (CAB_DISABLE_PLUGINS=<plugin>); every other task works")


def test_a_name_two_suites_define_is_disabled_alone_and_names_both():
    pm = _two_suites()
    assert all_tasks(pm) == {"t1": "A1", "t2": "B2"}
    got = load_suites(pm)
    assert got.suites == {"suite_a": ["t1", "shared"], "suite_b": ["shared", "t2"]}
    assert got.conflicts == {"shared": SHARED}
    rows = {r["plugin"]: r for r in describe(pm)}
    assert rows["plug_a"]["tasks"] == {"suite_a": ["t1", "shared"]}
    assert rows["plug_b"]["task_conflicts"] == {"shared": SHARED}


def _fake_distribution(root: Path, dist: str, ep_name: str, module: str, source: str) -> None:
    """A real installed distribution on ``root`` (dist-info with its entry point, and its module)."""
    info = root / f"{dist.replace('-', '_')}-0.2.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.2\n")
    (info / "entry_points.txt").write_text(f"[cab]\n{ep_name} = {module}\n")
    (root / f"{module}.py").write_text(source)


@pytest.fixture
def twice(tmp_path):
    """An installed plugin whose suite defines ``click_bell`` (the CodeActionBench suite's too)."""
    site = tmp_path / "site"
    site.mkdir()
    _fake_distribution(site, "cab-bells", "bells", "cab_bells_fixture",
                       "from cab_core import hookimpl\n\n\ndef _load():\n"
                       "    from cab_suite_codeaction.tasks.click_bell import TASK\n\n"
                       "    return {'click_bell': TASK()}\n\n\n"
                       "@hookimpl\ndef cab_task_suites():\n    return {'bells': _load}\n")
    return _env(site)


def test_cab_with_a_name_two_suites_define_is_one_line_and_other_tasks_run(twice, tmp_path):
    line = ("cab: task 'click_bell' is defined by two suites, 'bells' (plugin bells, distribution cab-bells) and "
            "'codeaction' (plugin suite_codeaction, distribution cab-suite-codeaction): it is disabled until one of "
            "them is uninstalled or disabled (CAB_DISABLE_PLUGINS=<plugin>); every other task works")
    r = subprocess.run([str(BIN / "cab"), "task=click_bell", "model=idle", "sim=mujoco",
                        f"hydra.run.dir={tmp_path / 'a'}"], capture_output=True, text=True, env=twice, cwd=tmp_path,
                       timeout=300)
    assert (r.returncode, r.stderr.splitlines()) == (2, [line])
    assert not (tmp_path / "a").exists()
    r = subprocess.run([str(BIN / "cab"), "task=press_stapler", "model=idle", "sim=mujoco", "record.video=false",
                        f"hydra.run.dir={tmp_path / 'b'}"], capture_output=True, text=True, env=twice, cwd=tmp_path,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((tmp_path / "b" / "result.json").read_text())["task"] == "press_stapler"
    r = subprocess.run([str(BIN / "cab-plugins")], capture_output=True, text=True, env=twice, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "click_bell (disabled)" in r.stdout
    assert r.stdout.splitlines()[-1] == "disabled: " + line[len("cab: "):]


# -- a conformance failure names the failing predicate ---------------------------------------------

def _margin(measured, threshold, slack, scale, unit):
    return {"slack": slack, "scale": scale, "fraction": slack / scale, "unit": unit, "measured": measured,
            "threshold": threshold}


def _pair(tmp_path, verdict: dict):
    d = tmp_path / "oracle"
    d.mkdir()
    (d / "result.json").write_text(json.dumps({"verdict": verdict}))
    row = {"task": "block_on_pad", "sim": "mujoco", "agent": "oracle", "dir": str(d), "success": False,
           "termination": "done", "calls": 12, "calls_limit": 30, "sim_s": 9.0, "sim_s_limit": 40.0,
           "subgoals": [True, False], "margin": -0.3}
    return PairResult("block_on_pad", "mujoco", {"oracle": row}), d


def test_a_failed_oracle_names_the_failing_predicate_with_its_margin(tmp_path):
    verdict = {"success": False, "scoring": "final", "predicates": {"on_pad": False, "gripper_open": True},
               "final_requirements": {}, "guard": {"block_on_table": True}, "latch": None,
               "margins": {"on_pad": _margin(0.052, 0.04, -0.012, 0.04, "m"),
                           "gripper_open": _margin(1.0, 0.8, 0.2, 0.8, "gripper command"),
                           "block_on_table": _margin(0.76, 0.66, 0.1, 0.08, "m")}}
    res, d = _pair(tmp_path, verdict)
    with pytest.raises(AssertionError) as e:
        check_pair(res)
    assert str(e.value) == (f"block_on_pad on mujoco: the oracle failed (done): on_pad false: measured 0.052 m, "
                            f"threshold 0.04 m, margin -0.012 m (-30% of its tolerance); records in {d}")


def test_a_latch_that_never_latched_and_a_predicate_without_threshold(tmp_path):
    verdict = {"success": False, "scoring": "latch", "predicates": {"pressed": False, "touching": False},
               "final_requirements": {"released": False}, "guard": {}, "latch": {"latched": False},
               "margins": {"pressed": _margin(0.004, 0.01, -0.006, 0.01, "m"),
                           "released": _margin(0.6, 0.8, -0.2, 0.8, "gripper command")}}
    assert failing_predicates(verdict) == (
        "the event never latched; pressed false: measured 0.004 m, threshold 0.01 m, margin -0.006 m (-60% of its "
        "tolerance); touching false (no threshold); released false: measured 0.6 gripper command, threshold 0.8 "
        "gripper command, margin -0.2 gripper command (-25% of its tolerance)")


# -- --cab-conformance --cab-tasks runs the task groups ----------------------------------------------

class _FakeWorld:
    @hookimpl
    def cab_simulators(self):
        return {"alpha": _never}

    @hookimpl
    def cab_task_suites(self):
        return {"fake_suite": lambda: {"t1": object(), "t2": object()}}


def _never(cfg):
    raise AssertionError("a simulator was built while collecting")


def _collected(pytester, monkeypatch, *args) -> list[str]:
    monkeypatch.setattr(plugins, "plugin_manager", lambda: build_plugin_manager(extra=[_FakeWorld()], autoload=False))
    rec = pytester.inline_run("-p", "no:cacheprovider", "--collect-only", *args)
    assert rec.ret in (0, pytest.ExitCode.NO_TESTS_COLLECTED), rec.ret
    [finish] = rec.getcalls("pytest_collection_finish")
    return [i.nodeid for i in finish.session.items]


def test_cab_tasks_with_the_bare_option_collects_the_task_groups_only(pytester, monkeypatch):
    got = _collected(pytester, monkeypatch, "--cab-conformance", "--cab-tasks=t2")
    assert got == ["cab-conformance::test_task[t2-alpha]", "cab-conformance::test_task_determinism[t2-alpha]"]


def test_all_and_the_bare_option_without_tasks_still_collect_every_group(pytester, monkeypatch):
    every = _collected(pytester, monkeypatch, "--cab-conformance=all", "--cab-tasks=t2")  # scripts/test.sh's form
    assert any(n.startswith("cab-conformance::test_simulator[alpha-") for n in every)
    assert "cab-conformance::test_task[t2-alpha]" in every and "cab-conformance::test_task[t1-alpha]" not in every
    bare = _collected(pytester, monkeypatch, "--cab-conformance")
    assert bare == _collected(pytester, monkeypatch, "--cab-conformance=all")
    assert any(n.startswith("cab-conformance::test_simulator[") for n in bare)
    assert "cab-conformance::test_task_determinism[t1-alpha]" in bare


# -- cab-plugins lists each suite's tasks ----------------------------------------------------------

def test_cab_plugins_lists_each_suites_tasks():
    r = subprocess.run([str(BIN / "cab-plugins"), "--json"], capture_output=True, text=True, env=_env(), timeout=300)
    assert r.returncode == 0, r.stderr
    row = {x["plugin"]: x for x in json.loads(r.stdout)}["suite_codeaction"]
    assert row["tasks"] == {"codeaction": list(TASK_MODULES)} and row["task_conflicts"] == {}
    r = subprocess.run([str(BIN / "cab-plugins")], capture_output=True, text=True, env=_env(), timeout=300)
    lines = r.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("    tasks of codeaction "))
    block = [lines[start]] + [line for line in lines[start + 1:start + 10] if line.startswith(" " * 24)]
    listed = " ".join(block)[len("    tasks of codeaction "):].replace(" ", "").split(",")
    assert listed == list(TASK_MODULES)


# -- docs/plugins.md: a plugin installed into a folder of its own, beside a checkout ---------------

TARGET_ROUTE = "python -m pip install --no-deps --no-build-isolation --target"


def test_the_documented_target_route_installs_the_example_offline(tmp_path):
    """The route of docs/plugins.md, as written there: the example built (offline: no index, no
    isolated build environment) into a folder that cab sees through PYTHONPATH."""
    assert TARGET_ROUTE in (ROOT / "docs" / "plugins.md").read_text()
    src = tmp_path / "block_on_pad"
    shutil.copytree(ROOT / "examples" / "block_on_pad", src, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, *TARGET_ROUTE.split()[1:], str(site), str(src)], capture_output=True,
                       text=True, env=_env(PIP_NO_INDEX="1", PIP_DISABLE_PIP_VERSION_CHECK="1"), timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert list(site.glob("cab_example_block_on_pad-*.dist-info"))
    assert not list(site.glob("cab-*.dist-info")) and not (site / "cab_core").exists()  # nothing of cab's own
    r = subprocess.run([str(BIN / "cab-plugins"), "--json"], capture_output=True, text=True,
                       env=_env(site), cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    row = {x["plugin"]: x for x in json.loads(r.stdout)}["example_block_on_pad"]
    assert row["distribution"] == "cab-example-block-on-pad"
    assert row["tasks"] == {"example_block_on_pad": ["block_on_pad"]}
    r = subprocess.run([str(BIN / "cab-plugins")], capture_output=True, text=True, env=_env(), cwd=tmp_path,
                       timeout=300)
    assert "example_block_on_pad" not in r.stdout  # without PYTHONPATH: not installed
