"""Issue 28, local servers probed and their quirks handled: fake OpenAI-compatible servers on
127.0.0.1 that reproduce, on the real wire (``/v1/chat/completions``, ``/v1/models``, the engines'
own endpoints, SSE streaming), each quirk a real server has:

- vLLM: 400 on an image in a ``tool`` message (vllm-project/vllm #43203), 400 "At most N
  image(s) may be provided in one request" (``--limit-mm-per-prompt``), ``GET /version``;
- vLLM whose tool parser leaves the calls in ``content`` (#17161, #22885), or loses the closing
  brace of the arguments (#17790);
- llama.cpp's ``llama-server`` without ``--jinja``: 500 "tools param requires --jinja flag",
  ``GET /props``;
- Ollama: ``/v1`` keeps only the last ``num_ctx`` tokens of a prompt, silently (ollama #18107),
  ``GET /api/version``;
- a well-behaved server.

The probe must classify each, and the reference harness must complete an attempt against each
(``sim=mujoco task=click_bell``): the scripted model looks once (``capture_head``) and calls
``done``, through the real ``openai`` SDK."""
from __future__ import annotations

import json
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

pytest.importorskip("openai")

try:
    import cab_harness_reference  # noqa: F401
except ImportError:  # the plugin is not installed in this environment: use the source tree
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plugins" / "harness_reference"))

from fake_json_api import PNG  # noqa: E402

from cab_harness_reference import probe  # noqa: E402
from cab_harness_reference.context import ReferenceContextPolicy  # noqa: E402
from cab_harness_reference.openai_compatible_provider import OpenAICompatibleProvider  # noqa: E402
from cab_harness_reference.probe import probe_endpoint, salvage_calls  # noqa: E402
from cab_harness_reference.types import Capabilities, Image, Message, Text, ToolCall, ToolResult, ToolSpec  # noqa: E402

MODEL = "Qwen/Qwen2.5-VL-7B-Instruct"
DONE = {"report": "looked at the bell", "success_claim": False}


def _err(status: int, message: str, kind: str) -> tuple[int, dict]:
    return status, {"error": {"message": message, "type": kind, "param": None, "code": status}}


class FakeEndpoint:
    """An OpenAI-compatible server with one engine's quirks (see the module docstring). The model
    it serves is scripted: a request offering ``record_word`` (the probe's) gets that call; the
    harness's gets ``capture_head`` until a tool result is in the conversation, then ``done``;
    a needle question is answered from the part of the prompt the server kept."""

    def __init__(self, engine: str | None = None, *, tool_mode: str = "parsed", tool_images: bool = True,
                 image_cap: int | None = None, jinja: bool = True, num_ctx: int | None = None):
        self.engine, self.tool_mode, self.tool_images = engine, tool_mode, tool_images
        self.image_cap, self.jinja, self.num_ctx = image_cap, jinja, num_ctx
        self.requests: list[tuple[str, str, dict]] = []  # (method, path, body)
        outer = self
        server = {"vllm": "uvicorn", "llama.cpp": "llama.cpp", "ollama": "ollama"}.get(engine or "", "fake-good")

        class H(BaseHTTPRequestHandler):
            def version_string(self):
                return server

            def log_message(self, *a):
                pass

            def _send(self, status, payload, ctype="application/json"):
                data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("content-type", ctype)
                self.send_header("content-length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def do_GET(self):  # noqa: N802
                outer.requests.append(("GET", self.path, {}))
                self._send(*outer.get(self.path))

            def do_POST(self):  # noqa: N802
                body = json.loads(self.rfile.read(int(self.headers.get("content-length") or 0)) or b"{}")
                outer.requests.append(("POST", self.path, body))
                status, payload = outer.chat(body)
                if status == 200 and body.get("stream"):
                    self._send(200, outer.sse(payload), "text/event-stream")
                else:
                    self._send(status, payload)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), H)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()

    # -- GET ----------------------------------------------------------------------------------
    def get(self, path: str):
        owned = {"vllm": "vllm", "llama.cpp": "llamacpp", "ollama": "library"}.get(self.engine or "", "me")
        if path == "/v1/models":
            return 200, {"object": "list", "data": [{"id": MODEL, "object": "model", "owned_by": owned}]}
        if path == "/version" and self.engine == "vllm":
            return 200, {"version": "0.11.2"}
        if path == "/props" and self.engine == "llama.cpp":
            return 200, {"default_generation_settings": {"n_ctx": 8192, "model": MODEL}, "total_slots": 1,
                         "chat_template": "{{ messages }}", "build_info": "b6912-3f2c1a7"}
        if path == "/api/version" and self.engine == "ollama":
            return 200, {"version": "0.12.6"}
        if self.engine == "ollama":
            return 404, b"404 page not found"
        return 404, {"detail": "Not Found"}

    # -- POST ---------------------------------------------------------------------------------
    @staticmethod
    def _texts(m: dict) -> list[str]:
        c = m.get("content")
        if isinstance(c, str):
            return [c]
        return [p.get("text", "") for p in c or [] if isinstance(p, dict) and p.get("type") == "text"]

    def chat(self, body: dict):
        msgs = body.get("messages") or []
        if body.get("tools") and self.engine == "llama.cpp" and not self.jinja:
            return _err(500, "tools param requires --jinja flag", "server_error")
        images = sum(1 for m in msgs if isinstance(m.get("content"), list)
                     for p in m["content"] if p.get("type") == "image_url")
        if self.image_cap is not None and images > self.image_cap:
            return _err(400, f"At most {self.image_cap} image(s) may be provided in one request.", "BadRequestError")
        if not self.tool_images and any(m["role"] == "tool" and isinstance(m.get("content"), list) and any(
                p.get("type") == "image_url" for p in m["content"]) for m in msgs):
            return _err(400, "1 validation error for ChatCompletionToolMessageParam: content: only text content "
                             "is supported in tool messages", "BadRequestError")
        text = "\n".join(t for m in msgs for t in self._texts(m))
        prompt_tokens = len(text) // 4
        if self.num_ctx is not None and prompt_tokens > self.num_ctx:  # Ollama: the start is dropped, silently
            text = text[-self.num_ctx * 4:]
            prompt_tokens = self.num_ctx
        names = {t["function"]["name"] for t in body.get("tools") or []}
        in_prompt = not names and "<tools>" in text
        if "code word" in text and not names:
            return 200, self.completion({"content": probe.NEEDLE if probe.NEEDLE in text else "I do not know."},
                                        prompt_tokens, "stop")
        if "How many images" in text or (msgs and msgs[-1]["role"] == "tool" and msgs[-1]["tool_call_id"] == "probe_1"):
            return 200, self.completion({"content": "1"}, prompt_tokens, "stop")
        if "record_word" in names:
            name, args = "record_word", {"word": "apple"}
        elif names or in_prompt:
            seen = any(m["role"] == "tool" or (m["role"] == "user" and "<tool_response>" in json.dumps(m))
                       for m in msgs)
            name, args = ("done", DONE) if seen else ("capture_head", {})
        else:
            return 200, self.completion({"content": "Hello."}, prompt_tokens, "stop")
        n = len([r for r in self.requests if r[0] == "POST"])
        call = json.dumps({"name": name, "arguments": args})
        if self.tool_mode == "content" or in_prompt:
            return 200, self.completion({"content": f"<tool_call>\n{call}\n</tool_call>"}, prompt_tokens, "stop")
        raw = json.dumps(args)
        if self.tool_mode == "lost_brace":
            raw = raw[:-1]
        return 200, self.completion({"content": None, "tool_calls": [
            {"id": f"chatcmpl-tool-{n}", "type": "function", "function": {"name": name, "arguments": raw}}]},
            prompt_tokens, "tool_calls")

    @staticmethod
    def completion(message: dict, prompt_tokens: int, finish: str) -> dict:
        return {"id": "chatcmpl-x", "object": "chat.completion", "created": 0, "model": MODEL,
                "choices": [{"index": 0, "message": {"role": "assistant", **message}, "finish_reason": finish}],
                "usage": {"prompt_tokens": prompt_tokens, "completion_tokens": 7,
                          "total_tokens": prompt_tokens + 7}}

    @staticmethod
    def sse(completion: dict) -> bytes:
        msg = completion["choices"][0]["message"]
        chunks = [{"role": "assistant", "content": ""}]
        if msg.get("tool_calls"):
            tc = msg["tool_calls"][0]
            chunks.append({"tool_calls": [{"index": 0, "id": tc["id"], "type": "function",
                                           "function": {"name": tc["function"]["name"], "arguments": ""}}]})
            chunks.append({"tool_calls": [{"index": 0, "function": {"arguments": tc["function"]["arguments"]}}]})
        else:
            text = msg.get("content") or ""
            chunks += [{"content": text[i:i + 8]} for i in range(0, len(text), 8)]
        out = b""
        for d in chunks:
            c = {"id": "chatcmpl-x", "object": "chat.completion.chunk", "created": 0, "model": MODEL,
                 "choices": [{"index": 0, "delta": d, "finish_reason": None}]}
            out += b"data: " + json.dumps(c).encode() + b"\n\n"
        return out + b"data: [DONE]\n\n"


QUIRKS = {
    "good": {},
    "vllm": {"engine": "vllm", "tool_images": False, "image_cap": 2},
    "vllm_content": {"engine": "vllm", "tool_mode": "content"},
    "vllm_lost_brace": {"engine": "vllm", "tool_mode": "lost_brace"},
    "llama_cpp_no_jinja": {"engine": "llama.cpp", "jinja": False},
    "ollama": {"engine": "ollama", "num_ctx": 12288},
}


@pytest.fixture(autouse=True)
def fresh(monkeypatch):
    for v in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy", "https_proxy", "all_proxy", "OPENAI_BASE_URL"):
        monkeypatch.delenv(v, raising=False)
    monkeypatch.setenv("NO_PROXY", "127.0.0.1,localhost")
    probe.clear_cache()
    yield
    probe.clear_cache()


def _cfg(url: str, **kw) -> dict:
    return {"provider": "openai_compatible", "model_id": MODEL, "base_url": url, "api_key_env": None, **kw}


# -- the probe's classification -------------------------------------------------------------------

def test_well_behaved_server_has_no_problems():
    with FakeEndpoint(**QUIRKS["good"]) as srv:
        p = probe_endpoint(_cfg(srv.url))
    assert p["problems"] == [] and p["reachable"] and p["model_listed"]
    assert (p["tools"], p["tool_calls"], p["stream_tool_calls"]) == ("accepted", "parsed", True)
    assert p["images"] is True and p["images_in_tool_results"] is True and p["max_images_per_request"] is None
    assert p["context"] == {"tested_tokens": 16384, "needle_found": True, "prompt_tokens": p["context"]["prompt_tokens"]}
    assert p["context"]["prompt_tokens"] > 16384 * 0.9 and p["effective_context_tokens"] is None
    assert p["engine"]["name"] is None and p["engine"]["server_header"] == "fake-good"
    assert p["requests"] == len(srv.requests) <= 12


def test_vllm_refuses_images_in_tool_messages_and_caps_images():
    with FakeEndpoint(**QUIRKS["vllm"]) as srv:
        p = probe_endpoint(_cfg(srv.url))
    assert p["engine"] == {"name": "vllm", "version": "0.11.2", "source": "GET /version",
                           "server_header": "uvicorn", "owned_by": "vllm"}
    assert p["images_in_tool_results"] is False and "only text content" in p["images_in_tool_results_error"]
    assert p["max_images_per_request"] == 2 and p["images"] is True
    assert p["tool_calls"] == "parsed"
    assert len(p["problems"]) == 2
    assert "at most 2 image(s)" in p["problems"][0] and "--limit-mm-per-prompt" in p["problems"][0]
    assert "refused in tool messages" in p["problems"][1]


def test_vllm_parser_leaving_calls_in_content():
    with FakeEndpoint(**QUIRKS["vllm_content"]) as srv:
        p = probe_endpoint(_cfg(srv.url))
    assert p["tool_calls"] == "content" and p["stream_tool_calls"] is False
    assert len(p["problems"]) == 1 and "--tool-call-parser" in p["problems"][0]


def test_vllm_parser_losing_a_brace():
    with FakeEndpoint(**QUIRKS["vllm_lost_brace"]) as srv:
        p = probe_endpoint(_cfg(srv.url))
    assert p["tool_calls"] == "broken_json" and p["stream_tool_calls"] is True
    assert len(p["problems"]) == 1 and "unparseable arguments" in p["problems"][0]


def test_llama_cpp_without_jinja():
    with FakeEndpoint(**QUIRKS["llama_cpp_no_jinja"]) as srv:
        p = probe_endpoint(_cfg(srv.url))
    assert p["engine"]["name"] == "llama.cpp" and p["engine"]["version"] == "b6912-3f2c1a7"
    assert p["engine"]["n_ctx"] == 8192 and p["engine"]["source"] == "GET /props"
    assert p["tools"] == "rejected" and "HTTP 500" in p["tools_error"] and "--jinja" in p["tools_error"]
    assert p["tool_calls"] is None and p["stream_tool_calls"] is None and p["images_in_tool_results"] is None
    assert len(p["problems"]) == 1 and "start llama-server with --jinja" in p["problems"][0]


def test_ollama_truncation_found_by_the_needle():
    with FakeEndpoint(**QUIRKS["ollama"]) as srv:
        p = probe_endpoint(_cfg(srv.url))
    assert p["engine"]["name"] == "ollama" and p["engine"]["version"] == "0.12.6"
    assert p["context"]["needle_found"] is False and p["context"]["prompt_tokens"] == 12288
    assert p["effective_context_tokens"] == 12288
    assert len(p["problems"]) == 1 and "keeps only 12288 tokens of a 16384-token prompt" in p["problems"][0]
    assert "OLLAMA_CONTEXT_LENGTH" in p["problems"][0]


def test_an_endpoint_failing_every_request_is_not_taken_for_one_refusing_tools():
    class Broken(FakeEndpoint):
        def chat(self, body):
            return 401, {"error": {"message": "Incorrect API key provided", "type": "invalid_request_error",
                                   "code": "invalid_api_key"}}

    with Broken() as srv:
        p = probe_endpoint(_cfg(srv.url))
    assert p["tools"] == "unknown" and "HTTP 401" in p["tools_error"]
    assert "fails a plain request too (HTTP 401: Incorrect API key provided)" in p["problems"][0]
    prov = OpenAICompatibleProvider(_cfg(srv.url))
    prov.apply_profile(p)
    assert not prov.tools_in_prompt  # the harness keeps sending tools; the request's own error ends it


def test_needle_size_follows_the_configured_context_and_vllm_limit_is_read():
    class Short(FakeEndpoint):
        def chat(self, body):
            text = "".join(t for m in body["messages"] for t in self._texts(m))
            if len(text) // 4 > 4096:
                return _err(400, f"This model's maximum context length is 4096 tokens. However, you requested "
                                 f"{len(text) // 4} tokens. Please reduce the length of the messages.",
                            "BadRequestError")
            return super().chat(body)

    with Short("vllm") as srv:
        p = probe_endpoint(_cfg(srv.url, context_tokens=10000))
    assert p["context"]["tested_tokens"] == 9000 and p["effective_context_tokens"] == 4096
    assert any("serves a context of 4096 tokens" in x for x in p["problems"])


def test_unreachable_endpoint_is_not_cached(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    p = probe_endpoint(_cfg(f"http://127.0.0.1:{port}/v1"), cache_dir=tmp_path)
    assert p["reachable"] is False and "nothing answers" in p["problems"][0] and p["requests"] == 1
    assert not probe._cache and not list(tmp_path.iterdir())


def test_profile_cached_per_endpoint_in_process_and_folder(tmp_path):
    with FakeEndpoint() as srv:
        first = probe_endpoint(_cfg(srv.url), cache_dir=tmp_path)
        n = len(srv.requests)
        assert probe_endpoint(_cfg(srv.url)) is first and len(srv.requests) == n
        probe.clear_cache()
        again = probe_endpoint(_cfg(srv.url), cache_dir=tmp_path)  # another process: from the folder
        assert again == json.loads(json.dumps(first)) and len(srv.requests) == n
    (f,) = tmp_path.iterdir()
    assert f.name.startswith("endpoint-probe-")


def test_probe_auto_only_for_local_servers():
    assert probe.wants_probe({"api_key_env": None})
    assert not probe.wants_probe({"api_key_env": "DASHSCOPE_API_KEY"})
    assert not probe.wants_probe({})  # the default key variable: a hosted API
    assert probe.wants_probe({"api_key_env": "X", "probe": True})
    assert not probe.wants_probe({"api_key_env": None, "probe": False})


# -- salvage and the policy's image cap (units) -------------------------------------------------

def test_salvage_tagged_bare_and_repaired_calls():
    names = {"done", "capture_head"}
    calls, rest = salvage_calls('Looking.\n<tool_call>\n{"name": "capture_head", "arguments": {}}\n</tool_call>', names)
    assert calls == [("capture_head", {})] and rest == "Looking."
    two = ('<tool_call>{"name": "capture_head", "arguments": {}}</tool_call>'
           '<tool_call>{"name": "done", "arguments": "{\\"report\\": \\"r\\"}"}</tool_call>')
    assert salvage_calls(two, names)[0] == [("capture_head", {}), ("done", {"report": "r"})]
    assert salvage_calls('{"name": "done", "arguments": {"report": "r"}', names)[0] == [("done", {"report": "r"})]
    assert salvage_calls('```json\n{"name": "done", "arguments": {}}\n```', names)[0] == [("done", {})]
    # a lost brace is repaired only where that gives exactly one call
    broken_two = ('<tool_call>{"name": "capture_head", "arguments": {}</tool_call>'
                  '<tool_call>{"name": "done", "arguments": {}}</tool_call>')
    assert salvage_calls(broken_two, names) == ([], broken_two)
    assert salvage_calls('[{"name": "done", "arguments": {}}, {"name": "done", "arguments": {}', names)[0] == []
    # unknown tools and plain text are left alone
    assert salvage_calls('{"name": "rm_rf", "arguments": {}}', names)[0] == []
    assert salvage_calls("I will look first.", names) == ([], "I will look first.")


def test_provider_salvages_and_marks_calls():
    p = OpenAICompatibleProvider(_cfg("http://127.0.0.1:9/v1"))
    p.request_kwargs("s", [Message("user", [Text("go")])], [ToolSpec("done", "", {})])

    class Obj:
        def __init__(self, **kw):
            self.__dict__.update(kw)

    def resp(content, tool_calls=None):
        msg = Obj(content=content, tool_calls=tool_calls, refusal=None, model_extra={})
        return Obj(choices=[Obj(message=msg, finish_reason="stop")], usage=None, model=MODEL, id="x")

    r = p.from_completion(resp('Done now.\n<tool_call>{"name": "done", "arguments": {"report": "r"}}</tool_call>'))
    (call,) = [x for x in r.message.parts if isinstance(x, ToolCall)]
    assert call.salvaged and call.arguments == {"report": "r"} and r.stop_reason == "tool_calls"
    assert [x.text for x in r.message.parts if isinstance(x, Text)] == ["Done now."]
    fn = Obj(name="done", arguments='{"report": "r"')
    r = p.from_completion(resp(None, [Obj(id="c1", function=fn)]))
    (call,) = r.message.parts
    assert call.salvaged and call.arguments == {"report": "r"} and call.call_id == "c1"
    two = [Obj(id="c1", function=fn), Obj(id="c2", function=Obj(name="done", arguments="{}"))]
    r = p.from_completion(resp(None, two))  # two calls: no repair, the broken one stays malformed
    assert [(c.arguments, c.salvaged) for c in r.message.parts] == [(None, False), ({}, False)]


def test_policy_keeps_the_newest_images_under_the_servers_cap():
    pol = ReferenceContextPolicy(max_image_rounds=10)
    msgs = [Message("user", [Text("go")])]
    for i in range(3):
        msgs += [Message("assistant", [ToolCall(f"c{i}", "capture_head", {})]),
                 Message("tool", [ToolResult(f"c{i}", "capture_head", "{}",
                                             images=[Image(PNG + bytes([i, j]), f"obs_{i}{j}") for j in range(2)])])]
    out = pol.build(msgs, Capabilities(images_in_tool_results=True, max_images_per_request=3))
    kept = [img.obs_id for m in out for p in m.parts if isinstance(p, ToolResult) for img in p.images]
    assert kept == ["obs_11", "obs_20", "obs_21"]
    texts = [p.text for m in out for p in m.parts if isinstance(p, ToolResult)]
    assert "obs_00" in texts[0] and "at most 3 image(s)" in texts[0] and "obs_10" in texts[1]
    out = pol.build(msgs, Capabilities(images_in_tool_results=True))
    assert sum(len(p.images) for m in out for p in m.parts if isinstance(p, ToolResult)) == 6


def test_report_notes_server_side_faults_apart():
    from cab_core.analysis.measures import _server_side
    from cab_core.analysis.report import notes

    events = [{"kind": "endpoint_probe", "problems": ["llama.cpp answers 500 to tools: start llama-server with --jinja"]},
              {"kind": "model_turn", "tool_calls": [{"name": "done", "arguments": {}, "salvaged": True},
                                                    {"name": "done", "arguments": None, "raw_arguments": "{"}]},
              {"kind": "provider_failure", "error_kind": "server", "status": 500}]
    ss = _server_side(events)
    assert ss == {"salvaged_calls": 1, "unparseable_calls": 1, "ended_by_server_error": True,
                  "probe_problems": ["llama.cpp answers 500 to tools: start llama-server with --jinja"]}
    assert not _server_side([{"kind": "provider_failure", "error_kind": "auth"}])["ended_by_server_error"]
    r = {"attempts": 1, "sweep": None, "in_flight": [], "excluded": [], "problems": [],
         "configs": [{"config": "local (reference, mujoco)", "borderline": {"attempts": []},
                      "server_side": {"salvaged_calls": 1, "unparseable_calls": 1, "attempts_ended_by_server_error": 1,
                                      "probe_problems": ss["probe_problems"]}},
                     {"config": "clean", "borderline": {"attempts": []}, "server_side": {
                         "salvaged_calls": 0, "unparseable_calls": 0, "attempts_ended_by_server_error": 0,
                         "probe_problems": []}}]}
    lines = [x for x in notes(r) if x.startswith("Server-side")]
    assert lines == ["Server-side, not the model's: local (reference, mujoco): 1 tool calls salvaged from the "
                     "server's output, 1 tool calls unparseable, 1 attempts ended by a server error; probe: "
                     "llama.cpp answers 500 to tools: start llama-server with --jinja"]


# -- an attempt against each server ----------------------------------------------------------------

def _attempt(url: str, out: Path) -> dict:
    from hydra import compose, initialize_config_module

    from cab_core.apps.cli import normalise_overrides
    from cab_core.attempt.runner import attempt_spec, run_attempt

    overrides = ["task=click_bell", "sim=mujoco", "model=qwen_local", f"model.base_url={url}", "record.video=false"]
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(overrides))
    return run_attempt(attempt_spec(cfg, out))


def _events(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines() if x.strip()]


@pytest.mark.sim
@pytest.mark.parametrize("quirk", list(QUIRKS))
def test_harness_completes_an_attempt_against_each_server(quirk, tmp_path):
    pytest.importorskip("mujoco")
    out = tmp_path / quirk
    with FakeEndpoint(**QUIRKS[quirk]) as srv:
        res = _attempt(srv.url, out)
    assert res["termination"]["reason"] == "done", res["termination"]
    serving = json.loads((out / "result.json").read_text())["agent"]["serving"]
    assert serving["engine"] == QUIRKS[quirk].get("engine") and serving["profile"]["model_id"] == MODEL
    ev = _events(out)
    (pr,) = [e for e in ev if e["kind"] == "endpoint_probe"]
    assert pr["problems"] == serving["profile"]["problems"]
    turns = [e for e in ev if e["kind"] == "model_turn"]
    assert [c["name"] for t in turns for c in t["tool_calls"]] == ["capture_head", "done"]
    salvaged = [c.get("salvaged", False) for t in turns for c in t["tool_calls"]]
    assert salvaged == [quirk in ("vllm_content", "vllm_lost_brace", "llama_cpp_no_jinja")] * 2
    n_probe = pr["requests"]
    gets = len([r for r in srv.requests if r[0] == "GET"])
    harness = [b for m, _, b in srv.requests[n_probe:] if m == "POST"]
    assert len(srv.requests) == n_probe + 2 and gets <= 4 and len(harness) == 2
    second = harness[1]["messages"]
    tool_imgs = [p for m in second if m["role"] == "tool" and isinstance(m["content"], list)
                 for p in m["content"] if p["type"] == "image_url"]
    user_imgs = [p for m in second if m["role"] == "user" and isinstance(m["content"], list)
                 for p in m["content"] if p["type"] == "image_url"]
    if QUIRKS[quirk].get("tool_images", True) and quirk != "llama_cpp_no_jinja":
        assert tool_imgs and not user_imgs  # the server takes images in tool messages: they go there
    else:
        assert user_imgs and not tool_imgs
    if quirk == "vllm":
        assert len(user_imgs) <= 2
    if quirk == "llama_cpp_no_jinja":  # tools described in the prompt, results sent back as text
        assert all("tools" not in b for b in harness) and "<tools>" in harness[0]["messages"][0]["content"]
        assert not any(m["role"] == "tool" for m in second)
        assert any("<tool_response>" in json.dumps(m) for m in second if m["role"] == "user")
    # the report counts the server's faults apart from the model's
    from cab_core.analysis.attempts import Attempt
    from cab_core.analysis.measures import AttemptMeasures, ConfigSummary

    m = AttemptMeasures.of(Attempt.load(out, tmp_path))
    assert m.server_side == {"salvaged_calls": sum(salvaged), "unparseable_calls": 0, "ended_by_server_error": False,
                             "probe_problems": pr["problems"]}
    summary = ConfigSummary.of(m.config, [m], 10).server_side
    assert summary["salvaged_calls"] == sum(salvaged) and summary["probe_problems"] == sorted(pr["problems"])
    from cab_core.apps.export import attempt_row  # the parquet export: the engine, and the salvaged calls

    row = attempt_row(Attempt.load(out, tmp_path), quirk)
    assert (row["serving_engine"], row["salvaged_calls"]) == (QUIRKS[quirk].get("engine"), sum(salvaged))
    assert row["serving_version"] == {"vllm": "0.11.2", "llama.cpp": "b6912-3f2c1a7", "ollama": "0.12.6"}.get(
        QUIRKS[quirk].get("engine"))
    if quirk == "ollama":
        assert pr["effective_context_tokens"] == 12288
        (ctx,) = {t["request_estimated_tokens"] <= 12288 for t in turns}  # the harness kept under it
        assert ctx


@pytest.mark.sim
def test_a_sweeps_attempts_share_one_probe(tmp_path):
    """Within a sweep (a folder with ``sweep.json``) the first attempt's profile is kept in the
    sweep's folder: another worker process (here: the process cache cleared) does not probe again."""
    pytest.importorskip("mujoco")
    from cab_harness_reference.loop import sweep_folder

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "sweep.json").write_text("{}")
    assert sweep_folder(sweep / "click_bell" / "qwen_local" / "attempt-1") == sweep.resolve()
    assert sweep_folder(tmp_path / "single") is None
    with FakeEndpoint("vllm", tool_images=False) as srv:
        _attempt(srv.url, sweep / "click_bell" / "qwen_local" / "attempt-1")
        first = len(srv.requests)
        (kept,) = sweep.glob("endpoint-probe-*.json")
        probe.clear_cache()
        res = _attempt(srv.url, sweep / "click_bell" / "qwen_local" / "attempt-2")
    assert res["termination"]["reason"] == "done"
    assert len(srv.requests) - first == 2  # the attempt's two turns, no probe
    assert res["agent"]["serving"]["profile"] == json.loads(kept.read_text())
    assert res["agent"]["serving"]["profile"]["images_in_tool_results"] is False
