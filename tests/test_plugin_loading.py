"""Entry points of group ``cab`` load one at a time: a broken one is named in one line with the fix,
and ``CAB_DISABLE_PLUGINS`` disables plugins by entry point or distribution name."""
import json
import os
import subprocess
import sys
from importlib import metadata

import pytest

from cab_core.plugins import build_plugin_manager, describe, distribution_versions, registry

CAB_PLUGINS = [sys.executable, "-c", "from cab_core.apps.cli import plugins_main; plugins_main()"]


def _fake_distribution(root, dist: str, ep_name: str, target: str, module_source: str | None = None) -> None:
    """A real installed distribution on ``root``: its dist-info (METADATA, entry_points.txt) and,
    if given, the module its entry point names."""
    info = root / f"{dist.replace('-', '_')}-0.3.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.3\n")
    (info / "entry_points.txt").write_text(f"[cab]\n{ep_name} = {target}\n")
    if module_source is not None:
        (root / f"{target.split('.')[0]}.py").write_text(module_source)


def _run(cmd, root, **env):
    e = {k: v for k, v in os.environ.items() if k not in ("CAB_DISABLE_PLUGINS", "CAB_DISABLE_PLUGIN_AUTOLOAD")}
    e.update(PYTHONPATH=str(root), **env)
    return subprocess.run(cmd, capture_output=True, text=True, env=e, timeout=120)


@pytest.fixture
def broken(tmp_path):
    """A distribution whose entry point module does not exist."""
    _fake_distribution(tmp_path, "cab-broken-fixture", "broken_fixture", "cab_no_such_module_xyz.plugin")
    return tmp_path


def test_a_broken_entry_point_is_named_in_one_line(broken):
    r = _run(CAB_PLUGINS, broken)
    assert r.returncode == 1
    assert r.stdout == ""
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    line = lines[0]
    assert line.startswith("cab-plugins: plugin 'broken_fixture' (distribution cab-broken-fixture, ")
    assert "entry point broken_fixture = cab_no_such_module_xyz.plugin" in line
    assert "ModuleNotFoundError: No module named 'cab_no_such_module_xyz'" in line
    assert "pip install --force-reinstall cab-broken-fixture" in line
    assert line.endswith("or disable it with CAB_DISABLE_PLUGINS=broken_fixture")


@pytest.mark.parametrize("name", ["broken_fixture", "cab-broken-fixture", "Cab_Broken.Fixture"])
def test_a_disabled_plugin_is_not_loaded_and_listed_as_disabled(broken, name):
    r = _run(CAB_PLUGINS, broken, CAB_DISABLE_PLUGINS=f" other ,{name}")
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line and not line.startswith(" ")}
    assert rows["broken_fixture"].split() == ["broken_fixture", "cab-broken-fixture", "0.3", "(disabled)"]
    assert "(disabled)" not in rows["core"]  # everything else is there and enabled
    r = _run(CAB_PLUGINS + ["--json"], broken, CAB_DISABLE_PLUGINS=name)
    by_name = {row["plugin"]: row for row in json.loads(r.stdout)}
    assert by_name["broken_fixture"] == {"plugin": "broken_fixture", "distribution": "cab-broken-fixture",
                                         "version": "0.3", "provides": {}, "hooks": [], "disabled": True,
                                         "defaults": {}}
    assert by_name["core"]["disabled"] is False and "direct" in by_name["core"]["provides"]["harnesses"]


def test_a_plugin_that_imports_but_does_not_register_is_named(tmp_path):
    """A misspelled hook fails pluggy's validation at registration: named the same way."""
    _fake_distribution(tmp_path, "cab-misspelt", "misspelt", "cab_misspelt_fixture",
                       "from cab_core import hookimpl\n\n@hookimpl\ndef cab_simulatorz():\n    return {}\n")
    r = _run(CAB_PLUGINS, tmp_path)
    assert r.returncode == 1
    assert len(r.stderr.splitlines()) == 1
    assert "plugin 'misspelt' (distribution cab-misspelt, entry point misspelt = cab_misspelt_fixture" in r.stderr
    assert "PluginValidationError" in r.stderr and "cab_simulatorz" in r.stderr
    assert _run(CAB_PLUGINS, tmp_path, CAB_DISABLE_PLUGINS="misspelt").returncode == 0


def test_an_attempt_with_a_broken_plugin_fails_in_one_line_and_runs_with_it_disabled(broken, tmp_path):
    cab = [os.path.join(os.path.dirname(sys.executable), "cab"), "task=click_bell", "model=idle", "sim=mujoco"]
    r = _run(cab + [f"hydra.run.dir={tmp_path / 'a'}"], broken)
    assert r.returncode == 2  # a broken installation: refused with the command, before anything starts
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("cab: plugin 'broken_fixture' (distribution cab-broken-fixture, entry point "
                               "broken_fixture = cab_no_such_module_xyz.plugin in group 'cab') failed to load: ")
    assert not (tmp_path / "a" / "result.json").exists()
    r = _run(cab + [f"hydra.run.dir={tmp_path / 'b'}", "record.video=false"], broken, CAB_DISABLE_PLUGINS="broken_fixture")
    assert r.returncode == 0, r.stderr
    result = json.loads((tmp_path / "b" / "result.json").read_text())
    assert result["termination"]["reason"] == "done"


def test_disabling_an_installed_plugin_removes_what_it_provides(monkeypatch):
    sims = set(registry("simulators", build_plugin_manager()))
    assert {"pybullet", "mujoco"} <= sims
    monkeypatch.setenv("CAB_DISABLE_PLUGINS", "sim_pybullet")
    pm = build_plugin_manager()
    assert pm.is_blocked("sim_pybullet")
    assert set(registry("simulators", pm)) == sims - {"pybullet"}
    assert [r["disabled"] for r in describe(pm) if r["plugin"] == "sim_pybullet"] == [True]
    assert "cab-sim-pybullet" not in distribution_versions()


def test_versions_are_the_distributions_of_the_installed_entry_points(monkeypatch):
    monkeypatch.delenv("CAB_DISABLE_PLUGINS", raising=False)
    expected = {ep.dist.name: ep.dist.version for ep in metadata.entry_points(group="cab")}
    versions = distribution_versions()
    assert versions == expected
    core = metadata.distribution(next(ep for ep in metadata.entry_points(group="cab")
                                      if ep.module.startswith("cab_core.")).dist.name)
    assert list(versions)[0] == core.name  # the core's own first
