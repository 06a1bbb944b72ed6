"""The reference harness core: retries, prompt, context policy and the agent loop, driven by a
scripted fake provider (no network, no simulator)."""
from __future__ import annotations

import json
import random
import sys
from pathlib import Path

import pytest

try:
    import cab_harness_reference  # noqa: F401
except ImportError:  # the plugin is not installed: use the source tree
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plugins" / "harness_reference"))

from cab_core.errors import ConfigError
from cab_core.kits.harness.pricing import cost, rates
from cab_core.kits.harness.prompts import first_user_message, system_prompt
from cab_core.tools.motion import HARNESS_PARAMETERS
from cab_harness_reference import plugin
from cab_harness_reference.context import compact_record
from cab_harness_reference.retry import RetryPolicy, call_with_retries
from cab_harness_reference.types import ProviderError


def _policy(sleeps, attempts=3):
    return RetryPolicy(max_attempts=attempts, sleep=sleeps.append, rng=random.Random(0))


class _Boom(Exception):
    def __init__(self, kind):
        self.kind = kind


def _classify(e):
    return ProviderError(e.kind, str(e))


def test_retry_success_after_rate_limit():
    sleeps, n = [], [0]

    def fn():
        n[0] += 1
        if n[0] == 1:
            raise _Boom("rate_limit")
        return "ok"

    res, waited = call_with_retries(fn, _classify, _policy(sleeps))
    assert res == "ok" and n[0] == 2 and len(sleeps) == 1
    assert 0 <= sleeps[0] <= 60 and waited == pytest.approx(sleeps[0], abs=0.05)


@pytest.mark.parametrize("kind", ["auth", "bad_request", "context_length"])
def test_retry_not_on_permanent_errors(kind):
    sleeps, n = [], [0]

    def fn():
        n[0] += 1
        raise _Boom(kind)

    with pytest.raises(ProviderError) as ei:
        call_with_retries(fn, _classify, _policy(sleeps))
    assert ei.value.kind == kind and n[0] == 1 and sleeps == [] and not ei.value.retryable


def test_retry_bounded_with_growing_caps():
    sleeps, n = [], [0]

    def fn():
        n[0] += 1
        raise _Boom("server")

    p = _policy(sleeps, attempts=4)
    with pytest.raises(ProviderError) as ei:
        call_with_retries(fn, _classify, p)
    assert n[0] == 4 and len(sleeps) == 3 and ei.value.kind == "server"
    assert ei.value.waited_s == pytest.approx(sum(sleeps), abs=0.05)
    for i, s in enumerate(sleeps):  # full jitter: uniform in [0, base * 2**i]
        assert 0 <= s <= 2.0 * 2 ** i


def test_prompt_states_facts_and_both_budgets():
    budget = {"tool_calls_remaining": 42, "tool_calls_limit": 42, "sim_seconds_remaining": 60.0, "sim_seconds_limit": 60.0}
    s = system_prompt(budget, HARNESS_PARAMETERS)
    assert "no depth sensor" in s and "achieved" in s and "Tool calls: 42" in s and "Simulated time: 60.0 s" in s
    assert json.dumps(HARNESS_PARAMETERS, sort_keys=True, default=str) in s
    assert '"max_images_per_result": 6' in s and "done(report, success_claim)" in s
    assert first_user_message("  Beat the block.\n") == "Beat the block."


# --- context policy ---------------------------------------------------------------------------
from cab_harness_reference.context import ContextOverflow, ReferenceContextPolicy  # noqa: E402
from cab_harness_reference.types import Capabilities, Image, Message, Text, Thinking, ToolCall, ToolResult  # noqa: E402

CAPS = Capabilities(images_in_tool_results=True)


def _conv(n_units: int, images_per_unit: int = 1, text_len: int = 40):
    msgs = [Message("user", [Text("Beat the block with the hammer.")])]
    k = 0
    for i in range(n_units):
        cid = f"c{i}"
        msgs.append(Message("assistant", [Thinking("hmm " * 10), Text(f"step {i} " + "x" * text_len),
                                          ToolCall(cid, "capture_head", {"note": i})]))
        imgs = []
        for _ in range(images_per_unit):
            imgs.append(Image(png=f"png-{k}".encode(), obs_id=f"obs_{k:04d}", label=f"obs_{k:04d} head_camera"))
            k += 1
        payload = {"status": "OK", "obs_id": imgs[-1].obs_id if imgs else None, "achieved": [i, 0, 0], "filler": "y" * text_len}
        msgs.append(Message("tool", [ToolResult(cid, "capture_head", json.dumps(payload), images=imgs)]))
    return msgs


def _images(msgs):
    out = []
    for m in msgs:
        for p in m.parts:
            if isinstance(p, Image):
                out.append(p.obs_id)
            if isinstance(p, ToolResult):
                out += [i.obs_id for i in p.images]
    return out


def test_context_keeps_images_of_two_latest_rounds_only():
    pol = ReferenceContextPolicy()
    msgs = _conv(5)
    out = pol.build(msgs, CAPS, limit_tokens=10**6)
    assert _images(out) == ["obs_0003", "obs_0004"]
    assert len(out) == len(msgs)  # nothing compacted
    old = [p for p in out[2].parts if isinstance(p, ToolResult)][0]
    assert "obs_0000" in old.text and "fetch it again" in old.text and old.images == []
    assert _images(msgs) == [f"obs_{i:04d}" for i in range(5)]  # the history is not modified
    assert out[0].cache_breakpoint and out[-1].cache_breakpoint


def test_context_caps_images_per_result_and_dedups():
    pol = ReferenceContextPolicy()
    msgs = _conv(1, images_per_unit=9)
    out = pol.build(msgs, CAPS, limit_tokens=10**6)
    assert _images(out) == [f"obs_{i:04d}" for i in range(3, 9)]
    assert "withheld (image cap)" in out[2].parts[0].text
    # follow-up user message form (openai_compatible): identical bytes are sent once
    msgs = _conv(1, images_per_unit=0)
    same = b"same-bytes"
    msgs.append(Message("user", [Image(same, "obs_a"), Image(same, "obs_b")]))
    out = pol.build(msgs, Capabilities(images_in_tool_results=False), limit_tokens=10**6)
    assert _images(out) == ["obs_b"] and "identical" in out[-1].parts[0].text


def test_context_compaction_keeps_8_units_and_ledger():
    pol = ReferenceContextPolicy()
    msgs = _conv(30, text_len=400)
    full = pol.estimate(pol.build(msgs, CAPS, None))
    out = pol.build(msgs, CAPS, limit_tokens=full - 1)
    assistants = [m for m in out if m.role == "assistant"]
    assert len(assistants) == 8 and assistants[0].parts[1].text.startswith("step 22")
    ledger = out[0].parts[-1].text.splitlines()
    assert out[0].parts[0].text.startswith("Beat the block")  # the anchor is kept
    assert ledger[0].startswith("[Record of earlier interactions") and len(ledger) == 1 + 22
    rec = json.loads(ledger[1])
    assert rec["tool"] == "capture_head" and rec["args"] == {"note": 0} and rec["obs_ids"] == ["obs_0000"]
    assert rec["status"] == "OK" and rec["achieved"] == [0, 0, 0] and "filler" not in rec
    assert pol.build(msgs, CAPS, limit_tokens=full - 1) == out  # deterministic
    assert pol.estimate(out) <= full - 1


def test_context_ledger_is_capped_at_128_records():
    pol = ReferenceContextPolicy()
    msgs = _conv(150, images_per_unit=0, text_len=600)
    out = pol.build(msgs, CAPS, limit_tokens=40000)
    ledger = out[0].parts[-1].text.splitlines()
    assert len(ledger) == 1 + 128 and "14 older records dropped" in ledger[0]
    assert json.loads(ledger[1])["args"] == {"note": 14}


def test_context_overflow_raises():
    pol = ReferenceContextPolicy()
    msgs = _conv(3, text_len=40000)
    with pytest.raises(ContextOverflow):
        pol.build(msgs, CAPS, limit_tokens=5000)
    out = pol.build(msgs, CAPS, limit_tokens=25000)  # reduced to the anchor + the newest unit
    assert len([m for m in out if m.role == "assistant"]) == 1


# --- the loop, with a scripted provider and a fake episode -------------------------------------
import numpy as np  # noqa: E402

from cab_core.attempt.engine.episode import ToolResponse  # noqa: E402
from cab_harness_reference.loop import (  # noqa: E402
    CANCELLED,
    NUDGE,  # noqa: E402
    ReferenceHarness,
)
from cab_harness_reference.types import Provider, Response, Usage  # noqa: E402


class FakeLedger:
    class _L:
        limit = 20

    tool_calls = _L()

    def __init__(self):
        self.credited = 0.0

    def remaining(self):
        return {"tool_calls_remaining": 20, "tool_calls_limit": 20, "sim_seconds_remaining": 60.0, "sim_seconds_limit": 60.0}

    def exhausted_reason(self):
        return None

    def credit_wall(self, s):
        self.credited += s

    def charge_cost(self, usd):
        pass


class FakeRecorder:
    def __init__(self):
        self.events = []

    def event(self, kind, **data):
        self.events.append((kind, data))


class FakeSpec:
    sandbox = {}
    run_code_max_internal_calls = 500


class FakeEpisode:
    instruction = "Beat the block with the hammer."

    def __init__(self, statuses=None):
        self.ended = False
        self.termination = None
        self.calls = []
        self.ledger = FakeLedger()
        self.recorder = FakeRecorder()
        self.spec = FakeSpec()
        self.statuses = statuses or {}
        self.n_obs = 0

    def tool_specs(self):
        return [{"name": n, "description": n, "parameters": {"type": "object", "properties": {}}}
                for n in ("capture_head", "move_delta", "run_code", "done")]

    def image(self, obs_id):
        return np.full((4, 4, 3), int(obs_id[-2:]), np.uint8)

    def end(self, reason, detail=""):
        if not self.ended:
            self.ended, self.termination = True, {"reason": reason, "detail": detail}

    def call(self, name, args):
        self.calls.append((name, dict(args)))
        if name == "done":
            self.end("done")
            return ToolResponse("done", {"ok": True}, [], ended=True)
        if any(k.startswith("__") for k in args):
            return ToolResponse(name, {"error": "bad arguments: unknown argument", "code": "invalid_tool_arguments"}, [])
        if name == "capture_head":
            self.n_obs += 1
            return ToolResponse(name, {"obs_id": f"obs_{self.n_obs:04d}"}, [f"obs_{self.n_obs:04d}"])
        st = self.statuses.get(len(self.calls))
        return ToolResponse(name, {"status": st or "OK"}, [], status=st)


class ScriptedProvider(Provider):
    name = "scripted"
    key_env = None

    def __init__(self, script, caps=CAPS):
        self.script = list(script)
        self.capabilities = caps
        self.requests = []

    def check_credentials(self):
        pass

    def complete(self, system, messages, tools):
        self.requests.append((system, messages, tools))
        item = self.script.pop(0)
        if isinstance(item, Exception):
            raise item
        parts = [Text("thinking out loud")] + [ToolCall(f"t{len(self.requests)}_{i}", n, a, raw_arguments="{oops")
                                               for i, (n, a) in enumerate(item)]
        return Response(Message("assistant", parts), "tool_calls" if item else "end_turn",
                        Usage(input_tokens=1000, output_tokens=100, cache_read_tokens=500), model="fake",
                        latency_s=0.5, waited_s=2.0)


def _results(msgs):
    return [p for m in msgs if m.role == "tool" for p in m.parts]


PRICING = {"input_per_mtok": 5.0, "output_per_mtok": 25.0, "cache_read_per_mtok": 0.5, "cache_write_per_mtok": 6.25}


def test_loop_runs_calls_in_order_and_records_turns():
    ep = FakeEpisode()
    prov = ScriptedProvider([[("capture_head", {}), ("move_delta", {"dx": 1})],
                             [("move_delta", None)],  # malformed JSON
                             [("done", {"report": "hit", "success_claim": True})]])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake", "pricing": PRICING})
    assert [c[0] for c in ep.calls] == ["capture_head", "move_delta", "move_delta", "done"]
    assert ep.calls[2][1] == {"__malformed_json_arguments__": "{oops"}  # charged as an invalid call
    assert ep.termination["reason"] == "done"
    sys_prompt, req2, tools = prov.requests[1]
    assert "Tool calls: 20" in sys_prompt and [t.name for t in tools][-1] == "done"
    assert req2[0].parts[0].text == "Beat the block with the hammer."
    res = _results(req2)
    assert [r.name for r in res] == ["capture_head", "move_delta"]
    assert res[0].images and res[0].images[0].obs_id == "obs_0001" and res[0].images[0].png.startswith(b"\x89PNG")
    err = _results(prov.requests[2][1])[-1]
    assert err.is_error and "not a valid JSON object" in err.text
    turns = [d for k, d in ep.recorder.events if k == "model_turn"]
    assert len(turns) == 3 and turns[0]["tool_calls"][0]["name"] == "capture_head"
    assert turns[0]["cost"]["usd"] == pytest.approx(1000 * 5e-6 + 100 * 25e-6 + 500 * 0.5e-6)
    assert turns[0]["usage"]["cache_read_tokens"] == 500 and turns[0]["waited_s"] == 2.0
    assert ep.ledger.credited == pytest.approx(6.0)


def test_loop_abort_cancels_rest_of_response():
    ep = FakeEpisode(statuses={1: "ABORTED"})
    prov = ScriptedProvider([[("move_delta", {"dx": 1}), ("move_delta", {"dx": 2}), ("capture_head", {})],
                             [("done", {"report": "r"})]])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    assert [c[0] for c in ep.calls] == ["move_delta", "done"]
    res = _results(prov.requests[1][1])
    assert [r.call_id for r in res] == ["t1_0", "t1_1", "t1_2"]
    assert CANCELLED in res[1].text and CANCELLED in res[2].text and res[1].is_error


def test_loop_images_in_followup_user_message():
    ep = FakeEpisode()
    prov = ScriptedProvider([[("capture_head", {}), ("capture_head", {})], [("done", {"report": "r"})]],
                            caps=Capabilities(images_in_tool_results=False))
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    req = prov.requests[1][1]
    assert [m.role for m in req] == ["user", "assistant", "tool", "tool", "user"]
    assert [p.obs_id for p in req[-1].parts if isinstance(p, Image)] == ["obs_0001", "obs_0002"]
    assert all(not r.images for r in _results(req))


def test_loop_nudges_then_ends_after_three_turns_without_tools():
    ep = FakeEpisode()
    prov = ScriptedProvider([[], [], []])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    assert ep.termination["reason"] == "no_tool_calls" and ep.calls == []
    last = prov.requests[2][1]
    assert [m.parts[0].text for m in last if m.role == "user"][1:] == [NUDGE, NUDGE]


def test_loop_nudge_counter_resets():
    ep = FakeEpisode()
    prov = ScriptedProvider([[], [], [("capture_head", {})], [], [("done", {"report": "r"})]])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    assert ep.termination["reason"] == "done"


def test_loop_provider_failure_is_recorded_and_credited():
    ep = FakeEpisode()
    err = ProviderError("server", "HTTP 500 storm", status=500, retryable=True)
    err.waited_s = 7.5
    prov = ScriptedProvider([[("capture_head", {})], err])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    assert ep.termination["reason"] == "provider_failure" and "server" in ep.termination["detail"]
    fail = [d for k, d in ep.recorder.events if k == "provider_failure"][0]
    assert fail["error_kind"] == "server" and fail["status"] == 500
    assert ep.ledger.credited == pytest.approx(2.0 + 7.5)


def test_loop_context_overflow_ends_attempt():
    ep = FakeEpisode()
    prov = ScriptedProvider([[("capture_head", {})]] * 3)
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake", "context_tokens": 100})
    assert ep.termination["reason"] == "context_length_exceeded" and prov.requests == []


def test_loop_context_length_error_forces_one_compaction():
    ep = FakeEpisode()
    prov = ScriptedProvider([[("capture_head", {})], ProviderError("context_length", "too long"),
                             ProviderError("context_length", "too long")])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    assert ep.termination["reason"] == "context_length_exceeded"
    assert [k for k, _ in ep.recorder.events].count("forced_compaction") == 1


def test_plugin_registers_lazily():
    assert set(plugin.cab_model_providers()) == {"anthropic", "openai", "google", "openai_compatible", "inspect"}
    assert "reference" in plugin.cab_harnesses() and "reference" in plugin.cab_context_policies()


def test_compact_record_of_run_code_drops_source_keeps_outcome():
    call = ToolCall("c1", "run_code", {"code": "x = 1\n" * 50})
    res = ToolResult("c1", "run_code", json.dumps({"ok": False, "error": "move_delta returned ABORTED", "status": "ABORTED",
                                                   "abort_reason": "stalled", "value": None, "stdout": "hi",
                                                   "images": ["obs_0007"], "internal_trace": [{"big": 1}]}))
    rec = compact_record(call, res, ["obs_0007"])
    assert rec["args"] == {"code_chars": 300} and rec["status"] == "ABORTED" and rec["abort_reason"] == "stalled"
    assert rec["error"].startswith("move_delta") and rec["stdout"] == "hi" and rec["ok"] is False
    assert "value" not in rec and "internal_trace" not in rec and rec["obs_ids"] == ["obs_0007"]


def test_loop_run_code_result_with_null_error_is_not_an_error():
    ep = FakeEpisode()
    ep.call = lambda name, args: (ep.calls.append((name, args)), ep.end("done") if name == "done" else None,
                                  ToolResponse(name, {"ok": True, "error": None}, []))[-1]
    prov = ScriptedProvider([[("run_code", {"code": "result = 1"})], [("done", {"report": "r"})]])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    assert not _results(prov.requests[1][1])[0].is_error


def test_loop_wall_budget_checked_per_turn():
    ep = FakeEpisode()
    ep.ledger.exhausted_reason = lambda: "wall_budget"
    prov = ScriptedProvider([[("capture_head", {})]])
    ReferenceHarness({}, provider=prov).run(ep, {"name": "fake"})
    assert ep.termination["reason"] == "wall_budget" and prov.requests == []


def test_pricing_rates_and_validation():
    assert cost(Usage(1000, 10), None) == {"usd": None}
    r = rates({"input_per_mtok": 2.0, "output_per_mtok": 8.0})
    assert r["cache_read_per_mtok"] == 2.0 and r["cache_write_per_mtok"] == 2.0
    c = cost(Usage(input_tokens=10**6, output_tokens=10**6, cache_read_tokens=10**6), {"input_per_mtok": 2, "output_per_mtok": 8,
                                                                                  "cache_read_per_mtok": 0.2})
    assert c["usd"] == pytest.approx(10.2) and c["cache_read"] == pytest.approx(0.2)
    with pytest.raises(ConfigError):
        rates({"input": 1})
