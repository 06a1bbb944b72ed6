"""cab-replay: an oracle attempt re-executed from its records validates; a tampered record does not,
with a message that says what differs; --regrade recomputes analyses without a simulator."""
import json
import shutil

import pytest
from attempt_records import TASKS, attempt_dir, events, shared_sweep

from cab_core.analysis.attempts import Attempt, read_jsonl, scan
from cab_core.apps import replay as rp
from cab_core.errors import RecordError

pytestmark = pytest.mark.sim


def copy_attempt(tmp_path_factory, task: str, model: str, name: str):
    src = attempt_dir(shared_sweep(tmp_path_factory), task, model, 1)
    d = tmp_path_factory.mktemp(name) / "attempt"
    shutil.copytree(src, d, ignore=shutil.ignore_patterns("view.html", "replay*"))
    return d


@pytest.fixture(scope="module")
def oracle(tmp_path_factory):
    return copy_attempt(tmp_path_factory, TASKS[0], "oracle", "oracle")


@pytest.fixture(scope="module")
def replayed(oracle):
    return rp.replay(oracle)


def test_oracle_replay_validates(oracle, replayed):
    v = replayed
    assert v.valid, v.mismatches
    ev = events(oracle)
    assert v.calls_compared == sum(e["kind"] in rp.CALL_KINDS for e in ev)
    assert v.snapshots_compared == len(read_jsonl(oracle / "privileged" / "snapshots.jsonl"))
    assert v.max_tcp_error_m <= rp.TOLERANCE_M and v.max_object_error_m <= rp.TOLERANCE_M
    assert v.original_success is True and v.replay_success is True
    out = oracle / "replay"
    saved = json.loads((out / "replay.json").read_text())
    assert saved["valid"] is True and saved["replay_dir"] == "replay" and saved["attempt"] == "attempt"
    # the replay's records are nested in the attempt: no analysis counts them as another attempt
    assert [a.rel for a in scan(oracle.parent).attempts] == ["attempt"]


def tampered(src, tmp_path, edit_events=None, edit_snapshots=None, edit_result=None) -> Attempt:
    d = tmp_path / "tampered"
    shutil.copytree(src, d, ignore=shutil.ignore_patterns("replay*", "*.mp4", "observations"))
    for name, edit in (("events.jsonl", edit_events), ("privileged/snapshots.jsonl", edit_snapshots)):
        if edit:
            rows = read_jsonl(d / name)
            edit(rows)
            (d / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
    if edit_result:
        r = json.loads((d / "result.json").read_text())
        edit_result(r)
        (d / "result.json").write_text(json.dumps(r))
    return Attempt.load(d)


def test_a_moved_object_fails_validation(oracle, replayed, tmp_path):
    def move(snaps):
        snaps[3]["objects"]["block"]["pose"][0] += 0.02

    v = rp.validate(tampered(oracle, tmp_path, edit_snapshots=move), Attempt.load(oracle / "replay"))
    assert not v.valid
    assert v.mismatches == [f"snapshot 3 ({read_jsonl(oracle / 'privileged/snapshots.jsonl')[3]['label']}): "
                            "object 'block' 20.0 mm from the recorded position"]


def test_a_changed_status_order_or_verdict_fails_validation(oracle, replayed, tmp_path):
    def status(evs):
        e = next(e for e in evs if e.get("tool") == "reach_tcp")
        e["status"] = "FAILED"

    v = rp.validate(tampered(oracle, tmp_path / "s", edit_events=status), Attempt.load(oracle / "replay"))
    assert not v.valid and v.mismatches[0].endswith("(reach_tcp): status 'FAILED' recorded, 'SUCCESS' in the replay")

    def order(evs):
        e = next(e for e in evs if e.get("tool") == "set_gripper")
        e["tool"] = "move_delta"

    v = rp.validate(tampered(oracle, tmp_path / "o", edit_events=order), Attempt.load(oracle / "replay"))
    assert not v.valid and "the replay made call 'set_gripper' instead" in v.mismatches[0]

    def verdict(r):
        r["verdict"]["success"] = False

    v = rp.validate(tampered(oracle, tmp_path / "v", edit_result=verdict), Attempt.load(oracle / "replay"))
    assert v.mismatches == ["verdict success=False recorded, success=True in the replay"]


def test_records_without_the_configuration_are_refused(oracle, tmp_path):
    def strip(evs):
        evs[0].pop("config")

    a = tampered(oracle, tmp_path, edit_events=strip)
    with pytest.raises(RecordError, match="lack the resolved configuration"):
        rp.replay(a.dir)


def test_regrade_without_a_simulator(oracle, tmp_path):
    g = rp.regrade(oracle)
    assert g["checkpoints_changed"] == [] and g["claim"] == "correct" and g["failure_stage"] is None
    assert g["checkpoints"]["spatial_coverage"] == 1.0

    def away(snaps):  # the left TCP never comes near anything
        for s in snaps:
            s["arms"]["left"]["tcp_pose"][:3] = [-0.6, -0.4, 1.3]

    g = rp.regrade(tampered(oracle, tmp_path, edit_snapshots=away).dir)
    assert "spatial 1: attained False (recorded True)" in g["checkpoints_changed"]


def test_cli_replays_a_scripted_attempt(tmp_path_factory, capsys):
    d = copy_attempt(tmp_path_factory, TASKS[0], "scripted", "scripted")
    with pytest.raises(SystemExit) as e:
        rp.main([str(d), "--out", str(d / "again")])
    out = capsys.readouterr().out
    assert e.value.code == 0, out
    n = sum(e["kind"] in rp.CALL_KINDS for e in events(d))
    assert out.startswith(f"cab-replay: VALID: {n} calls") and "success False -> False" in out
    assert json.loads((d / "again" / "replay.json").read_text())["valid"] is True


def test_cli_regrade_prints_the_recomputed_analyses(oracle, capsys):
    rp.main(["--regrade", str(oracle)])
    g = json.loads(capsys.readouterr().out)
    assert g == {"attempt": str(oracle), "success": True, "claim": "correct", "checkpoints_changed": [],
                 "failure_stage": None, "failure_detail": ""}
