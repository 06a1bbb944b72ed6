"""The ``openai`` provider (Responses API) driven through the real ``openai`` SDK against a local
HTTP server thread that speaks the Responses wire format. No network."""
from __future__ import annotations

import base64
import json
import sys
from pathlib import Path

import pytest

pytest.importorskip("openai")

try:
    import cab_harness_reference  # noqa: F401
except ImportError:  # the plugin is not installed in this environment: use the source tree
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plugins" / "harness_reference"))

from fake_json_api import PNG, FakeServer, offline_provider  # noqa: E402
from helpers_provider import SYSTEM, TOOLS, first_turn  # noqa: E402

from cab_core.errors import ConfigError  # noqa: E402
from cab_harness_reference.openai_provider import OpenAIProvider  # noqa: E402
from cab_harness_reference.types import Image, Message, ProviderError, Text, Thinking, ToolCall, ToolResult  # noqa: E402


def response_body(output, usage=None, status="completed", incomplete=None):
    return {"id": "resp_1", "object": "response", "created_at": 0, "model": "gpt-5.6",
            "status": status, "incomplete_details": incomplete, "output": output,
            "usage": usage or {"input_tokens": 1200, "output_tokens": 300, "total_tokens": 1500,
                               "input_tokens_details": {"cached_tokens": 1000,
                                                        "cache_write_tokens": 100},
                               "output_tokens_details": {"reasoning_tokens": 250}}}


def fcall(call_id, name, args):
    return {"type": "function_call", "id": f"fc_{call_id}", "call_id": call_id, "name": name,
            "arguments": json.dumps(args), "status": "completed"}


REASONING = {"type": "reasoning", "id": "rs_1", "summary": [{"type": "summary_text",
                                                              "text": "look first"}],
             "encrypted_content": "ENC123"}


@pytest.fixture
def key(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)
    for v in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy", "https_proxy", "all_proxy"):
        monkeypatch.delenv(v, raising=False)


def make(url, sleeps=None, **cfg):
    base = {"model": "gpt-5.6", "base_url": url, "reasoning_effort": "high",
            "max_output_tokens": 128000,
            "retry": {"max_attempts": 3, "base_delay_s": {"rate_limit": 5.0, "server": 2.0}}}
    return offline_provider(OpenAIProvider, base, cfg, sleeps)


def test_missing_key_is_one_line_naming_the_variable(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    p = OpenAIProvider({"model": "gpt-5.6"})
    with pytest.raises(ConfigError, match="OPENAI_API_KEY is not set"):
        p.check_credentials()
    assert p.capabilities.images_in_tool_results


def test_base_url_from_environment(key, monkeypatch):
    monkeypatch.setenv("OPENAI_BASE_URL", "http://127.0.0.1:9/v1")
    assert OpenAIProvider({"model": "m"}).base_url == "http://127.0.0.1:9/v1"
    assert OpenAIProvider({"model": "m", "base_url": "http://x/v1"}).base_url == "http://x/v1"


def test_two_turns_with_image_tool_result_then_done(key):
    replies = [
        (200, response_body([REASONING, {"type": "message", "id": "m1", "role": "assistant",
                                         "status": "completed", "content": [
                                             {"type": "output_text", "text": "Looking.",
                                              "annotations": []}]},
                             fcall("call_1", "run_code", {"code": "observe()"})])),
        (200, response_body([fcall("call_2", "done", {"report": "placed", "success_claim": True})],
                            usage={"input_tokens": 2000, "output_tokens": 40, "total_tokens": 2040,
                                   "input_tokens_details": {"cached_tokens": 0},
                                   "output_tokens_details": {"reasoning_tokens": 0}})),
    ]
    with FakeServer(replies) as srv:
        p = make(srv.url)
        msgs, r1 = first_turn(p)
        calls = [x for x in r1.message.parts if isinstance(x, ToolCall)]
        assert calls[0].name == "run_code" and calls[0].arguments == {"code": "observe()"}
        assert any(isinstance(x, Thinking) and x.text == "look first" for x in r1.message.parts)
        assert r1.usage.cache_read_tokens == 1000 and r1.usage.cache_write_tokens == 100
        assert r1.usage.input_tokens == 100 and r1.usage.output_tokens == 300
        assert r1.usage.reasoning_tokens == 250
        assert r1.request_id == "req_1" and r1.waited_s == 0.0 and r1.latency_s > 0

        msgs += [r1.message, Message("tool", [ToolResult(
            "call_1", "run_code", '{"ok": true, "obs": ["obs_0001"]}',
            images=[Image(PNG, "obs_0001", "obs_0001 head_camera tick 4")])],
            cache_breakpoint=True)]
        r2 = p.complete(SYSTEM, msgs, TOOLS)
        assert r2.stop_reason == "tool_calls"
        done = r2.message.parts[0]
        assert done.name == "done" and done.arguments["success_claim"] is True
        assert r2.usage.input_tokens == 2000 and r2.usage.cache_read_tokens == 0

    path, b1, h1 = srv.requests[0]
    assert path == "/v1/responses" and h1.get("authorization", h1.get("Authorization")) == "Bearer sk-test"
    assert b1["model"] == "gpt-5.6" and b1["instructions"] == "You control a robot."
    assert b1["reasoning"]["effort"] == "high" and b1["max_output_tokens"] == 128000
    assert b1["store"] is False and "reasoning.encrypted_content" in b1["include"]
    assert "temperature" not in b1
    assert [t["name"] for t in b1["tools"]] == ["run_code", "done"]
    assert b1["tools"][0]["type"] == "function"
    assert b1["input"][0]["role"] == "user"

    _, b2, _ = srv.requests[1]
    items = b2["input"]
    kinds = [i.get("type") for i in items]
    assert kinds == ["message", "reasoning", "message", "function_call", "function_call_output"]
    assert items[1]["encrypted_content"] == "ENC123" and items[1]["id"] == "rs_1"
    assert items[3]["call_id"] == "call_1" and json.loads(items[3]["arguments"]) == {"code": "observe()"}
    out = items[4]
    assert out["call_id"] == "call_1"
    assert out["output"][0] == {"type": "input_text", "text": '{"ok": true, "obs": ["obs_0001"]}'}
    assert out["output"][1]["text"] == "obs_0001 head_camera tick 4"
    img = out["output"][2]
    assert img["type"] == "input_image"
    assert img["image_url"] == "data:image/png;base64," + base64.b64encode(PNG).decode()
    assert img["prompt_cache_breakpoint"] == {"mode": "explicit"}


def test_rate_limit_then_success_waits_with_backoff(key):
    err = {"error": {"message": "Rate limit reached", "type": "requests", "code": "rate_limit_exceeded"}}
    sleeps: list[float] = []
    with FakeServer([(429, err), (200, response_body([fcall("c", "done", {"report": "x"})]))]) as srv:
        r = make(srv.url, sleeps).complete("s", [Message("user", [Text("go")])], TOOLS)
    assert len(srv.requests) == 2  # the SDK itself did not retry
    assert sleeps == [5.0] and r.waited_s == pytest.approx(5.0) and r.waited_s > 0
    assert r.stop_reason == "tool_calls"


def test_server_error_storm_ends_as_provider_failure(key):
    sleeps: list[float] = []
    with FakeServer([(500, {"error": {"message": "boom", "type": "server_error"}})]) as srv:
        with pytest.raises(ProviderError) as ei:
            make(srv.url, sleeps).complete("s", [Message("user", [Text("go")])], TOOLS)
    assert ei.value.kind == "server" and ei.value.status == 500
    assert len(srv.requests) == 3 and sleeps == [2.0, 4.0]
    assert ei.value.waited_s == pytest.approx(6.0)


@pytest.mark.parametrize("status,body,kind", [
    (400, {"error": {"message": "Your input exceeds the context window of this model.",
                     "type": "invalid_request_error", "code": "context_length_exceeded"}},
     "context_length"),
    (400, {"error": {"message": "Invalid schema", "type": "invalid_request_error"}}, "bad_request"),
    (401, {"error": {"message": "Incorrect API key", "type": "invalid_request_error"}}, "auth"),
])
def test_non_retryable_errors_are_mapped(key, status, body, kind):
    sleeps: list[float] = []
    with FakeServer([(status, body)]) as srv:
        with pytest.raises(ProviderError) as ei:
            make(srv.url, sleeps).complete("s", [Message("user", [Text("go")])], TOOLS)
    assert ei.value.kind == kind and not ei.value.retryable
    assert len(srv.requests) == 1 and sleeps == []


def test_max_output_tokens_and_malformed_arguments(key):
    body = response_body([{"type": "function_call", "id": "fc", "call_id": "c1", "name": "run_code",
                           "arguments": "{not json", "status": "completed"}])
    trunc = response_body([{"type": "message", "id": "m", "role": "assistant", "status": "incomplete",
                            "content": [{"type": "output_text", "text": "abc", "annotations": []}]}],
                          status="incomplete", incomplete={"reason": "max_output_tokens"})
    with FakeServer([(200, body), (200, trunc)]) as srv:
        p = make(srv.url)
        r = p.complete("s", [Message("user", [Text("go")])], TOOLS)
        tc = r.message.parts[0]
        assert tc.arguments is None and tc.raw_arguments == "{not json"
        r2 = p.complete("s", [Message("user", [Text("go")])], TOOLS)
        assert r2.stop_reason == "max_tokens"


@pytest.mark.parametrize("name,cls,key_env", [("gpt56", "OpenAIProvider", "OPENAI_API_KEY"),
                                              ("astra", "OpenAIProvider", "OPENAI_API_KEY"),
                                              ("qwen_local", "OpenAICompatibleProvider", None)])
def test_model_configs_build_through_the_plugin(name, cls, key_env):
    import yaml

    from cab_harness_reference.plugin import PROVIDERS

    cfg = yaml.safe_load((Path(__file__).resolve().parents[1] / "plugins" / "harness_reference" / "cab_harness_reference"
                          / "conf" / "model" / f"{name}.yaml").read_text())
    p = PROVIDERS[cfg["provider"]](cfg)
    assert type(p).__name__ == cls and p.key_env == key_env
    assert p.retry.max_attempts == 3
