"""Exports of records (``cab-export``, docs/export.md): an attempt as a Rerun recording (the plugin
``cab-export-rerun``, as a record observer and as an exporter), read back with the Rerun SDK; a sweep
as attempts.parquet and calls.parquet, read back with pandas. Expected values come from the record
files directly (result.json, events.jsonl, privileged/snapshots.jsonl, observations/, programs/)."""
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from attempt_records import events, results, run_one

from cab_core.apps import export as ex
from cab_core.plugins import registry, select_record_observers

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = [  # wrist images, an annotated image, joint states, a refusal, a bad argument, two programs
    {"tool": "capture_head", "args": {}},
    {"tool": "capture_wrist", "args": {"active_arm": "none", "views": "both"}},
    {"tool": "get_robot_state", "args": {"arms": ["left", "right"]}},
    {"tool": "get_world_frame", "args": {}},
    {"tool": "reach_tcp", "args": {"arm": "left", "target_xyz": [0.0, 0.7, 1.45]}},
    {"tool": "move_delta", "args": {"arm": "left", "dx": 0.0, "dy": 0.0, "dz": "x"}},
    {"tool": "run_code", "args": {"code": "p = get_arm_pose(arm='left')\nraise ValueError('no block found')\n"}},
    {"tool": "run_code", "args": {"code": "r = move_delta(arm='right', dx=0.0, dy=0.0, dz=-0.05)\n"
                                          "img = capture_head()\nresult = r['status']\n"}},
    {"tool": "done", "args": {"report": "moved the right arm down", "success_claim": True}},
]


def _snapshots(d: Path) -> list[dict]:
    return [json.loads(line) for line in (d / "privileged" / "snapshots.jsonl").read_text().splitlines() if line.strip()]


@pytest.fixture(scope="module")
def attempts(tmp_path_factory):
    """An oracle attempt and a scripted one on MuJoCo, each with the rerun observer on."""
    pytest.importorskip("rerun")
    root = tmp_path_factory.mktemp("rerun")
    script = root / "script.json"
    script.write_text(json.dumps(SCRIPT))
    run_one(root / "oracle", "click_bell", "oracle", 1, "sim=mujoco", "record.observers=[rerun]")
    run_one(root / "scripted", "beat_block_hammer", "scripted", 1, "sim=mujoco", "record.observers=[rerun]",
            f"model.script={script}")
    return root


def _rrd(path: Path):
    """A recording read back with rerun-sdk's reader (``cab_export_rerun.readback``, on ``rerun.chunk``)."""
    from cab_export_rerun.readback import Recording

    return Recording(path)


def _expected_paths(d: Path) -> set[str]:
    snap = _snapshots(d)[0]
    paths = {"/world", "/attempt/result", "/attempt/instruction", "/attempt/scene_info", "/log/calls", "/log/events",
             "/log/verdict", "/log/checkpoints", "/video", "/world/cameras/head_camera", "/world/cameras/head_camera/image"}
    paths |= {f"/world/robot/{a}/tcp" for a in snap["arms"]} | {f"/robot/{a}/gripper_cmd" for a in snap["arms"]}
    paths |= {f"/robot/{a}/finger_gap_m" for a in snap["arms"]} | {f"/world/objects/{o}" for o in snap["objects"]}
    return paths


@pytest.mark.sim
@pytest.mark.parametrize("name", ["oracle", "scripted"])
def test_an_attempt_as_a_rerun_recording(attempts, name, tmp_path):
    d = attempts / name
    result = json.loads((d / "result.json").read_text())
    ev = events(d)
    snaps = _snapshots(d)
    pngs = sorted(p.stem for p in (d / "observations").glob("*.png"))
    programs = sorted(p.stem for p in (d / "programs").glob("*.py"))
    assert (d / "attempt.rrd").stat().st_size > 0  # written by the observer at the attempt's end
    assert not any(e["kind"] == "observer_detached" for e in ev)

    # the same converter through cab-export, into another folder
    ex.main(["rerun", str(d), "--out", str(tmp_path)])
    for rrd in (d / "attempt.rrd", tmp_path / "attempt.rrd"):
        r = _rrd(rrd)
        assert _expected_paths(d) <= r.entities
        # every image the agent saw, once, under its camera, each at the event that took it
        cams = sorted(p for p in r.entities if re.fullmatch(r"/world/cameras/[^/]+/(image|annotated)", p))
        shown = sum(len(r.rows(p, "EncodedImage:blob", "event")) for p in cams)
        assert shown == len(pngs) == result["counts"]["observations"]
        took = {o for e in ev if e["kind"] in ("call", "internal_call") for o in e.get("obs_ids") or []}
        assert took == set(pngs)
        # one log entry per call and per internal call, in the events' order
        calls = [e for e in ev if e["kind"] == "call"]
        texts = [t[0] for t in r.rows("/log/calls", "TextLog:text", "event")]
        assert len(texts) == len(calls) and all(t.startswith(f"#{e['seq']} {e['tool']}(") for t, e in zip(texts, calls))
        internal = [e for e in ev if e["kind"] == "internal_call"]
        assert len(r.rows("/log/internal_calls", "TextLog:text", "event")) == len(internal)
        others = [e for e in ev if e["kind"] not in ("call", "internal_call")]
        assert len(r.rows("/log/events", "TextLog:text", "event")) == len(others)
        # a TCP transform per arm and snapshot; object poses and gripper state too
        for arm in snaps[0]["arms"]:
            tcp = r.rows(f"/world/robot/{arm}/tcp", "Transform3D:translation", "snapshot")
            assert len(tcp) == len(snaps)
            assert [round(v, 5) for v in tcp[-1][0]] == [round(v, 5) for v in snaps[-1]["arms"][arm]["tcp_pose"][:3]]
            assert len(r.rows(f"/robot/{arm}/gripper_cmd", "Scalars:scalars", "snapshot")) == len(snaps)
        for obj in snaps[0]["objects"]:
            assert len(r.rows(f"/world/objects/{obj}", "Transform3D:translation", "snapshot")) == len(snaps)
        # the recording camera's frames, on simulated time
        assert len(r.rows("/video", "VideoFrameReference:timestamp", "sim_time")) == result["video"]["frames"]
        # checkpoints, programs, verdict
        ck = result["checkpoints"]
        assert len(r.rows("/log/checkpoints", "TextLog:text", "checkpoint")) == len(ck["subgoals"]) + len(ck["spatial"])
        assert sorted(p.rsplit("/", 1)[1] for p in r.entities if p.startswith("/programs/")) == programs
        assert len(r.rows("/log/verdict", "TextLog:text", "sim_time")) == 1
    cli = Path(sys.executable).parent / "rerun"  # the SDK's own command line: the file loads in its viewer
    if cli.exists():
        out = subprocess.run([str(cli), "rrd", "verify", str(d / "attempt.rrd")], capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
    if name == "scripted":
        r = _rrd(d / "attempt.rrd")
        assert programs == ["prog_001", "prog_002"] and internal
        assert {"/world/cameras/left_camera/image", "/world/cameras/right_camera/image",
                "/world/cameras/head_camera/annotated"} <= r.entities
        assert any(p.startswith("/robot/left/joints/") for p in r.entities)  # get_robot_state's joint positions
        levels = [t[0] for t in r.rows("/log/calls", "TextLog:level", "event")]
        assert "ERROR" in levels and "WARN" in levels  # the bad argument, the refused reach


def test_the_rerun_observer_is_off_by_default_and_selectable():
    pytest.importorskip("cab_export_rerun")
    assert "rerun" in registry("record_observers") and "rerun" in registry("record_exporters")
    assert "rerun" not in [s.name for s in select_record_observers({"observers": None})]
    assert "rerun" not in [s.name for s in select_record_observers({})]
    assert [s.name for s in select_record_observers({"observers": ["rerun"]})] == ["rerun"]
    assert [(s.name, s.cfg) for s in select_record_observers({"observers": {"rerun": {"video": False}}})] == \
        [("rerun", {"video": False})]


def test_an_exporter_that_is_not_installed_is_one_line(capsys, monkeypatch):
    with pytest.raises(SystemExit) as e:
        ex.main(["nosuchformat", str(ROOT)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cab-export: no exporter 'nosuchformat' is installed (installed: parquet")
    assert "install it with: pip install" in err[0]
    # a format the checkout ships as a plugin, not installed: the command that installs it
    monkeypatch.setattr(ex, "exporters", lambda: {})
    monkeypatch.setattr(ex, "sweep_exporters", lambda: {})
    with pytest.raises(SystemExit):
        ex.main(["rerun", str(ROOT)])
    err = capsys.readouterr().err.strip()
    assert err == f"cab-export: no exporter 'rerun' is installed (installed: parquet, leaderboard); install it with: " \
                  f"pip install -e {ROOT / 'plugins' / 'export_rerun'}"


def test_the_core_does_not_import_the_exporter_plugin():
    src = (ROOT / "cab_core" / "apps" / "export.py").read_text()
    assert "rerun" not in src.lower()


# -- parquet ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tables(sweep, tmp_path_factory):
    pd = pytest.importorskip("pandas")
    out = tmp_path_factory.mktemp("parquet")
    ex.main(["parquet", str(sweep), "--out", str(out)])
    return pd.read_parquet(out / ex.ATTEMPTS_FILE), pd.read_parquet(out / ex.CALLS_FILE)


@pytest.mark.sim
def test_a_sweep_as_parquet(sweep, tables):
    attempts, calls = tables
    res = results(sweep)
    assert len(attempts) == len(res) == 10
    assert list(attempts.columns) == [c for c, _, _ in ex.ATTEMPT_COLUMNS]
    assert list(calls.columns) == [c for c, _, _ in ex.CALL_COLUMNS]
    by_key = attempts.set_index("attempt_key")
    call_events = 0
    for p in sorted(sweep.glob("*/*/seed-*/attempt-*/result.json")):
        r = json.loads(p.read_text())
        key = p.parent.relative_to(sweep).as_posix()
        row = by_key.loc[key]
        assert row["config"] == f"{r['model']} ({r['harness']}, {r['sim']})"
        for col, value in [("task", r["task"]), ("model", r["model"]), ("harness", r["harness"]), ("sim", r["sim"]),
                           ("seed", r["seed"]), ("attempt", r["attempt"]), ("success", r["verdict"]["success"]),
                           ("termination_reason", r["termination"]["reason"]),
                           ("tool_calls_used", r["budget"]["tool_calls_used"]),
                           ("tool_calls_limit", r["budget"]["tool_calls_limit"]),
                           ("sim_seconds_used", r["budget"]["sim_seconds_used"]),
                           ("wall_seconds", r["timing"]["wall_seconds"]),
                           ("subgoal_coverage", r["checkpoints"]["subgoal_coverage"]),
                           ("spatial_coverage", r["checkpoints"]["spatial_coverage"])]:
            assert row[col] == value, (key, col)
        claim = r["claim"]["success_claim"]
        assert (row["success_claim"] is None or row["success_claim"] != row["success_claim"]) if claim is None \
            else row["success_claim"] == claim
        ev = [e for e in events(p.parent) if e["kind"] in ("call", "internal_call")]
        call_events += len(ev)
        mine = calls[calls["attempt_key"] == key].sort_values("seq")
        assert list(mine["seq"]) == [e["seq"] for e in ev]
        assert list(mine["tool"]) == [e["tool"] for e in ev] and list(mine["kind"]) == [e["kind"] for e in ev]
        assert [json.loads(a) for a in mine["arguments"]] == [e["arguments"] for e in ev]
        assert int(mine["charged"].sum()) == r["budget"]["tool_calls_used"]
        # a run_code call's steps include its internal calls'
        assert int(mine[mine["kind"] == "call"]["physics_steps"].sum()) == r["budget"]["physics_steps"]
    assert len(calls) == call_events
    assert str(attempts["seed"].dtype) == "int64" and str(attempts["success"].dtype) == "bool"
    assert attempts["cost_usd"].isna().all()  # model-free agents record no cost
    scripted = calls[calls["attempt_key"].str.contains("/scripted/")]
    assert set(scripted["kind"]) == {"call", "internal_call"} and scripted["program"].notna().any()
    assert scripted["error_code"].notna().any() or (scripted["status"] == "FAILED").any()


@pytest.mark.sim
def test_a_sweep_as_rerun_recordings(sweep, tmp_path):
    pytest.importorskip("rerun")
    ex.main(["rerun", str(sweep), "--out", str(tmp_path)])
    written = sorted(p.parent.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("attempt.rrd"))
    assert written == sorted(p.parent.relative_to(sweep).as_posix() for p in sweep.glob("*/*/seed-*/attempt-*/result.json"))


def test_the_docs_list_every_column():
    doc = (ROOT / "docs" / "export.md").read_text()
    for columns in (ex.ATTEMPT_COLUMNS, ex.CALL_COLUMNS):
        for name, kind, _ in columns:
            assert re.search(rf"^\| `{name}` \| {kind} \|", doc, re.M), name
