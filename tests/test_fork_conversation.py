"""A fork played by the reference harness goes on from its parent's conversation
(cab_core.kits.harness.conversation.transcript, ReferenceHarness._rebuild): the model's first request holds the
turns the parent's model had up to the fork point and the results it was given, built as the live
loop builds them. First with a fake episode whose records are written as an attempt writes them
(no simulator), then with real MuJoCo attempts (a parent played through the harness by a scripted
provider, and one played by the oracle)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_harness_reference import CANCELLED, CAPS, FakeEpisode, ScriptedProvider  # first: it finds the plugin

from cab_core.attempt.engine.episode import Episode
from cab_core.attempt.fork import ForkPoint
from cab_core.attempt.runner import run_attempt
from cab_core.attempt.spec import attempt_spec, forked
from cab_core.config import composed
from cab_core.kits.harness.conversation import transcript
from cab_harness_reference.loop import MALFORMED_KEY, NUDGE, ReferenceHarness
from cab_harness_reference.types import Capabilities, Image, Text, ToolCall, ToolResult

DONE = [("done", {"report": "r", "success_claim": False})]


def shape(messages) -> list:
    """A request as the model reads it: roles, texts, tool calls (a call's raw text only where its
    arguments were malformed: otherwise the arguments are sent), results and the images' ids."""
    out = []
    for m in messages:
        parts = []
        for p in m.parts:
            if isinstance(p, Text):
                parts.append(("text", p.text))
            elif isinstance(p, Image):
                parts.append(("image", p.obs_id, p.label))
            elif isinstance(p, ToolCall):
                raw = p.raw_arguments if p.arguments is None else None
                parts.append(("call", p.call_id, p.name, p.arguments, raw))
            elif isinstance(p, ToolResult):
                images = [(i.obs_id, i.label) for i in p.images]
                parts.append(("result", p.call_id, p.name, p.text, p.is_error, images))
        out.append((m.role, parts))
    return out


class RecordedEpisode(FakeEpisode):
    """A fake episode whose calls are recorded as the call server records them."""

    def call(self, name, args):
        r = super().call(name, args)
        self.recorder.event("call", tool=name, arguments=dict(args), result=dict(r.payload), obs_ids=list(r.obs_ids),
                            status=r.status, **({"charged": False} if name == "done" else {}))
        return r

    def write(self, out: Path, prefix: list[dict] = ()) -> Path:
        """The records of this episode (after ``prefix``: a fork's re-executed calls) as
        ``events.jsonl`` in ``out``, which ForkPoint.load reads."""
        out.mkdir(parents=True)
        events = [{"kind": "attempt_start", "config": {"task": "fake"}}, *prefix,
                  *({"kind": k, **d} for k, d in self.recorder.events)]
        (out / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
        return out


def fork_of(parent: Path, at: int, script, caps=CAPS):
    """A fake fork of ``parent`` at charged call ``at``, played by the harness with ``script``."""
    ep = RecordedEpisode()
    ep.fork = ForkPoint.load(parent, at)
    ep.n_obs = sum(len(e.get("obs_ids") or []) for e in ep.fork.events if e.get("kind") == "call")  # taken again
    prov = ScriptedProvider(script, caps)
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    return ep, prov


PARENT_SCRIPT = [
    [("capture_head", {}), ("move_delta", {"dx": 1}), ("capture_head", {})],  # call 2 aborts: call 3 cancelled
    [("move_delta", None)],  # malformed JSON
    [],  # no tool call: nudged
    [("capture_head", {}), ("capture_head", {}), ("move_delta", {"dx": 2})],
    DONE,
]


@pytest.mark.parametrize("images_in_results", [True, False])
def test_fork_request_is_the_parents_request_at_the_fork_point(tmp_path, images_in_results):
    caps = Capabilities(images_in_tool_results=images_in_results)
    parent = RecordedEpisode(statuses={2: "ABORTED"})
    prov = ScriptedProvider(PARENT_SCRIPT, caps)
    ReferenceHarness({}, provider=prov).run(parent, {"name": "fake"})
    d = parent.write(tmp_path / "parent")
    # charged calls: capture, move (aborted), malformed move, capture, capture, move: the fork at 6
    # starts after turn 4, where the parent's model made its 5th request
    child, child_prov = fork_of(d, 6, [DONE], caps)
    assert shape(child_prov.requests[0][1]) == shape(prov.requests[4][1])
    assert child.calls == [("done", {"report": "r", "success_claim": False})]  # nothing made again
    rebuilt = [d for k, d in child.recorder.events if k == "conversation_rebuilt"]
    assert len(rebuilt) == 1
    r = rebuilt[0]
    assert (r["at"], r["turns"], r["calls"], r["cancelled"], r["images"]) == (6, 4, 6, 1, 3)
    req = child_prov.requests[0][1]
    roles = [m.role for m in req]
    if images_in_results:
        assert roles == ["user", "assistant", "tool", "tool", "tool", "assistant", "tool", "assistant", "user",
                         "assistant", "tool", "tool", "tool"]
    else:  # the images follow the results in a user message, as the live loop sends them
        assert roles == ["user", "assistant", "tool", "tool", "tool", "user", "assistant", "tool", "assistant",
                         "user", "assistant", "tool", "tool", "tool", "user"]
        assert [p.obs_id for p in req[-1].parts if isinstance(p, Image)] == ["obs_0002", "obs_0003"]
    results = [p for m in req if m.role == "tool" for p in m.parts]
    assert CANCELLED in results[2].text and "not a valid JSON object: {oops" in results[3].text
    nudge = next(i for i, m in enumerate(req) if m.parts == [Text(NUDGE)])
    assert req[nudge - 1].role == "assistant" and req[nudge - 1].parts == [Text("thinking out loud")]


def test_fork_in_the_middle_of_a_turn_and_a_fork_of_a_fork(tmp_path):
    parent = RecordedEpisode(statuses={2: "ABORTED"})
    prov = ScriptedProvider(PARENT_SCRIPT)
    ReferenceHarness({}, provider=prov).run(parent, {"name": "fake"})
    d = parent.write(tmp_path / "parent")
    # at 5: turn 4 cut after its second call (the model asked for three)
    child, child_prov = fork_of(d, 5, [[("capture_head", {})], [("move_delta", {"dx": 3})], DONE])
    first = child_prov.requests[0][1]
    assert [p.call_id for p in first[-3].parts if isinstance(p, ToolCall)] == ["t4_0", "t4_1"]
    assert [p.call_id for m in first[-2:] for p in m.parts] == ["t4_0", "t4_1"]
    # the child's records: the prefix made again (tagged), then its own; its fork at 6 (its own
    # capture_head) starts with the parent's turns, as the child rebuilt them, and the child's first
    point = ForkPoint.load(d, 5)
    prefix = [{**e, "fork_prefix": True} for e in point.events if e.get("kind") == "call"]
    grand, grand_prov = fork_of(child.write(tmp_path / "child", prefix), 6, [DONE])
    assert shape(grand_prov.requests[0][1]) == shape(child_prov.requests[1][1])
    turns = transcript(ForkPoint.load(tmp_path / "child", 6).events)
    assert [[c["call_id"] for c in t["calls"]] for t in turns] == [
        ["t1_0", "t1_1", "t1_2"], ["t2_0"], [], ["t4_0", "t4_1"], ["t1_0"]]


def test_transcript_keeps_cancelled_calls_in_their_turn():
    """A call cancelled after an aborted action was not made: the next turn's call of the same
    name is that turn's, not the cancelled one's."""
    events = [
        {"kind": "model_turn", "text": "a", "tool_calls": [
            {"call_id": "x1", "name": "move_delta", "arguments": {"dx": 1}},
            {"call_id": "x2", "name": "move_delta", "arguments": {"dx": 2}}]},
        {"kind": "call", "tool": "move_delta", "arguments": {"dx": 1}, "result": {"status": "ABORTED"},
         "status": "ABORTED"},
        {"kind": "model_turn", "text": "b", "tool_calls": [{"call_id": "y1", "name": "move_delta", "arguments": None,
                                                           "raw_arguments": "{dx"}]},
        {"kind": "call", "tool": "move_delta", "arguments": {MALFORMED_KEY: "{dx"}, "result": {"error": "e"}},
    ]
    t = transcript(events)
    assert [(x["text"], [(c["call_id"], c["made"]) for c in x["calls"]]) for x in t] == [
        ("a", [("x1", True), ("x2", False)]), ("b", [("y1", True)])]
    assert t[0]["calls"][1]["result"] is None and t[0]["calls"][1]["arguments"] == {"dx": 2}
    assert t[1]["calls"][0]["arguments"] is None and t[1]["calls"][0]["raw_arguments"] == "{dx"
    assert t[1]["calls"][0]["result"] == {"error": "e"}


def test_transcript_of_a_model_free_parent_and_of_leftover_calls():
    calls = [{"kind": "call", "tool": n, "arguments": {"i": i}, "result": {"ok": i},
              "obs_ids": [f"obs_{i}"] if i else []} for i, n in enumerate(["capture_head", "move_delta"])]
    assert transcript(calls) == [
        {"text": "", "calls": [{"call_id": "call_0001", "name": "capture_head", "arguments": {"i": 0},
                                "raw_arguments": "", "result": {"ok": 0}, "obs_ids": [], "status": None,
                                "made": True}]},
        {"text": "", "calls": [{"call_id": "call_0002", "name": "move_delta", "arguments": {"i": 1},
                                "raw_arguments": "", "result": {"ok": 1}, "obs_ids": ["obs_1"], "status": None,
                                "made": True}]}]
    turn = {"kind": "model_turn", "text": "",
            "tool_calls": [{"call_id": "m", "name": "capture_head", "arguments": {}}]}
    t = transcript([turn, *calls])  # the second call's model turn is missing (a torn line): kept on its own
    assert [[c["call_id"] for c in x["calls"]] for x in t] == [["m"], ["call_0002"]]


# -- real attempts ---------------------------------------------------------------------------------
def spec_for(out: Path, *overrides: str, fork: dict | None = None):
    spec = attempt_spec(composed(["sim=mujoco", "task=click_bell", "record.video=false", *overrides]), out)
    return forked(spec, fork) if fork else spec


def play(spec, script):
    """The attempt ``spec``, played by the reference harness answered by ``script``."""
    prov = ScriptedProvider(script)
    with Episode.open(spec) as ep:
        ReferenceHarness({}, provider=prov).run(ep, spec.model_cfg)
    return ep, prov


def recorded_calls(out: Path) -> list[dict]:
    return [e for e in map(json.loads, (out / "events.jsonl").read_text().splitlines())
            if e["kind"] == "call" and not e.get("fork_prefix")]


@pytest.mark.sim
def test_fork_of_a_model_attempt_rebuilds_its_conversation(tmp_path):
    parent_script = [
        [("capture_head", {}), ("get_arm_pose", {"arm": "left"})],
        [("move_delta", None)],  # malformed JSON
        [],
        [("move_delta", {"arm": "left", "dx": 0.0, "dy": 0.0, "dz": 0.02}), ("capture_head", {})],
        DONE,
    ]
    parent, prov = play(spec_for(tmp_path / "parent", "model=sonnet5"), parent_script)
    assert parent.termination["reason"] == "done"
    calls = recorded_calls(tmp_path / "parent")
    assert [c["tool"] for c in calls] == ["capture_head", "get_arm_pose", "move_delta", "move_delta", "capture_head",
                                          "done"]
    child, child_prov = play(spec_for(tmp_path / "child", "model=sonnet5",
                                      fork={"from": str(tmp_path / "parent"), "at": 5}), [DONE])
    assert child.termination["reason"] == "done" and len(recorded_calls(tmp_path / "child")) == 1
    req = child_prov.requests[0][1]
    assert shape(req) == shape(prov.requests[4][1])  # the parent's model's 5th request, as it was
    assert [m.role for m in req] == ["user", "assistant", "tool", "tool", "assistant", "tool", "assistant", "user",
                                     "assistant", "tool", "tool"]
    asked = [(p.call_id, p.name) for m in req for p in m.parts if isinstance(p, ToolCall)]
    assert asked == [("t1_0", "capture_head"), ("t1_1", "get_arm_pose"), ("t2_0", "move_delta"),
                     ("t4_0", "move_delta"), ("t4_1", "capture_head")]
    results = [p for m in req if m.role == "tool" for p in m.parts]
    assert [r.call_id for r in results] == [c for c, _ in asked]
    for r, c in zip(results, calls):
        payload = json.loads(r.text)
        if c["arguments"].get(MALFORMED_KEY) is not None:  # the harness's own words, as the parent's model read them
            assert payload["error"].startswith("bad arguments: the arguments are not a valid JSON object")
            payload["error"] = c["result"]["error"]
        assert payload == c["result"]
    images = [(r.call_id, [i.obs_id for i in r.images]) for r in results if r.images]
    assert images == [("t1_0", ["obs_0001"]), ("t4_1", ["obs_0002"])]
    assert all(i.png.startswith(b"\x89PNG") for r in results for i in r.images)
    rebuilt = [e for e in map(json.loads, (tmp_path / "child" / "events.jsonl").read_text().splitlines())
               if e["kind"] == "conversation_rebuilt"]
    assert [(e["at"], e["turns"], e["calls"], e["images"]) for e in rebuilt] == [(5, 4, 5, 2)]


@pytest.mark.sim
def test_fork_of_an_oracle_attempt_gives_one_turn_per_call(tmp_path):
    assert run_attempt(spec_for(tmp_path / "parent", "model=oracle"))["termination"]["reason"] == "done"
    calls = recorded_calls(tmp_path / "parent")[:3]
    _, child_prov = play(spec_for(tmp_path / "child", "model=sonnet5",
                                  fork={"from": str(tmp_path / "parent"), "at": 3}), [DONE])
    req = child_prov.requests[0][1]
    assert [m.role for m in req] == ["user"] + ["assistant", "tool"] * 3
    for i, c in enumerate(calls):
        (asked,), (result,) = req[1 + 2 * i].parts, req[2 + 2 * i].parts
        assert (asked.call_id, asked.name, asked.arguments) == (f"call_{i + 1:04d}", c["tool"], c["arguments"])
        assert result.call_id == asked.call_id and json.loads(result.text) == c["result"]
        assert [im.obs_id for im in result.images] == c["obs_ids"]
    assert calls[0]["obs_ids"] == ["obs_0001"]  # the oracle looks first: its image is shown again
    rebuilt = [e for e in map(json.loads, (tmp_path / "child" / "events.jsonl").read_text().splitlines())
               if e["kind"] == "conversation_rebuilt"]
    assert [(e["turns"], e["calls"], e["images"]) for e in rebuilt] == [(3, 3, 1)]
