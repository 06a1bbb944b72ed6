"""The ``openai_compatible`` provider (Chat Completions) driven through the real ``openai`` SDK
against a local HTTP server thread that speaks the Chat Completions wire format. No network."""
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
from cab_harness_reference.openai_compatible_provider import OpenAICompatibleProvider  # noqa: E402
from cab_harness_reference.types import Image, Message, ProviderError, Text, Thinking, ToolCall, ToolResult  # noqa: E402


def completion(message, finish="tool_calls", usage=None):
    return {"id": "chatcmpl-1", "object": "chat.completion", "created": 0, "model": "qwen3.8-max",
            "choices": [{"index": 0, "message": {"role": "assistant", **message},
                         "finish_reason": finish}],
            "usage": usage or {"prompt_tokens": 1500, "completion_tokens": 200, "total_tokens": 1700,
                               "prompt_tokens_details": {"cached_tokens": 1000},
                               "completion_tokens_details": {"reasoning_tokens": 150}}}


def tc(call_id, name, args):
    return {"id": call_id, "type": "function", "function": {"name": name, "arguments": json.dumps(args)}}



@pytest.fixture(autouse=True)
def no_proxy(monkeypatch):
    for v in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy", "https_proxy", "all_proxy"):
        monkeypatch.delenv(v, raising=False)
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)


def make(url, sleeps=None, **cfg):
    base = {"model": "qwen3.8-max", "base_url": url, "api_key_env": "DASHSCOPE_API_KEY",
            "max_output_tokens": 131072, "extra_body": {"enable_thinking": True},
            "retry": {"max_attempts": 3, "base_delay_s": {"rate_limit": 5.0, "server": 2.0}}}
    return offline_provider(OpenAICompatibleProvider, base, cfg, sleeps)


def test_missing_key_names_the_configured_variable(monkeypatch):
    monkeypatch.delenv("MOONSHOT_API_KEY", raising=False)
    p = OpenAICompatibleProvider({"model": "kimi-k3", "api_key_env": "MOONSHOT_API_KEY",
                                  "base_url": "https://api.moonshot.ai/v1"})
    with pytest.raises(ConfigError, match="MOONSHOT_API_KEY is not set"):
        p.check_credentials()
    assert not p.capabilities.images_in_tool_results


def test_local_server_needs_no_key(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    with FakeServer([(200, completion({"content": None, "tool_calls": [tc("c", "done", {"report": "r"})]}))]) as srv:
        p = OpenAICompatibleProvider({"model": "local", "base_url": srv.url, "api_key_env": None})
        p.check_credentials()
        r = p.complete("s", [Message("user", [Text("go")])], TOOLS)
    assert r.stop_reason == "tool_calls" and srv.requests[0][0] == "/v1/chat/completions"


def test_two_turns_images_in_follow_up_user_message_then_done(monkeypatch):
    monkeypatch.setenv("DASHSCOPE_API_KEY", "dk-test")
    replies = [
        (200, completion({"content": "Observing.", "reasoning_content": "need a look",
                          "tool_calls": [tc("call_1", "run_code", {"code": "observe()"}),
                                         tc("call_2", "run_code", {"code": "observe(2)"})]})),
        (200, completion({"content": None, "tool_calls": [tc("call_3", "done", {"report": "ok"})]},
                         usage={"prompt_tokens": 3000, "completion_tokens": 20, "total_tokens": 3020})),
    ]
    with FakeServer(replies) as srv:
        p = make(srv.url)
        msgs, r1 = first_turn(p)
        calls = [x for x in r1.message.parts if isinstance(x, ToolCall)]
        assert [c.call_id for c in calls] == ["call_1", "call_2"]
        assert calls[0].arguments == {"code": "observe()"}
        assert any(isinstance(x, Thinking) and x.text == "need a look" for x in r1.message.parts)
        u = r1.usage
        assert (u.input_tokens, u.cache_read_tokens, u.output_tokens, u.reasoning_tokens) == (500, 1000, 200, 150)
        assert r1.waited_s == 0.0 and r1.latency_s > 0

        msgs += [r1.message,
                 Message("tool", [ToolResult("call_1", "run_code", '{"obs": ["obs_0001"]}',
                                             images=[Image(PNG, "obs_0001", "obs_0001 head tick 4")])]),
                 Message("tool", [ToolResult("call_2", "run_code", '{"obs": ["obs_0002"]}',
                                             images=[Image(PNG, "obs_0002")])])]
        r2 = p.complete(SYSTEM, msgs, TOOLS)
        assert r2.message.parts[0].name == "done" and r2.usage.input_tokens == 3000

    _, b1, h1 = srv.requests[0]
    assert h1.get("authorization", h1.get("Authorization")) == "Bearer dk-test"
    assert b1["model"] == "qwen3.8-max" and b1["max_tokens"] == 131072
    assert b1["enable_thinking"] is True and "temperature" not in b1
    assert b1["messages"][0] == {"role": "system", "content": "You control a robot."}
    assert b1["tools"][0]["function"]["name"] == "run_code"

    _, b2, _ = srv.requests[1]
    m = b2["messages"]
    assert [x["role"] for x in m] == ["system", "user", "assistant", "tool", "tool", "user"]
    assert m[2]["reasoning_content"] == "need a look" and m[2]["content"] == "Observing."
    assert [t["id"] for t in m[2]["tool_calls"]] == ["call_1", "call_2"]
    assert m[3] == {"role": "tool", "tool_call_id": "call_1", "content": '{"obs": ["obs_0001"]}'}
    follow = m[5]["content"]
    assert follow[0] == {"type": "text", "text": "obs_0001 head tick 4"}
    assert follow[1]["type"] == "image_url"
    assert follow[1]["image_url"]["url"] == "data:image/png;base64," + base64.b64encode(PNG).decode()
    assert follow[2]["text"] == "[image obs_0002]" and follow[3]["type"] == "image_url"


def test_rate_limit_then_success_waits_with_backoff(monkeypatch):
    monkeypatch.setenv("DASHSCOPE_API_KEY", "dk-test")
    sleeps: list[float] = []
    err = {"error": {"message": "Requests rate limit exceeded", "code": "Throttling"}}
    ok = completion({"content": None, "tool_calls": [tc("c", "done", {"report": "x"})]})
    with FakeServer([(429, err), (200, ok)]) as srv:
        r = make(srv.url, sleeps).complete("s", [Message("user", [Text("go")])], TOOLS)
    assert len(srv.requests) == 2 and sleeps == [5.0]
    assert r.waited_s == pytest.approx(5.0) and r.stop_reason == "tool_calls"


def test_server_error_storm_ends_as_provider_failure(monkeypatch):
    monkeypatch.setenv("DASHSCOPE_API_KEY", "dk-test")
    sleeps: list[float] = []
    with FakeServer([(503, {"error": {"message": "overloaded"}})]) as srv:
        with pytest.raises(ProviderError) as ei:
            make(srv.url, sleeps).complete("s", [Message("user", [Text("go")])], TOOLS)
    assert ei.value.kind == "server" and ei.value.status == 503
    assert len(srv.requests) == 3 and sleeps == [2.0, 4.0]


def test_empty_completion_is_retried_then_text_reply_is_end_turn(monkeypatch):
    monkeypatch.setenv("DASHSCOPE_API_KEY", "dk-test")
    sleeps: list[float] = []
    with FakeServer([(200, completion({"content": ""}, finish="stop")),
                     (200, completion({"content": "I am done thinking."}, finish="stop"))]) as srv:
        r = make(srv.url, sleeps).complete("s", [Message("user", [Text("go")])], TOOLS)
    assert len(srv.requests) == 2 and sleeps == [2.0]
    assert r.stop_reason == "end_turn" and r.message.parts[-1].text == "I am done thinking."


def test_context_length_error_is_not_retried(monkeypatch):
    monkeypatch.setenv("DASHSCOPE_API_KEY", "dk-test")
    body = {"error": {"message": "This model's maximum context length is 131072 tokens.",
                      "code": "context_length_exceeded"}}
    with FakeServer([(400, body)]) as srv:
        with pytest.raises(ProviderError) as ei:
            make(srv.url).complete("s", [Message("user", [Text("go")])], TOOLS)
    assert ei.value.kind == "context_length" and len(srv.requests) == 1


def test_length_finish_and_no_reasoning_replay(monkeypatch):
    monkeypatch.setenv("XAI_API_KEY", "xk")
    with FakeServer([(200, completion({"content": "trunc"}, finish="length"))]) as srv:
        p = make(srv.url, api_key_env="XAI_API_KEY", replay_reasoning=False, extra_body=None,
                 max_tokens_param="max_completion_tokens", reasoning_effort="high")
        hist = [Message("user", [Text("go")]),
                Message("assistant", [Thinking("secret"), ToolCall("c1", "run_code", {"code": "x"})]),
                Message("tool", [ToolResult("c1", "run_code", "{}")])]
        r = p.complete("s", hist, TOOLS)
    assert r.stop_reason == "max_tokens"
    b = srv.requests[0][1]
    assert b["max_completion_tokens"] == 131072 and b["reasoning_effort"] == "high"
    assert "reasoning_content" not in b["messages"][2]
    assert b["messages"][2]["content"] is None
