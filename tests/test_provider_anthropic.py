"""The Anthropic provider through the real ``anthropic`` SDK against a local HTTP server (a thread
on 127.0.0.1) speaking the Messages API wire format. No network."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

pytest.importorskip("anthropic")

try:
    import cab_harness_reference  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plugins" / "harness_reference"))

from fake_json_api import JsonServer

from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.engine.episode import Episode
from cab_core.attempt.runner import attempt_spec
from cab_core.errors import ConfigError
from cab_core.kits.harness.pricing import rates
from cab_core.plugins import all_tasks, create
from cab_harness_reference.anthropic_provider import AnthropicProvider, to_wire
from cab_harness_reference.loop import ReferenceHarness
from cab_harness_reference.types import Image, Message, ProviderError, Text, Thinking, ToolCall, ToolResult, ToolSpec


class FakeAnthropic(JsonServer):
    """Scripted Messages API: each item is (status, body-dict) or a callable(request) -> (status, body);
    records each request body and its headers. Serving from the start."""

    def __init__(self):
        super().__init__()
        self.script: list = []
        self.requests: list[dict] = []
        self.headers: list[dict] = []
        self.start()

    def answer(self, path, body, headers):
        self.requests.append(body)
        self.headers.append(headers)
        item = self.script.pop(0) if self.script else (500, {"type": "error", "error": {"type": "api_error", "message": "script empty"}})
        if callable(item):
            item = item(body)
        status, out = item
        return status, out, {"request-id": f"req_{len(self.requests)}", **({"retry-after": "0"} if status == 429 else {})}


def message(content, stop="tool_use", usage=None):
    return (200, {"id": "msg_1", "type": "message", "role": "assistant", "model": "claude-opus-5",
                  "content": content, "stop_reason": stop, "stop_sequence": None,
                  "usage": usage or {"input_tokens": 120, "output_tokens": 30, "cache_read_input_tokens": 1000,
                                     "cache_creation_input_tokens": 64}})


def tool_use(i, name, inp):
    return {"type": "tool_use", "id": f"toolu_{i}", "name": name, "input": inp}


def error(status, etype, msg="x"):
    return (status, {"type": "error", "error": {"type": etype, "message": msg}})


@pytest.fixture
def server():
    s = FakeAnthropic()
    yield s
    s.close()


CFG = {"name": "opus5", "provider": "anthropic", "model_id": "claude-opus-5", "max_output_tokens": 128000,
       "thinking": {"type": "adaptive"}, "effort": "high"}
TOOLS = [ToolSpec("capture_head", "Captures the head camera.", {"type": "object", "properties": {}, "additionalProperties": False}),
         ToolSpec("run_code", "Runs a program.", {"type": "object", "properties": {"code": {"type": "string"}}, "required": ["code"]}),
         ToolSpec("done", "Ends.", {"type": "object", "properties": {"report": {"type": "string"}}, "required": ["report"]})]


def _provider(server, monkeypatch, **over):
    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-test")
    p = AnthropicProvider({**CFG, "base_url": server.url, **over})
    sleeps = []
    p.retry_policy.sleep = sleeps.append
    return p, sleeps


def test_missing_key_is_one_line_naming_the_variable(monkeypatch):
    monkeypatch.delenv("ANTHROPIC_API_KEY", raising=False)
    with pytest.raises(ConfigError) as ei:
        AnthropicProvider(CFG).check_credentials()
    assert "ANTHROPIC_API_KEY" in str(ei.value) and "\n" not in str(ei.value)


def test_multi_turn_tools_images_run_code_done(server, monkeypatch):
    p, sleeps = _provider(server, monkeypatch)
    server.script = [
        message([{"type": "thinking", "thinking": "look first", "signature": "sig1"},
                 {"type": "text", "text": "Looking."}, tool_use(1, "capture_head", {})]),
        message([tool_use(2, "run_code", {"code": "result = 1 + 1"})]),
        message([tool_use(3, "done", {"report": "hit", "success_claim": True})]),
    ]
    hist = [Message("user", [Text("Beat the block with the hammer.")], cache_breakpoint=True)]
    r1 = p.complete("SYSTEM", hist, TOOLS)
    assert r1.stop_reason == "tool_calls" and r1.raw_stop_reason == "tool_use"
    th, tx, tc = r1.message.parts
    assert isinstance(th, Thinking) and th.signature == "sig1" and tx.text == "Looking."
    assert isinstance(tc, ToolCall) and tc.name == "capture_head" and tc.arguments == {}
    assert (r1.usage.input_tokens, r1.usage.output_tokens, r1.usage.cache_read_tokens, r1.usage.cache_write_tokens) == (120, 30, 1000, 64)
    assert r1.waited_s == 0 and r1.latency_s > 0 and r1.request_id == "req_1" and sleeps == []
    req = server.requests[0]
    assert req["model"] == "claude-opus-5" and req["max_tokens"] == 128000
    assert req["thinking"] == {"type": "adaptive"} and req["output_config"] == {"effort": "high"}
    assert "temperature" not in req
    assert req["system"][0]["text"] == "SYSTEM" and req["system"][0]["cache_control"] == {"type": "ephemeral"}
    assert [t["name"] for t in req["tools"]] == ["capture_head", "run_code", "done"] and "input_schema" in req["tools"][1]
    assert req["messages"][0]["content"][-1]["cache_control"] == {"type": "ephemeral"}
    hdr = {k.lower(): v for k, v in server.headers[0].items()}
    assert "sk-test" in (hdr.get("x-api-key"), hdr.get("authorization", "").removeprefix("Bearer "))

    png = b"\x89PNG\r\n\x1a\nfake"
    hist += [r1.message, Message("tool", [ToolResult("toolu_1", "capture_head", '{"obs_id": "obs_0001"}',
                                                     images=[Image(png, "obs_0001", "obs_0001 head")])], cache_breakpoint=True)]
    r2 = p.complete("SYSTEM", hist, TOOLS)
    assert r2.message.parts[0].arguments == {"code": "result = 1 + 1"}
    msgs = server.requests[1]["messages"]
    assert [m["role"] for m in msgs] == ["user", "assistant", "user"]
    assert msgs[1]["content"][0] == {"type": "thinking", "thinking": "look first", "signature": "sig1"}
    tr = msgs[2]["content"][0]
    assert tr["type"] == "tool_result" and tr["tool_use_id"] == "toolu_1"
    assert tr["content"][0] == {"type": "text", "text": '{"obs_id": "obs_0001"}'}
    assert tr["content"][1]["type"] == "image" and tr["content"][1]["source"]["media_type"] == "image/png"
    assert tr["cache_control"] == {"type": "ephemeral"}

    hist += [r2.message, Message("tool", [ToolResult("toolu_2", "run_code", '{"result": 2}')])]
    r3 = p.complete("SYSTEM", hist, TOOLS)
    assert r3.message.parts[0].name == "done" and r3.message.parts[0].arguments["success_claim"] is True
    assert server.requests[2]["messages"][-1]["content"][0]["content"][0]["text"] == '{"result": 2}'


def test_rate_limit_then_success(server, monkeypatch):
    p, sleeps = _provider(server, monkeypatch)
    server.script = [error(429, "rate_limit_error"), message([tool_use(1, "capture_head", {})])]
    r = p.complete("S", [Message("user", [Text("go")])], TOOLS)
    assert len(server.requests) == 2 and len(sleeps) == 1 and 0 <= sleeps[0] <= 60
    assert r.waited_s == pytest.approx(sleeps[0], abs=0.05) and r.message.parts[0].name == "capture_head"


def test_server_error_storm_is_a_provider_failure(server, monkeypatch):
    p, sleeps = _provider(server, monkeypatch, retry={"max_attempts": 3})
    server.script = [error(500, "api_error"), error(529, "overloaded_error"), error(503, "api_error")]
    with pytest.raises(ProviderError) as ei:
        p.complete("S", [Message("user", [Text("go")])], TOOLS)
    assert ei.value.kind == "server" and ei.value.status == 503 and len(server.requests) == 3 and len(sleeps) == 2


@pytest.mark.parametrize("status,etype,msg,kind", [
    (401, "authentication_error", "invalid x-api-key", "auth"),
    (400, "invalid_request_error", "prompt is too long: 250000 tokens > 200000 maximum", "context_length"),
    (400, "invalid_request_error", "tools.0: bad schema", "bad_request"),
])
def test_permanent_errors_are_not_retried(server, monkeypatch, status, etype, msg, kind):
    p, sleeps = _provider(server, monkeypatch)
    server.script = [error(status, etype, msg)]
    with pytest.raises(ProviderError) as ei:
        p.complete("S", [Message("user", [Text("go")])], TOOLS)
    assert ei.value.kind == kind and len(server.requests) == 1 and sleeps == []


def test_wire_merges_followup_user_and_drops_foreign_thinking():
    msgs = [Message("user", [Text("task")]),
            Message("assistant", [Thinking("x", "enc", "openai"), ToolCall("a", "capture_head", {}), ToolCall("b", "done", None)]),
            Message("tool", [ToolResult("a", "capture_head", "{}")]),
            Message("tool", [ToolResult("b", "done", '{"error": "bad"}', is_error=True)]),
            Message("user", [Text("Respond with tool calls.")])]
    w = to_wire(msgs)
    assert [m["role"] for m in w] == ["user", "assistant", "user"]
    assert [b["type"] for b in w[1]["content"]] == ["tool_use", "tool_use"] and w[1]["content"][1]["input"] == {}
    assert [b["type"] for b in w[2]["content"]] == ["tool_result", "tool_result", "text"]
    assert w[2]["content"][1]["is_error"] is True


# --- configs and preflight ---------------------------------------------------------------------
CONF = Path(__file__).resolve().parents[1] / "plugins" / "harness_reference" / "cab_harness_reference" / "conf" / "model"


@pytest.mark.parametrize("name,env", [("opus5", "ANTHROPIC_API_KEY"), ("sonnet5", "ANTHROPIC_API_KEY")])
def test_paper_config_preflight_names_the_variable(name, env, monkeypatch):
    import yaml

    cfg = yaml.safe_load((CONF / f"{name}.yaml").read_text())
    assert cfg["harness"] == "reference" and cfg["provider"] == "anthropic" and cfg["max_output_tokens"] == 128000
    assert rates(cfg["pricing"])["output_per_mtok"] > 0
    monkeypatch.delenv(env, raising=False)
    with pytest.raises(ConfigError, match=env):
        ReferenceHarness({}).preflight(cfg)
    monkeypatch.setenv(env, "sk-test")
    ReferenceHarness({}).preflight(cfg)


# --- one full attempt on SAPIEN, the fake server answering -------------------------------------
@pytest.mark.sim
def test_full_attempt_with_sapien(server, monkeypatch, tmp_path):
    pytest.importorskip("sapien")
    from hydra import compose, initialize_config_module

    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-test")
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(
            ["model=opus5", "task=beat_block_hammer", f"model.base_url={server.url}", "record.video=false"]))
    spec = attempt_spec(cfg, tmp_path)
    assert spec.harness == "reference"
    harness = ReferenceHarness({"name": "reference"})
    harness.preflight(spec.model_cfg)  # before the simulator starts
    harness.provider.retry_policy.sleep = lambda s: None
    code = "h = capture_head()\nresult = {'obs': h['obs_id']}"
    server.script = [
        message([{"type": "text", "text": "Look first."}, tool_use(1, "capture_head", {})]),
        error(429, "rate_limit_error"),
        message([tool_use(2, "run_code", {"code": code})]),
        message([tool_use(3, "done", {"report": "looked twice", "success_claim": False})], stop="tool_use"),
    ]
    ep = Episode(spec, all_tasks()[spec.task], create("simulators", spec.sim, spec.sim_cfg),
                 create("planners", spec.planner, {}), create("embodiments", spec.embodiment, {}))
    try:
        harness.run(ep, spec.model_cfg)
        res = ep.finish()
    finally:
        ep.close()
    assert res["termination"]["reason"] == "done" and res["claim"]["success_claim"] is False
    assert res["budget"]["tool_calls_used"] == 2
    assert len(server.requests) == 4
    first = server.requests[0]
    assert first["messages"][0]["content"][0]["text"] == ep.instruction.strip()
    assert "Tool calls:" in first["system"][0]["text"] and first["max_tokens"] == 128000
    tr = server.requests[1]["messages"][-1]["content"][0]
    assert tr["type"] == "tool_result" and any(b["type"] == "image" for b in tr["content"])
    tr = server.requests[3]["messages"][-1]["content"][0]
    payload = json.loads(tr["content"][0]["text"])
    assert payload["value"]["obs"].startswith("obs") and any(b["type"] == "image" for b in tr["content"])
    ev = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    turns = [e for e in ev if e.get("kind", e.get("event")) == "model_turn"]
    assert len(turns) == 3 and turns[1]["waited_s"] >= 0


@pytest.mark.parametrize("name", ["opus5", "sonnet5", "gpt56", "gemini36flash", "qwen38max", "grok46", "kimik3"])
def test_every_paper_config_preflights_before_the_simulator(name, monkeypatch):
    import yaml

    cfg = yaml.safe_load((CONF / f"{name}.yaml").read_text())
    assert cfg["name"] == name and cfg["harness"] == "reference" and cfg["max_output_tokens"] > 0
    for env in ("ANTHROPIC_API_KEY", "OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY", cfg["api_key_env"]):
        monkeypatch.delenv(env, raising=False)
    try:
        h = ReferenceHarness({})
        with pytest.raises(ConfigError, match=cfg["api_key_env"]):
            h.preflight(cfg)
    except Exception as e:  # a provider module another engineer owns may be missing its SDK here
        if type(e).__name__ == "MissingDependency":
            pytest.skip(str(e))
        raise
