"""Issue 4 acceptance: pointed at a local fake server, ``cab +model=<each provider's config>``
completes a recorded attempt whose records hold usage and cost.

For each provider config (opus5: anthropic, gpt56: openai Responses, qwen_local:
openai_compatible Chat Completions, gemini36flash: google) a fake server thread on 127.0.0.1
speaks that provider's wire format (the fakes and body builders of the provider unit tests are
reused) and the real ``cab`` entry point runs as a subprocess against it. The server scripts
``capture_head`` -> ``run_code`` -> ``done`` and the test checks the tool results travelled back,
then reads ``result.json`` and ``events.jsonl``.

gpt56, qwen_local and gemini36flash ship ``pricing: null`` (their cost records ``{"usd": null}``);
so that the cost path is exercised for every provider they are run with a ``model.pricing=``
override, and the as-shipped null cost is checked once separately (qwen_local)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("sapien")

from test_provider_anthropic import FakeAnthropic, message, tool_use  # noqa: E402
from test_provider_google import _ok, _Server  # noqa: E402
from test_provider_openai import FakeServer as FakeResponses  # noqa: E402
from test_provider_openai import fcall, response_body
from test_provider_openai_compatible import FakeServer as FakeChat  # noqa: E402
from test_provider_openai_compatible import completion, tc

BIN = os.path.dirname(sys.executable)
CODE = "result = get_arm_pose(arm='left')['tcp_pose']"
DONE = {"report": "looked and read the left arm pose", "success_claim": False}
KEY_VARS = ("ANTHROPIC_API_KEY", "OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY", "DASHSCOPE_API_KEY",
            "ANTHROPIC_BASE_URL", "OPENAI_BASE_URL", "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY",
            "http_proxy", "https_proxy", "all_proxy")
PRICING = "+model.pricing={input_per_mtok:1.0,output_per_mtok:2.0}"  # qwen_local ships unpriced (a local model)


def _cab(model, url, out, env_key, extra=()):
    env = {k: v for k, v in os.environ.items() if k not in KEY_VARS}
    env["NO_PROXY"] = env["no_proxy"] = "127.0.0.1,localhost"
    if env_key:
        env[env_key] = "sk-test-dummy"
    r = subprocess.run([os.path.join(BIN, "cab"), "+sim=sapien", f"+model={model}", "task=beat_block_hammer",
                        f"model.base_url={url}", f"hydra.run.dir={out}", "record.video=false", *extra],
                       cwd=out.parent, env=env, capture_output=True, text=True, timeout=540)
    return r


def _check_records(r, out, model, priced, n_requests):
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    res = json.loads((out / "result.json").read_text())
    assert res["model"] == model and res["task"] == "beat_block_hammer" and res["sim"] == "sapien"
    assert res["termination"]["reason"] == "done", res["termination"]
    assert res["claim"]["success_claim"] is False and res["claim"]["report"] == DONE["report"]
    assert n_requests == 3
    ev = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines() if line.strip()]
    turns = [e for e in ev if e.get("kind", e.get("event")) == "model_turn"]
    assert len(turns) == 3
    assert [t["tool_calls"][0]["name"] for t in turns] == ["capture_head", "run_code", "done"]
    for t in turns:
        u = t["usage"]
        assert u["input_tokens"] + u["cache_read_tokens"] > 0 and u["output_tokens"] > 0, u
        if priced:
            assert isinstance(t["cost"]["usd"], float) and t["cost"]["usd"] > 0, t["cost"]
        else:
            assert t["cost"] == {"usd": None}
    (total,) = [e for e in ev if e.get("kind", e.get("event")) == "model_usage_total"]
    assert total["output_tokens"] == sum(t["usage"]["output_tokens"] for t in turns)
    if priced:
        assert total["usd"] == pytest.approx(sum(t["cost"]["usd"] for t in turns), abs=1e-6)
    return turns


def _header(headers, name):
    return {k.lower(): v for k, v in headers.items()}.get(name)


@pytest.mark.sim
def test_opus5_anthropic(tmp_path):
    srv = FakeAnthropic()
    srv.script = [message([{"type": "text", "text": "Look first."}, tool_use(1, "capture_head", {})]),
                  message([tool_use(2, "run_code", {"code": CODE})]),
                  message([tool_use(3, "done", DONE)])]
    try:
        r = _cab("opus5", srv.url, tmp_path / "d", "ANTHROPIC_API_KEY")
    finally:
        srv.close()
    turns = _check_records(r, tmp_path / "d", "opus5", True, len(srv.requests))
    assert turns[0]["usage"]["input_tokens"] == 120 and turns[0]["usage"]["cache_read_tokens"] == 1000
    h = srv.headers[0]  # the SDK sends the key as x-api-key or (some versions) Authorization
    assert _header(h, "x-api-key") == "sk-test-dummy" or "sk-test-dummy" in (_header(h, "authorization") or "")
    tr = srv.requests[1]["messages"][-1]["content"][0]
    assert tr["type"] == "tool_result" and tr["tool_use_id"] == "toolu_1"
    assert any(b["type"] == "image" for b in tr["content"])
    tr = srv.requests[2]["messages"][-1]["content"][0]
    assert tr["type"] == "tool_result" and tr["tool_use_id"] == "toolu_2"
    assert "value" in json.loads(tr["content"][0]["text"])


@pytest.mark.sim
def test_gpt56_openai_responses(tmp_path):
    replies = [(200, response_body([fcall("call_1", "capture_head", {})])),
               (200, response_body([fcall("call_2", "run_code", {"code": CODE})])),
               (200, response_body([fcall("call_3", "done", DONE)]))]
    with FakeResponses(replies) as srv:
        r = _cab("gpt56", srv.url, tmp_path / "d", "OPENAI_API_KEY", [])  # priced as shipped (the paper's rates)
    turns = _check_records(r, tmp_path / "d", "gpt56", True, len(srv.requests))
    assert turns[0]["usage"]["input_tokens"] == 100 and turns[0]["usage"]["cache_read_tokens"] == 1000
    path, b2, h = srv.requests[1]
    assert path == "/v1/responses" and _header(h, "authorization") == "Bearer sk-test-dummy"
    (out,) = [i for i in b2["input"] if i.get("type") == "function_call_output"]
    assert out["call_id"] == "call_1" and any(p["type"] == "input_image" for p in out["output"])
    outs = [i for i in srv.requests[2][1]["input"] if i.get("type") == "function_call_output"]
    assert outs[-1]["call_id"] == "call_2" and "value" in json.loads(outs[-1]["output"][0]["text"])


def _qwen_script():
    return [(200, completion({"content": "Looking.", "tool_calls": [tc("call_1", "capture_head", {})]})),
            (200, completion({"content": None, "tool_calls": [tc("call_2", "run_code", {"code": CODE})]})),
            (200, completion({"content": None, "tool_calls": [tc("call_3", "done", DONE)]}))]


def _check_qwen_wire(srv):
    path, b2, h = srv.requests[1]
    assert path == "/v1/chat/completions" and b2["model"] == "Qwen/Qwen2.5-VL-7B-Instruct"
    m = b2["messages"]
    tool = [x for x in m if x["role"] == "tool"]
    assert tool and tool[-1]["tool_call_id"] == "call_1"
    # Chat Completions puts images in a follow-up user message after the tool messages
    assert m[-1]["role"] == "user" and any(p.get("type") == "image_url" for p in m[-1]["content"])
    tool = [x for x in srv.requests[2][1]["messages"] if x["role"] == "tool"]
    assert tool[-1]["tool_call_id"] == "call_2" and "value" in json.loads(tool[-1]["content"])


@pytest.mark.sim
def test_qwen_local_openai_compatible(tmp_path):
    with FakeChat(_qwen_script()) as srv:
        # api_key_env: null; the scripted server answers turns only (the endpoint probe: tests/test_probe.py)
        r = _cab("qwen_local", srv.url, tmp_path / "d", None, [PRICING, "model.probe=false"])
    turns = _check_records(r, tmp_path / "d", "qwen_local", True, len(srv.requests))
    assert turns[0]["usage"]["input_tokens"] == 500 and turns[0]["usage"]["cache_read_tokens"] == 1000
    _check_qwen_wire(srv)


@pytest.mark.sim
def test_qwen_local_as_shipped_records_null_cost(tmp_path):
    """``pricing: null`` (a local server has no API cost): usage is recorded, cost is ``{"usd": null}``."""
    with FakeChat(_qwen_script()) as srv:
        r = _cab("qwen_local", srv.url, tmp_path / "d", None, ["model.probe=false"])
    _check_records(r, tmp_path / "d", "qwen_local", False, len(srv.requests))


@pytest.mark.sim
def test_gemini36flash_google(tmp_path):
    usage = {"promptTokenCount": 1200, "candidatesTokenCount": 40, "thoughtsTokenCount": 300,
             "cachedContentTokenCount": 1000, "totalTokenCount": 1540}
    script = [(200, _ok([{"functionCall": {"id": "fc-1", "name": "capture_head", "args": {}}}], usage=usage)),
              (200, _ok([{"functionCall": {"id": "fc-2", "name": "run_code", "args": {"code": CODE}}}], usage=usage)),
              (200, _ok([{"functionCall": {"id": "fc-3", "name": "done", "args": DONE}}], usage=usage))]
    with _Server(script) as srv:
        r = _cab("gemini36flash", srv.url, tmp_path / "d", "GEMINI_API_KEY", [])  # priced as shipped
    turns = _check_records(r, tmp_path / "d", "gemini36flash", True, len(srv.requests))
    u = turns[0]["usage"]
    assert (u["input_tokens"], u["cache_read_tokens"], u["output_tokens"]) == (200, 1000, 340)
    req = srv.requests[1]
    assert req["path"].endswith("/models/gemini-3.6-flash:generateContent")
    assert _header(req["headers"], "x-goog-api-key") == "sk-test-dummy"
    parts = req["json"]["contents"][-1]["parts"]
    (fr,) = [p["functionResponse"] for p in parts if "functionResponse" in p]
    assert fr["id"] == "fc-1" and fr["name"] == "capture_head"
    blobs = [x for x in fr.get("parts", []) if "inlineData" in x or "inline_data" in x] + \
            [x for x in parts if "inlineData" in x or "inline_data" in x]
    assert blobs, parts  # the head image travels with (or beside) the function response
    parts = srv.requests[2]["json"]["contents"][-1]["parts"]
    (fr,) = [p["functionResponse"] for p in parts if "functionResponse" in p]
    assert fr["id"] == "fc-2" and "value" in fr["response"]["output"]
