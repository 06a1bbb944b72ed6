"""The ``google`` provider driven through the real google-genai SDK against a local HTTP server
(127.0.0.1, a thread in the test) that speaks the generateContent wire format. No network."""
from __future__ import annotations

import base64
import json
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("google.genai")

try:
    import cab_harness_reference  # noqa: F401
except ImportError:  # the plugin is not installed: use the source tree
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plugins" / "harness_reference"))

from fake_json_api import JsonServer

from cab_core.errors import ConfigError
from cab_harness_reference.google_provider import GoogleProvider, inline_schema
from cab_harness_reference.types import (
    Image,
    Message,
    ProviderError,
    Text,
    Thinking,
    ToolCall,
    ToolResult,
    ToolSpec,
)

PNG = base64.b64decode(  # 1x1 PNG
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg==")
SIG = b"\x01opaque-thought-signature\xff"


class _Server(JsonServer):
    """Replies with a scripted list of (status, json) and records each request (path, headers, json);
    a ("stall", seconds) item answers nothing after that long, so the client times out."""

    def __init__(self, script):
        super().__init__()
        self.script = list(script)
        self.requests: list[dict] = []

    def answer(self, path, body, headers):
        self.requests.append({"path": path, "headers": headers, "json": body})
        status, payload = self.script.pop(0) if self.script else (500, _err(500, "INTERNAL", "empty script"))
        if status == "stall":  # answer too late: the client times out
            time.sleep(payload)
            return None
        return status, payload, {}


def _k(d, camel, snake):
    return d[camel] if camel in d else d[snake]


def _b64(s):
    return base64.urlsafe_b64decode(s.replace("+", "-").replace("/", "_"))


def _err(code, status, message):
    return {"error": {"code": code, "status": status, "message": message}}


def _ok(parts, finish="STOP", usage=None):
    return {"candidates": [{"content": {"role": "model", "parts": parts}, "finishReason": finish, "index": 0}],
            "usageMetadata": usage or {"promptTokenCount": 10, "candidatesTokenCount": 5, "totalTokenCount": 15},
            "modelVersion": "gemini-3.6-flash", "responseId": "resp-1"}


TOOLS = [
    ToolSpec("run_code", "Run a Python program.", {
        "type": "object", "properties": {"code": {"type": "string"}}, "required": ["code"]}),
    ToolSpec("compare_tcp_poses", "Compare poses.", {
        "$defs": {"TcpCandidate": {"type": "object", "additionalProperties": False,
                                   "properties": {"arm": {"type": "string", "enum": ["left", "right"]},
                                                  "title": {"type": "string"}},
                                   "required": ["arm"]}},
        "type": "object",
        "properties": {"candidates": {"type": "array", "items": {"$ref": "#/$defs/TcpCandidate"}}},
        "required": ["candidates"]}),
    ToolSpec("done", "Claim the task is complete.", {"type": "object", "properties": {}}),
]


@pytest.fixture
def env_key(monkeypatch):
    monkeypatch.delenv("GOOGLE_API_KEY", raising=False)
    monkeypatch.setenv("GEMINI_API_KEY", "test-key")


def _provider(url, sleeps=None, **cfg):
    return GoogleProvider({"model_id": "gemini-3.6-flash", "base_url": url, "timeout_s": 10, **cfg},
                          sleep=(sleeps.append if sleeps is not None else (lambda s: None)))


def test_missing_key_names_the_variable(monkeypatch):
    monkeypatch.delenv("GEMINI_API_KEY", raising=False)
    monkeypatch.delenv("GOOGLE_API_KEY", raising=False)
    p = GoogleProvider({"model_id": "gemini-3.6-flash"})
    with pytest.raises(ConfigError, match="GEMINI_API_KEY"):
        p.check_credentials()
    monkeypatch.setenv("GOOGLE_API_KEY", "k")
    p.check_credentials()
    p2 = GoogleProvider({"key_env": "MY_GEMINI_KEY"})
    with pytest.raises(ConfigError, match="MY_GEMINI_KEY"):
        p2.check_credentials()


def test_inline_schema_resolves_defs():
    s = inline_schema(TOOLS[1].parameters)
    assert "$defs" not in json.dumps(s) and "$ref" not in json.dumps(s)
    item = s["properties"]["candidates"]["items"]
    assert item["properties"]["arm"]["enum"] == ["left", "right"] and item["required"] == ["arm"]
    assert item["properties"]["title"] == {"type": "string"}  # a property named like a keyword stays


def test_two_turn_exchange_with_image_function_response(env_key):
    usage1 = {"promptTokenCount": 1200, "candidatesTokenCount": 40, "thoughtsTokenCount": 300,
              "cachedContentTokenCount": 1000, "totalTokenCount": 1540}
    turn1 = _ok([
        {"text": "Let me look at the scene.", "thought": True},
        {"functionCall": {"id": "fc-1", "name": "run_code", "args": {"code": "print(1)"}},
         "thoughtSignature": base64.b64encode(SIG).decode()},
    ], usage=usage1)
    turn2 = _ok([{"functionCall": {"name": "done", "args": {}}}])
    with _Server([(200, turn1), (200, turn2)]) as srv:
        p = _provider(srv.url)
        msgs = [Message("user", [Text("Stack the blocks.")])]
        r1 = p.complete("You are a robot.", msgs, TOOLS)
        assert r1.stop_reason == "tool_calls" and r1.request_id == "resp-1"
        calls = [x for x in r1.message.parts if isinstance(x, ToolCall)]
        assert [(c.call_id, c.name, c.arguments) for c in calls] == [("fc-1", "run_code", {"code": "print(1)"})]
        assert any(isinstance(x, Thinking) and x.text == "Let me look at the scene." for x in r1.message.parts)
        u = r1.usage
        assert (u.input_tokens, u.cache_read_tokens, u.output_tokens, u.reasoning_tokens) == (200, 1000, 340, 300)

        msgs += [r1.message,
                 Message("tool", [ToolResult("fc-1", "run_code", json.dumps({"ok": True, "obs_ids": ["obs_0001"]}),
                                             images=[Image(PNG, "obs_0001", "obs_0001 head_camera tick 1")])])]
        r2 = p.complete("You are a robot.", msgs, TOOLS)
        assert r2.stop_reason == "tool_calls"
        (done,) = [x for x in r2.message.parts if isinstance(x, ToolCall)]
        assert done.name == "done" and done.arguments == {} and done.call_id

        req1, req2 = srv.requests
        assert req1["path"].endswith("/models/gemini-3.6-flash:generateContent")
        assert req1["headers"].get("x-goog-api-key") == "test-key"
        body = req1["json"]
        assert body["systemInstruction"]["parts"][0]["text"] == "You are a robot."
        gc = body["generationConfig"]
        assert gc["maxOutputTokens"] == 65536 and "temperature" not in gc
        tc = gc["thinkingConfig"]  # the SDK sends these keys snake_case (proto JSON accepts both)
        assert tc.get("thinkingLevel", tc.get("thinking_level")) == "HIGH"
        assert tc.get("includeThoughts", tc.get("include_thoughts")) is True
        decls = {d["name"]: d for d in body["tools"][0]["functionDeclarations"]}
        assert set(decls) == {"run_code", "compare_tcp_poses", "done"}
        assert "$ref" not in json.dumps(decls) and "$defs" not in json.dumps(decls)

        c = req2["json"]["contents"]
        assert [x["role"] for x in c] == ["user", "model", "user"]
        fc_part = [x for x in c[1]["parts"] if "functionCall" in x][0]
        assert fc_part["functionCall"] == {"id": "fc-1", "name": "run_code", "args": {"code": "print(1)"}}
        assert base64.b64decode(fc_part["thoughtSignature"]) == SIG
        fr = c[2]["parts"][0]["functionResponse"]
        assert fr["id"] == "fc-1" and fr["name"] == "run_code"
        assert fr["response"]["output"] == {"ok": True, "obs_ids": ["obs_0001"]}
        assert fr["response"]["images"][0]["obs_id"] == "obs_0001"
        # the SDK passes function responses through snake_case with URL-safe base64 (proto JSON
        # accepts both spellings)
        blob = _k(fr["parts"][0], "inlineData", "inline_data")
        assert _k(blob, "mimeType", "mime_type") == "image/png" and _b64(blob["data"]) == PNG
        assert _k(blob, "displayName", "display_name") == "obs_0001.png"


def test_images_beside_function_response_and_generated_ids(env_key):
    with _Server([(200, _ok([{"functionCall": {"name": "run_code", "args": {"code": "x"}}}])),
                  (200, _ok([{"text": "All done."}]))]) as srv:
        p = _provider(srv.url, images_in_function_response=False)
        assert p.capabilities.images_in_tool_results is False
        msgs = [Message("user", [Text("go")])]
        r1 = p.complete("", msgs, TOOLS[:1])
        (call,) = [x for x in r1.message.parts if isinstance(x, ToolCall)]
        msgs += [r1.message, Message("tool", [ToolResult(call.call_id, "run_code", '{"ok": true}',
                                                         images=[Image(PNG, "obs_0002")])]),
                 Message("user", [Text("Respond with tool calls.")])]
        r2 = p.complete("", msgs, TOOLS[:1])
        assert r2.stop_reason == "end_turn" and r2.message.parts == [Text("All done.")]
        c = srv.requests[1]["json"]["contents"]
        assert [x["role"] for x in c] == ["user", "model", "user"]  # tool + user merged
        assert "id" not in c[1]["parts"][0]["functionCall"]  # made-up ids are not sent back
        parts = c[2]["parts"]
        assert "functionResponse" in parts[0] and "id" not in parts[0]["functionResponse"]
        assert any("inlineData" in x for x in parts[1:]) and parts[-1]["text"] == "Respond with tool calls."


def test_rate_limit_then_success(env_key):
    sleeps: list[float] = []
    with _Server([(429, _err(429, "RESOURCE_EXHAUSTED", "quota")), (200, _ok([{"text": "hi"}]))]) as srv:
        r = _provider(srv.url, sleeps).complete("", [Message("user", [Text("hi")])], [])
    assert r.stop_reason == "end_turn" and len(srv.requests) == 2  # the SDK itself did not retry
    assert len(sleeps) == 1 and r.waited_s == pytest.approx(sleeps[0])
    assert 0 <= sleeps[0] <= 60


def test_server_error_storm_is_provider_failure(env_key):
    sleeps: list[float] = []
    with _Server([(500, _err(500, "INTERNAL", "boom"))] * 10) as srv:
        p = _provider(srv.url, sleeps)
        with pytest.raises(ProviderError) as ei:
            p.complete("", [Message("user", [Text("hi")])], [])
    assert ei.value.kind == "server" and ei.value.status == 500
    assert len(srv.requests) == 4 and len(sleeps) == 3
    assert ei.value.waited_s == pytest.approx(sum(sleeps))


@pytest.mark.parametrize("code,status,message,kind", [
    (400, "INVALID_ARGUMENT", "bad schema", "bad_request"),
    (400, "INVALID_ARGUMENT", "The input token count (2000000) exceeds the maximum number of tokens allowed",
     "context_length"),
    (401, "UNAUTHENTICATED", "bad key", "auth"),
    (403, "PERMISSION_DENIED", "no", "auth"),
])
def test_client_errors_not_retried(env_key, code, status, message, kind):
    sleeps: list[float] = []
    with _Server([(code, _err(code, status, message))] * 3) as srv:
        with pytest.raises(ProviderError) as ei:
            _provider(srv.url, sleeps).complete("", [Message("user", [Text("hi")])], [])
    assert ei.value.kind == kind and len(srv.requests) == 1 and sleeps == []


def test_empty_completion_is_retried_and_max_tokens(env_key):
    empty = {"candidates": [], "usageMetadata": {"promptTokenCount": 3}}
    with _Server([(200, empty), (200, _ok([{"text": "part"}], finish="MAX_TOKENS"))]) as srv:
        r = _provider(srv.url).complete("", [Message("user", [Text("hi")])], [])
    assert r.stop_reason == "max_tokens" and r.raw_stop_reason == "MAX_TOKENS" and len(srv.requests) == 2


def test_timeout_is_retried(env_key):
    sleeps: list[float] = []
    with _Server([("stall", 1.5), (200, _ok([{"text": "ok"}]))]) as srv:
        r = _provider(srv.url, sleeps, timeout_s=0.5).complete("", [Message("user", [Text("hi")])], [])
    assert r.message.parts == [Text("ok")] and len(sleeps) == 1 and sleeps[0] <= 2.0
