"""The fault rule (cab_core/attempt/faults.py) and total validation at the tool boundary: every input an agent
can send gets a success or a typed error, directly and from run_code, and the attempt goes on; only
a broken host ends an attempt as an infrastructure failure, which sweeps retry and reports exclude.
Each reproduction of issue 12 is one test here, on MuJoCo (the fastest simulator to start)."""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_module

from cab_core import geometry
from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.engine import faults
from cab_core.attempt.engine.episode import Episode
from cab_core.attempt.runner import attempt_spec
from cab_core.errors import InfrastructureFault, SimulatorError
from cab_core.plugins import all_tasks, create
from cab_core.tools import TOOLS

pytestmark = pytest.mark.sim

HUGE = 1e308


def _episode(out: Path, *overrides) -> Episode:
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(
            ["sim=mujoco", "task=click_bell", "record.video=false", "budget.tool_calls=200", *overrides]))
    s = attempt_spec(cfg, out)
    return Episode(s, all_tasks()[s.task], create("simulators", s.sim, s.sim_cfg), create("planners", s.planner, {}),
                   create("embodiments", s.embodiment, {}))


@pytest.fixture(scope="module")
def ep(tmp_path_factory):
    e = _episode(tmp_path_factory.mktemp("faults"))
    yield e
    e.close()


@pytest.fixture(scope="module")
def head(ep):
    return ep.call("capture_head").payload["obs_id"]


def _used(ep) -> int:
    return ep.ledger.summary()["tool_calls_used"]


def _call(ep, name, args):
    """One direct call: charged exactly once, the attempt goes on."""
    before = _used(ep)
    r = ep.call(name, args)
    assert _used(ep) == before + 1
    assert not r.ended and not ep.ended
    return r.payload


def _refused(ep, name, args, *fragments):
    p = _call(ep, name, args)
    assert p["code"] == "invalid_tool_arguments", p
    for f in fragments:
        assert f in p["error"], p["error"]
    return p


# -- the reproductions of the issue ---------------------------------------------------------------
def test_huge_coordinates_are_refused_not_crashing(ep, head):
    _refused(ep, "project", {"obs_id": head, "xyz": [-HUGE] * 3}, "xyz.0", "greater than or equal to -10")
    _refused(ep, "camera_aim_pose", {"camera": "left_camera", "target_xyz": [HUGE] * 3},
             "target_xyz.0", "less than or equal to 10")
    _refused(ep, "ray", {"obs_id": head, "px": [HUGE, HUGE]}, "px.0", "less than or equal to 10000")
    _refused(ep, "plane_intersect", {"obs_id": head, "px": [320, 240], "plane_point_xyz": [0, 0, -HUGE],
                                     "plane_normal_xyz": [0, 0, 1], "plane_offset_sigma_m": 0.01}, "plane_point_xyz.2")
    _refused(ep, "move_delta", {"arm": "left", "dz": HUGE}, "dz")
    _refused(ep, "move_both_delta", {"left_delta": [0, 0, HUGE], "right_delta": [0, 0, 0]}, "left_delta.2")
    assert ep.termination is None and ep.tool_errors == 0


def test_wrong_types_are_refused_not_coerced(ep):
    _refused(ep, "set_gripper", {"arm": "left", "pos": "0.1"}, "pos: Input should be a valid number", "'0.1'")
    _refused(ep, "move_delta", {"arm": "left", "dz": True}, "dz: Input should be a valid number", "True")
    _refused(ep, "move_delta", {"arm": "left", "dz": None}, "dz")
    _refused(ep, "get_robot_state", {"arms": "left"}, "arms")
    _refused(ep, "get_arm_pose", [1, 2], "arguments must be a JSON object, got list")
    _refused(ep, "move_delta", {"arm": "left", "dz": 10 ** 400}, "dz")


def test_done_enforces_its_schema_and_the_attempt_goes_on(ep):
    r = ep.call("done", {"report": "x" * 1_000_000, "success_claim": False})
    assert r.payload["code"] == "invalid_tool_arguments" and "report" in r.payload["error"]
    assert "at most 20000 characters" in r.payload["error"]
    assert not r.ended and not ep.ended
    r = ep.call("done", {"report": "ok", "success_claim": "yes"})
    assert r.payload["code"] == "invalid_tool_arguments" and "success_claim" in r.payload["error"]
    assert not ep.ended


def test_motion_clamp_holds_for_any_finite_input(ep):
    p = _call(ep, "move_delta", {"arm": "left", "dz": 10.0})
    c = p["commanded"]
    assert c["clamped"] is True and c["delta_m"] == [0.0, 0.0, 10.0]
    assert c["applied_delta_m"] == pytest.approx([0.0, 0.0, 0.30], abs=1e-9)
    p = _call(ep, "move_both_delta", {"left_delta": [-10, 10, 0], "right_delta": [0, 0, 0.01]})
    left = p["commanded"]["left"]
    assert left["clamped"] is True
    assert np.linalg.norm(left["applied_delta_m"]) == pytest.approx(0.30, abs=1e-5)  # rounded to 5 decimals
    assert left["applied_delta_m"][0] == pytest.approx(-left["applied_delta_m"][1])


def test_degenerate_geometry_says_so(ep, head):
    p = _call(ep, "ray", {"obs_id": head, "px": [9999, -9999]})
    assert p["valid"] is True and np.linalg.norm(p["value"]["dir"]) == pytest.approx(1.0, abs=1e-6)
    # the head camera looks forward and down: a near-horizontal plane far below the table
    p = _call(ep, "plane_intersect", {"obs_id": head, "px": [320, 0], "plane_point_xyz": [0, 0, -9.0],
                                      "plane_normal_xyz": [0, 0, 1], "plane_offset_sigma_m": 0.01})
    assert p["valid"] is False and p["failure"]["code"] == "OUTSIDE_WORKSPACE"
    assert p["value"] is not None and p["value"][2] == pytest.approx(-9.0, abs=1e-6)
    p = _call(ep, "plane_intersect", {"obs_id": head, "px": [320, 300], "plane_point_xyz": [0, 0, 0.75],
                                      "plane_normal_xyz": [0, 0, 1], "plane_offset_sigma_m": 0.01})
    assert p["valid"] is True and p["failure"] is None and p["value"][2] == pytest.approx(0.75, abs=1e-6)
    d = geometry.pixel_ray(np.eye(3), np.hstack([np.eye(3), np.zeros((3, 1))]), [np.inf, 0.0])[1]
    assert geometry.degenerate_direction(d)


@pytest.mark.parametrize("bbox, extent, code", [
    ([100, 100, 100.0000001, 100.0000001], 10.0, "DEGENERATE_GEOMETRY"),  # a sub-pixel box: no scale
    ([-0.0005, -770.2, -5.4e-195, 1650.9], 1e-6, "DEGENERATE_GEOMETRY"),  # a depth of 0.3 micrometres
    ([300, 200, 302, 202], 10.0, "OUTSIDE_WORKSPACE"),  # a 10 m object 2 px wide: kilometres away
    ([300, 200, 340, 260], 0.05, None),  # a 5 cm object 40 px wide on the table
])
def test_scale_from_object_size_flags_degenerate_boxes(ep, head, bbox, extent, code):
    p = _call(ep, "scale_from_object_size", {"obs_id": head, "bbox": bbox, "extent_axis": "width",
                                             "known_extent_m": extent})
    assert (p["failure"] or {}).get("code") == code
    assert p["valid"] is (code is None)
    if code is None:
        assert 0.5 < p["value"] < 2.0


def test_schema_declares_every_numeric_range():
    def walk(node, path):
        if isinstance(node, dict):
            if node.get("type") == "number":
                assert ("minimum" in node or "exclusiveMinimum" in node) and "maximum" in node, path
            for k, v in node.items():
                walk(v, f"{path}.{k}")
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{path}[{i}]")

    for name, t in TOOLS.items():
        walk(t.json_schema(), name)


# -- the fault rule --------------------------------------------------------------------------------
def _raise_in(monkeypatch, ep, tool: str, exc: BaseException):
    """Make ``tool``'s handler raise ``exc`` in the registry ``ep`` serves its calls from."""
    def boom(ctx, args):
        raise exc

    monkeypatch.setitem(ep.registry, tool, dataclasses.replace(ep.registry[tool], handler=boom))


def test_an_exception_while_serving_a_call_is_the_agents_tool_error(ep, monkeypatch):
    n0 = ep.tool_errors
    _raise_in(monkeypatch, ep, "get_arm_pose", ValueError(f"degenerate quaternion at {Path(__file__).resolve()}"))
    p = _call(ep, "get_arm_pose", {"arm": "left"})
    assert p["code"] == "tool_error"
    assert p["error"].startswith("tool error: get_arm_pose could not complete this call (ValueError: ")
    assert "<path>" in p["error"] and str(Path(__file__).parent) not in p["error"] and "Traceback" not in p["error"]
    # the same from inside a program: the program sees the error payload, run_code goes on
    p = _call(ep, "run_code", {"code": "r = get_arm_pose(arm='left')\nresult = r"})
    assert p["ok"] is True and p["value"]["code"] == "tool_error"
    assert ep.tool_errors == n0 + 2 and not ep.ended
    rec = [json.loads(line) for line in (ep.out / "events.jsonl").read_text().splitlines()]
    errs = [e for e in rec if e["kind"] == "tool_error"][-2:]
    assert [e["direct"] for e in errs] == [True, False]
    assert all("Traceback" in e["traceback"] for e in errs)  # host-only record keeps the whole story


@pytest.mark.parametrize("exc", [SimulatorError("physics blew up"), KeyError("x"), ZeroDivisionError()],
                         ids=lambda e: type(e).__name__)
def test_simulator_and_library_errors_are_tool_errors(ep, monkeypatch, exc):
    _raise_in(monkeypatch, ep, "capture_head", exc)
    assert _call(ep, "capture_head", {})["code"] == "tool_error"


@pytest.mark.parametrize("exc", [InfrastructureFault("renderer process died"), MemoryError(),
                                 OSError(28, "No space left on device")], ids=lambda e: type(e).__name__)
def test_only_a_broken_host_ends_the_attempt_as_an_infrastructure_fault(tmp_path, monkeypatch, exc):
    assert faults.is_infrastructure_fault(exc)
    e = _episode(tmp_path)
    try:
        _raise_in(monkeypatch, e, "get_arm_pose", exc)
        r = e.call("get_arm_pose", {"arm": "left"})
        assert r.ended and e.termination["reason"] == "host_fault"
        assert "not your doing" in r.payload["error"]
        res = e.finish()
    finally:
        e.close()
    assert faults.is_infrastructure_termination(res["termination"]["reason"])


def test_infrastructure_fault_inside_a_program_ends_the_attempt(tmp_path, monkeypatch):
    e = _episode(tmp_path)
    try:
        _raise_in(monkeypatch, e, "get_arm_pose", InfrastructureFault("simulator server stopped answering"))
        r = e.call("run_code", {"code": "get_arm_pose(arm='left')"})
        assert r.ended and e.termination["reason"] == "host_fault"
    finally:
        e.close()


def test_classification_is_by_type():
    assert not faults.is_infrastructure_fault(ValueError("x"))
    assert not faults.is_infrastructure_fault(OSError(2, "No such file"))
    assert not faults.is_infrastructure_fault(SimulatorError("bad"))
    assert faults.agent_message(ValueError("a\nb " + "c" * 400)).startswith("ValueError: a b c")
    assert len(faults.agent_message(ValueError("c" * 400))) <= len("ValueError: ") + faults.MESSAGE_CHARS
    assert "error" in faults.INFRASTRUCTURE_TERMINATIONS  # older records stay excluded
    assert "harness_error" not in faults.INFRASTRUCTURE_TERMINATIONS


# -- a sweep cannot re-roll an attempt with bad input ----------------------------------------------
CRASHERS = [
    {"tool": "capture_head", "args": {}},
    {"tool": "camera_aim_pose", "args": {"camera": "left_camera", "target_xyz": [HUGE] * 3}},
    {"tool": "project", "args": {"obs_id": "obs_0001", "xyz": [-HUGE] * 3}},
    {"tool": "move_delta", "args": {"arm": "left", "dz": HUGE}},
    {"tool": "ray", "args": {"obs_id": "obs_0001", "px": [HUGE, HUGE]}},
    {"tool": "set_gripper", "args": {"arm": "left", "pos": "0.1"}},
    {"tool": "move_delta", "args": {"arm": "left", "dz": True}},
    {"tool": "move_both_delta", "args": {"left_delta": [0, 0, HUGE], "right_delta": [0, 0, 0]}},
    {"tool": "plane_intersect", "args": {"obs_id": "obs_0001", "px": [320, 240], "plane_point_xyz": [0, 0, -HUGE],
                                         "plane_normal_xyz": [0, 0, 1], "plane_offset_sigma_m": 0.01}},
    {"tool": "done", "args": {"report": "x" * 1_000_000}},  # refused (over 20000 characters): free, goes on
    {"tool": "run_code", "args": {"code": "camera_aim_pose(camera='left_camera', target_xyz=[1e308]*3)\n"
                                          "project(obs_id='obs_0001', xyz=[-1e308]*3)\nresult = 1"}},
    {"tool": "done", "args": {"report": "tried", "success_claim": True}},
]


def test_a_sweep_scores_the_attempt_of_a_script_sending_bad_numbers(tmp_path):
    script = tmp_path / "crash.jsonl"
    script.write_text("\n".join(json.dumps(c) for c in CRASHERS) + "\n")
    sweep = tmp_path / "sweep"
    env = {**os.environ, "HYDRA_FULL_ERROR": "0"}
    cab = Path(sys.executable).parent / "cab"
    p = subprocess.run([str(cab), "-m", "task=click_bell", "sim=mujoco", "model=scripted", f"model.script={script}",
                        "record.video=false", "sweep.retry_backoff_s=0", f"hydra.sweep.dir={sweep}"],
                       capture_output=True, text=True, env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    results = [json.loads(r.read_text()) for r in sweep.rglob("result.json") if "set_aside" not in r.parts]
    assert len(results) == 1
    res = results[0]
    assert res["termination"]["reason"] == "done" and res["verdict"]["success"] is False
    assert res["claim"]["success_claim"] is True
    assert res["budget"]["tool_calls_used"] == len(CRASHERS) - 2  # done is free
    assert "infrastructure" not in res or res["infrastructure"]["failures"] == []
    assert not list(sweep.rglob("set_aside"))
    rep = subprocess.run([str(cab.parent / "cab-report"), str(sweep), "--no-views"], capture_output=True,
                         text=True, timeout=300)
    assert rep.returncode == 0, rep.stderr
    report = json.loads((sweep / "report.json").read_text())
    assert report["excluded"] == [] and report["problems"] == []
    assert report["attempts"] == 1
    assert [(c["attempts"], c["successes"]) for c in report["configs"]] == [(1, 0)]
