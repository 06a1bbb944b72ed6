"""The typed attempt record (cab_core/attempt/record.py): ``result.json`` is written from
:class:`AttemptRecord` and read back through it.

* records written before the model existed (the agent attempts kept in ``../shared/agent_attempts``
  and the oracle records in ``tests/data/records``, written by the dict-built writer at wings
  c237ef2) are read by every reader, and dumped again they are the same file, key order included;
* the typed writer writes what the dict-built one wrote for the same attempt (timings aside);
* a malformed record is refused with a RecordError naming what is wrong.
"""
from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pytest
from helpers_data import replaced
from pydantic import BaseModel

from cab_core.analysis.attempts import Attempt, InfrastructureResult, check_result, read_record, scan
from cab_core.attempt.records.result_format import (
    READABLE_VERSIONS,
    RECORD_VERSION,
    AttemptRecord,
    MalformedRecord,
    dumps,
    parse_record,
)
from cab_core.errors import RecordError
from cab_core.sweep.attempt_state import annotate_result, check_attempt, write_infrastructure_result

DATA = Path(__file__).parent / "data" / "records"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "agent_attempts"
STORED = sorted(DATA.glob("*.json"))
SHARED_RESULTS = sorted(SHARED.glob("*/result.json")) if SHARED.is_dir() else []
# what differs between two runs of the same attempt: wall-clock times
TIMINGS = (("timing", "wall_seconds"), ("timing", "setup_seconds"), ("budget", "wall_seconds_used"),
           ("video", "render_seconds"))


def extra_keys(m, path: str = "") -> list[str]:
    """Keys of a record that its model does not name (kept, but not typed)."""
    out = []
    if isinstance(m, BaseModel):
        out += [f"{path}.{k}" for k in (m.model_extra or {})]
        for f in type(m).model_fields:
            out += extra_keys(getattr(m, f), f"{path}.{f}")
    elif isinstance(m, dict):
        for k, v in m.items():
            out += extra_keys(v, f"{path}.{k}")
    elif isinstance(m, list):
        for i, v in enumerate(m):
            out += extra_keys(v, f"{path}[{i}]")
    return out


def key_order(d, path: str = "") -> list[str]:
    out = [f"{path}: {', '.join(d)}"] if isinstance(d, dict) else []
    for k, v in (d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()):
        out += key_order(v, f"{path}.{k}")
    return out


# -- (a) records written before the model: read, and dumped again unchanged -------------------------


@pytest.mark.parametrize("path", STORED + SHARED_RESULTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_records_written_before_the_model_are_read_and_kept_as_they_are(path):
    text = path.read_text()
    raw = json.loads(text)
    record = read_record(path)
    assert record.record_version == RECORD_VERSION == "cab-record/1"
    assert extra_keys(record) == []  # the model names every key these records hold
    assert record.dump() == raw and key_order(record.dump()) == key_order(raw)
    assert dumps(record.dump(), indent=2) == text.rstrip("\n")  # byte for byte, as write_json_atomic writes it
    assert check_result(raw) == record and not record.excluded
    assert isinstance(record.verdict.success, bool) and isinstance(record.termination.reason, str)


def test_the_stored_records_cover_the_optional_blocks():
    blocks = {p.name: json.loads(p.read_text()) for p in STORED}
    assert blocks["click_bell-oracle.json"]["video"] is None  # written as null, stays null
    assert "perturbation" not in blocks["click_bell-oracle.json"]  # absent, stays absent
    assert "perturbation" in blocks["click_bell-oracle-perturb1.json"]
    latch = blocks["beat_block_hammer-oracle-video.json"]
    assert latch["verdict"]["latch"]["latched"] and "render_seconds" in latch["video"]


@pytest.mark.skipif(not SHARED_RESULTS, reason=f"no agent attempts in {SHARED}")
def test_agent_attempts_written_before_the_model_pass_every_reader(tmp_path):
    """The real agent attempts (MCP, records from before margins, tool_errors and the render mode
    existed): analysis loads them, the sweep's record check calls them complete."""
    for rp in SHARED_RESULTS:
        a = Attempt.load(rp.parent, SHARED)
        assert a.record.harness == "mcp" and a.success == a.result["verdict"]["success"]
        assert a.record.counts.tool_errors is None and "tool_errors" not in a.record.dump()["counts"]
        assert check_attempt(rp.parent, {"task": rp.parent.name, "attempt": 1}).state == "complete"
    s = scan(SHARED)
    assert len(s.attempts) == len(SHARED_RESULTS) and s.problems == []


# -- (b) the typed writer writes what the dict-built one wrote ----------------------------------------


def _timings_aside(res: dict) -> dict:
    res = copy.deepcopy(res)
    for block, key in TIMINGS:
        if isinstance(res.get(block), dict) and key in res[block]:
            res[block][key] = "<timing>"
    return res


@pytest.mark.sim
def test_the_typed_writer_writes_what_the_dict_writer_wrote(tmp_path):
    """``cab task=click_bell record.video=false`` (the oracle) now, against the same attempt's
    result.json written by the dict-built writer. Timings aside; of what describes the machine
    (``versions``, ``sandbox``: stored on another machine they differ) the keys, not the values.
    The stored attempt was planned by mplib: where it is not installed (numpy 2), the default planner
    moves the arm along paths a few micrometres apart, so the verdict's measured margins are compared
    by their keys too, and the planner's name is the one difference allowed."""
    from attempt_records import run_one

    from cab_core.plugins import registry

    out = tmp_path / "click_bell"
    mplib = "mplib" in registry("planners")
    result = run_one(out, "click_bell", "oracle", 1, "record.video=false", *(["planner=mplib"] if mplib else []))
    new = json.loads((out / "result.json").read_text())
    old = json.loads((DATA / "click_bell-oracle.json").read_text())
    assert new == result
    assert set(new.pop("contract")["parts"]) >= {"tools", "task", "budget"}  # added to cab-record/1 after the stored record
    for machine in ("versions", "sandbox"):
        assert list(new[machine]) == list(old[machine])
        new[machine] = old[machine] = "<machine>"
    if not mplib:
        assert (new["planner"], old["planner"]) == ("pin", "mplib")
        new["planner"] = old["planner"]
        for rec in (new, old):
            measured = rec["verdict"]["margins"]["knob_contact"]
            assert set(measured) >= {"fraction", "measured", "slack"}
            # 1.2 um apart: 0.00390 m measured, 84.4 % of the tolerance
            measured.update(measured=round(measured["measured"], 5), slack=round(measured["slack"], 5),
                            fraction=round(measured["fraction"], 3))
            rec["verdict"]["margin"]["fraction"] = round(rec["verdict"]["margin"]["fraction"], 3)
    assert _timings_aside(new) == _timings_aside(old)
    assert key_order(new) == key_order(old)
    assert read_record(out / "result.json").dump() == json.loads((out / "result.json").read_text())


def _old_infrastructure_result(identity: dict, failures: list[dict]) -> dict:
    """What write_infrastructure_result wrote before the model (verbatim)."""
    last = failures[-1] if failures else {}
    return {
        "record_version": RECORD_VERSION, **identity,
        "verdict": {"success": None, "excluded": "infrastructure_failure"},
        "termination": {"reason": "infrastructure_failure",
                        "detail": f"{len(failures)} tries failed; last: {last.get('kind')}: {last.get('detail')}"},
        "claim": {"success_claim": None, "report": None},
        "budget": {}, "timing": {}, "versions": {},
        "infrastructure": {"failed": True, "failures": failures},
    }


def test_the_sweep_writes_what_it_wrote_before(tmp_path):
    identity = {"task": "click_bell", "seed": 0, "attempt": 1, "sim": "sapien", "model": "oracle"}
    failures = [{"kind": "crash", "detail": "attempt process killed by signal 9", "log_tail": "...", "try_no": 1,
                 "wall_seconds": 3.2, "at": 1764000000.5, "records": "set_aside/01-crash"},
                {"kind": "hang", "detail": "no progress for 900 s; killed", "try_no": 2, "wall_seconds": 901.0,
                 "at": 1764000900.25, "records": None}]
    written = write_infrastructure_result(tmp_path, identity, failures)
    on_disk = json.loads((tmp_path / "result.json").read_text())
    assert written == on_disk == _old_infrastructure_result(identity, failures)
    assert key_order(on_disk) == key_order(_old_infrastructure_result(identity, failures))
    with pytest.raises(InfrastructureResult, match="excluded \\(infrastructure_failure\\): 2 tries failed"):
        check_result(on_disk)
    assert check_attempt(tmp_path).problems == ["infrastructure failure: 2 tries failed; last: hang: no progress "
                                                "for 900 s; killed"]
    # a good try after failures: its result gains the block at the end, nothing else changes
    good = tmp_path / "good"
    good.mkdir()
    shutil.copy(DATA / "click_bell-oracle.json", good / "result.json")
    before = json.loads((good / "result.json").read_text())
    annotated = annotate_result(good, failures[:1])
    assert annotated == json.loads((good / "result.json").read_text())
    assert annotated == {**before, "infrastructure": {"failed": False, "failures": failures[:1]}}
    assert list(annotated)[-1] == "infrastructure"


# -- (c) a malformed record is refused with a clear error ---------------------------------------------


def _stored() -> dict:
    return json.loads((DATA / "click_bell-oracle.json").read_text())


def _without(d: dict, *path: str) -> dict:
    d = copy.deepcopy(d)
    node = d
    for k in path[:-1]:
        node = node[k]
    del node[path[-1]]
    return d


def _with(d: dict, value, *path) -> dict:
    return replaced(d, path, value)


MALFORMED = [
    (_without(_stored(), "verdict"), "result.json lacks 'verdict'"),
    (_without(_stored(), "termination", "reason"), "result.json lacks 'termination.reason'"),
    (_with(_stored(), True, "seed"), "result.json seed should be an integer, got True"),
    (_with(_stored(), "3", "attempt"), "result.json attempt should be an integer, got '3'"),
    (_with(_stored(), "yes", "verdict", "success"), "result.json verdict.success should be true or false, got 'yes'"),
    (_with(_stored(), None, "verdict", "success"), "result.json verdict.success should be true or false"),
    (_with(_stored(), "many", "budget", "sim_seconds_used"), "result.json budget.sim_seconds_used should be a number, "
                                                              "got 'many'"),
    (_with(_stored(), [], "claim"), "result.json claim should be an object, got []"),
    (_with(_stored(), "cab-record/9", "record_version"),
     "result.json record_version 'cab-record/9' is not a record version this cab reads (cab-record/1)"),
    (_without(_stored(), "record_version"), "result.json lacks 'record_version'"),
    (_without(_stored(), "harness"), "result.json a scored record needs 'harness'"),
    (_with(_stored(), [{"index": 1}], "checkpoints", "spatial"),
     "result.json lacks 'checkpoints.spatial[0].name'; result.json lacks 'checkpoints.spatial[0].arm'; "
     "result.json lacks 'checkpoints.spatial[0].attained'"),
    (_with(_stored(), {"kind": "mcp_client", "named_by": "someone"}, "agent"),
     "result.json agent.named_by should be 'config', 'client' or 'placeholder', got 'someone'"),
    (_with(_stored(), {"kind": "mcp_client", "named_by": "client", "client": {"name": "x", "version": "1",
                                                                             "session": 0}}, "agent"),
     "result.json agent.client.session should be greater than or equal to 1, got 0"),
]


@pytest.mark.parametrize("bad,message", MALFORMED, ids=[m for _, m in MALFORMED])
def test_a_malformed_record_is_refused_naming_what_is_wrong(bad, message, tmp_path):
    with pytest.raises(MalformedRecord) as e:
        parse_record(bad)
    assert str(e.value) == message and isinstance(e.value, RecordError)
    (tmp_path / "result.json").write_text(json.dumps(bad))
    with pytest.raises(RecordError, match="^" + message.replace("(", "\\(").replace(")", "\\)").replace("[", "\\[")
                       .replace("]", "\\]")):
        Attempt.load(tmp_path)
    (tmp_path / "events.jsonl").write_text("")
    check = check_attempt(tmp_path)
    assert check.state == "partial" and "; ".join(check.problems).startswith(message)
    assert scan(tmp_path).problems == [(".", message)]


def test_unreadable_files_are_refused(tmp_path):
    p = tmp_path / "result.json"
    with pytest.raises(RecordError, match="result.json is missing"):
        read_record(p)
    p.write_text('{"record_version": "cab-record/1", "task"')
    with pytest.raises(RecordError, match="result.json is not valid JSON"):
        read_record(p)
    p.write_text("[1, 2]")
    with pytest.raises(RecordError, match="result.json does not hold a JSON object"):
        read_record(p)
    with pytest.raises(MalformedRecord, match="result.json does not hold a JSON object"):
        parse_record([1, 2])


def test_the_writer_refuses_what_the_format_does_not_hold():
    fields = parse_record(_stored()).dump()
    with pytest.raises(MalformedRecord, match="verdict.success should be true or false, got 'yes'"):
        AttemptRecord.build(**{**fields, "verdict": {**fields["verdict"], "success": "yes"}})
    import numpy as np

    # what the host holds (numpy numbers) becomes JSON first, as write_json_atomic would write it
    rec = AttemptRecord.build(**{**fields, "seed": np.int64(0), "budget": {**fields["budget"],
                                                                          "sim_dt": np.float64(0.004)}})
    assert rec.seed == 0 and type(rec.seed) is int and rec.budget.sim_dt == 0.004


def test_keys_and_nulls_are_kept_as_written():
    """A key the writer leaves out stays out, a null stays null, an unknown key is kept, and a number
    keeps its kind."""
    d = _stored()
    d["budget"]["sim_seconds_limit"] = 60  # an integer, as a config may give it
    d["budget"]["a_later_key"] = {"x": 1}
    d["counts"].pop("tool_errors")
    rec = parse_record(d)
    out = rec.dump()
    assert out == d and out["budget"]["sim_seconds_limit"] == 60 and type(out["budget"]["sim_seconds_limit"]) is int
    assert out["video"] is None and "agent" not in out and "perturbation" not in out
    assert "tool_errors" not in out["counts"]
    fields = {**_stored(), "agent": None, "perturbation": None}  # the writer passes them; None leaves them out
    assert "agent" not in AttemptRecord.build(**fields).dump()
    assert READABLE_VERSIONS == ("cab-record/1",)


@pytest.mark.sim
def test_an_attempt_whose_record_does_not_validate_is_still_written(tmp_path, monkeypatch):
    """Never lose an attempt: a record the model refuses (here a version report of the wrong shape)
    is written as assembled, the event log says why, and every reader then refuses it."""
    from hydra import compose, initialize_config_module

    from cab_core.analysis.attempts import read_jsonl
    from cab_core.apps.cli import normalise_overrides
    from cab_core.attempt.engine.episode import Episode
    from cab_core.attempt.runner import attempt_spec

    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(
            ["sim=mujoco", "task=click_bell", "record.video=false", "model=idle"]))
    monkeypatch.setattr(Episode, "versions", lambda self: {"packages": {"cab": 1}})
    out = tmp_path / "a"
    with Episode.open(attempt_spec(cfg, out)) as ep:
        ep.call("done", {"report": "nothing", "success_claim": False})
        result = ep.finish()
    assert ep.record is None and result["versions"] == {"packages": {"cab": 1}} and "agent" not in result
    assert json.loads((out / "result.json").read_text()) == result
    kinds = [e["kind"] for e in read_jsonl(out / "events.jsonl")]
    assert kinds[-2:] == ["record_invalid", "attempt_end"]
    with pytest.raises(MalformedRecord, match=r"result.json versions.packages.cab should be a string, got 1"):
        read_record(out / "result.json")
    assert check_attempt(out).state == "partial"
