"""The reference harness on Inspect AI's model API (provider ``inspect``, issue 29): a whole attempt
driven by Inspect's ``mockllm/model`` with scripted outputs (the oracle's calls for click_bell, on
MuJoCo); Inspect's real OpenAI-compatible provider (``openai-api/<service>/<model>``) against cab's
fake OpenAI server, through rate limits, server errors and an outage; and the equivalence of the
requests: for the same model turns, the harness sends through Inspect what it sends through cab's own
``openai_compatible`` provider, compared at the wire.

The scripted mockllm outputs reach the attempt process through the test route the provider documents:
``model.model_args.custom_outputs`` given as a JSON file of Inspect ``ModelOutput`` objects. Each
carries its usage: without one, mockllm counts tokens with tiktoken, whose encoding it downloads."""
from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("inspect_ai")
pytest.importorskip("openai")

sys.path.insert(0, str(Path(__file__).parent))
from fake_json_api import PNG, JsonServer, TopOfRange  # noqa: E402

from cab_core.errors import ConfigError  # noqa: E402
from cab_core.testing.fake_openai import MODEL_ID, FakeOpenAIServer  # noqa: E402
from cab_harness_reference.inspect_provider import (  # noqa: E402
    InspectProvider,
    classify_error,
    from_output,
    to_inspect,
)
from cab_harness_reference.types import (  # noqa: E402
    Image,
    Message,
    ProviderError,
    Text,
    Thinking,
    ToolCall,
    ToolResult,
    ToolSpec,
)

TOOLS = [ToolSpec("done", "Finish", {"type": "object", "properties": {"report": {"type": "string"}},
                                     "required": ["report"], "additionalProperties": False})]
USER = [Message("user", [Text("Put the cube in the bin.")])]
CAB = [os.environ.get("CAB_BIN") or "cab"]


def _completion(name="done", args=None, call_id="c1", usage=None):
    return {"id": "chatcmpl-1", "object": "chat.completion", "created": 0, "model": MODEL_ID,
            "choices": [{"index": 0, "finish_reason": "tool_calls", "message": {
                "role": "assistant", "content": None, "tool_calls": [{"id": call_id, "type": "function", "function": {
                    "name": name, "arguments": json.dumps(args if args is not None else {"report": "r"})}}]}}],
            "usage": usage or {"prompt_tokens": 10, "completion_tokens": 5, "total_tokens": 15}}


def _error(message, etype="server_error", code=None):
    return {"error": {"message": message, "type": etype, "code": code}}


class Scripted(JsonServer):
    """Chat Completions answered from a list of ``(status, body, headers)``, one per POST (the last
    answers every request after it); each request's time and body are kept."""

    base_path = "/v1"

    def __init__(self, replies):
        super().__init__()
        self.replies = list(replies)
        self.requests: list[tuple[float, str, dict]] = []

    def answer(self, path, body, headers):
        self.requests.append((time.monotonic(), path, body))
        return self.replies.pop(0) if len(self.replies) > 1 else self.replies[0]


def closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def provider(url: str, sleeps: list | None = None, **cfg) -> InspectProvider:
    """Inspect's OpenAI-compatible provider on ``url`` (service ``fake``: its key in FAKE_API_KEY),
    the SDK's own retries off so that Inspect's retry loop (cab's backoff) handles every failure;
    jitter at the top of its range."""
    base = {"model_id": f"openai-api/fake/{MODEL_ID}", "base_url": url, "model_args": {"max_retries": 0},
            "retry": {"max_attempts": 3, "base_delay_s": {"server": 0.05, "rate_limit": 0.05, "unreachable": 0.05,
                                                  "overloaded": 0.05}}}
    return InspectProvider(dict(base, **cfg), rng=TopOfRange())


@pytest.fixture(autouse=True)
def _fake_key(monkeypatch):
    monkeypatch.setenv("FAKE_API_KEY", "sk-fake")


# -- the conversion ---------------------------------------------------------------------------------

def test_a_cab_request_becomes_inspects_messages_and_tools():
    from inspect_ai.model import (
        ChatMessageAssistant,
        ChatMessageSystem,
        ChatMessageTool,
        ChatMessageUser,
        ContentImage,
        ContentText,
    )

    img = Image(PNG, "obs_0001", "obs_0001 from capture_head (c1)")
    msgs = USER + [Message("assistant", [Text("looking"), ToolCall("c1", "capture_head", {})]),
                   Message("tool", [ToolResult("c1", "capture_head", '{"obs_id": "obs_0001"}', images=[img])])]
    # the provider takes images in tool messages: they stay in the tool message, after its label
    inp, infos = to_inspect("sys", msgs, TOOLS, images_in_tool_results=True)
    assert [type(m) for m in inp] == [ChatMessageSystem, ChatMessageUser, ChatMessageAssistant, ChatMessageTool]
    assert inp[1].content == "Put the cube in the bin."
    assert inp[2].text == "looking" and [(c.id, c.function, c.arguments) for c in inp[2].tool_calls] == \
        [("c1", "capture_head", {})]
    tool = inp[3]
    assert tool.tool_call_id == "c1" and tool.function == "capture_head"
    assert [type(c) for c in tool.content] == [ContentText, ContentText, ContentImage]
    assert tool.content[1].text == "obs_0001 from capture_head (c1)"
    assert tool.content[2].image.startswith("data:image/png;base64,")
    # it does not: the images follow the tool messages in one user message
    inp, _ = to_inspect("sys", msgs, TOOLS, images_in_tool_results=False)
    assert inp[3].content == '{"obs_id": "obs_0001"}'
    assert isinstance(inp[4], ChatMessageUser) and [type(c) for c in inp[4].content] == [ContentText, ContentImage]
    assert [(t.name, t.description, t.parameters.model_dump(exclude_none=True)) for t in infos] == \
        [("done", "Finish", {"type": "object", "properties": {"report": {"type": "string"}}, "required": ["report"],
                             "additionalProperties": False})]


def test_a_schema_with_references_reaches_inspect_inlined():
    schema = {"type": "object", "$defs": {"P": {"type": "object", "properties": {"x": {"type": "number"}}}},
              "properties": {"p": {"$ref": "#/$defs/P", "description": "a point"}}, "required": ["p"]}
    (info,) = to_inspect("", [], [ToolSpec("go", "Go", schema)])[1]
    assert info.parameters.model_dump(exclude_none=True)["properties"] == \
        {"p": {"type": "object", "properties": {"x": {"type": "number"}}, "description": "a point"}}


def test_inspects_output_becomes_a_cab_response():
    from inspect_ai.model import ChatMessageAssistant, ContentReasoning, ContentText, ModelOutput, ModelUsage
    from inspect_ai.tool import ToolCall as InspectCall

    out = ModelOutput.from_message(ChatMessageAssistant(
        content=[ContentReasoning(reasoning="the bin is left", signature="sig"), ContentText(text="moving")],
        tool_calls=[InspectCall(id="a", function="done", arguments={"report": "r"}),
                    InspectCall(id="b", function="done", arguments={}, parse_error="Expecting value: {bad")]))
    out.usage = ModelUsage(input_tokens=100, output_tokens=30, input_tokens_cache_read=400,
                           input_tokens_cache_write=50, reasoning_tokens=12, total_tokens=580)
    r = from_output(out)
    assert r.stop_reason == "tool_calls"
    thinking, text, good, bad = r.message.parts
    assert isinstance(thinking, Thinking) and (thinking.text, thinking.signature) == ("the bin is left", "sig")
    assert text == Text("moving")
    assert (good.call_id, good.name, good.arguments) == ("a", "done", {"report": "r"})
    assert bad.arguments is None and "{bad" in bad.raw_arguments  # the loop answers it as malformed JSON
    u = r.usage
    assert (u.input_tokens, u.output_tokens, u.cache_read_tokens, u.cache_write_tokens, u.reasoning_tokens) == \
        (100, 30, 400, 50, 12)
    assert from_output(ModelOutput.from_content("m", "no", stop_reason="max_tokens")).stop_reason == "max_tokens"
    assert from_output(ModelOutput.from_content("m", "no", stop_reason="content_filter")).stop_reason == "refusal"
    assert from_output(ModelOutput.from_content("m", "fine", stop_reason="stop")).stop_reason == "end_turn"
    with pytest.raises(ProviderError) as e:  # Inspect's word for a request over the context window
        from_output(ModelOutput.from_content("m", "too long", stop_reason="model_length"))
    assert e.value.kind == "context_length" and not e.value.infrastructure


# -- credentials, configuration, event loops -----------------------------------------------------------

def test_the_key_inspects_provider_reads_is_checked_without_network(monkeypatch):
    monkeypatch.delenv("FAKE_API_KEY")
    p = provider(f"http://127.0.0.1:{closed_port()}/v1")
    with pytest.raises(ConfigError) as e:
        p.check_credentials()
    assert str(e.value) == (f"model.model_id=openai-api/fake/{MODEL_ID}: Unable to initialise fake client: "
                            "No FAKE_API_KEY defined in the environment.")
    monkeypatch.setenv("FAKE_API_KEY", "k")
    p.check_credentials()
    assert p.key_envs == ("FAKE_API_KEY",)  # what Inspect's provider declares (check_model reports it)
    p.close()
    with pytest.raises(ConfigError, match="needs an Inspect model string <provider>/<model>"):
        InspectProvider({"model_id": "gpt-4o"})
    monkeypatch.delenv("MY_KEY", raising=False)
    with pytest.raises(ConfigError, match="^MY_KEY is not set"):
        InspectProvider({"model_id": "openai-api/fake/m", "api_key_env": "MY_KEY"}).check_credentials()


def test_the_configuration_is_checked_before_any_attempt():
    from cab_harness_reference.loop import ReferenceHarness

    cfg = {"name": "x", "harness": "reference", "provider": "inspect", "model_id": "openai-api/fake/m",
           "base_url": f"http://127.0.0.1:{closed_port()}/v1"}
    check = ReferenceHarness().check_model(cfg, network=False)
    assert (check.provider, check.key_env, check.key_present, check.problems) == ("inspect", "FAKE_API_KEY", True, [])


def test_each_thread_has_one_event_loop_reused_across_turns_and_closed_with_the_provider():
    from inspect_ai.model import ModelOutput, ModelUsage

    def outputs(*_):
        o = ModelOutput.for_tool_call("mockllm/model", "done", {"report": "r"})
        o.usage = ModelUsage(input_tokens=3, output_tokens=1, total_tokens=4)
        return o

    p = InspectProvider({"model_id": "mockllm/model", "model_args": {"custom_outputs": outputs}})
    for _ in range(2):
        assert p.complete("s", USER, TOOLS).stop_reason == "tool_calls"
    t = threading.Thread(target=lambda: p.complete("s", USER, TOOLS))
    t.start()
    t.join()
    loops = [s.runner.get_loop() for s in p._slots]
    assert len(loops) == 2 and loops[0] is not loops[1]  # the main thread's, reused for both turns; the thread's
    p.close()
    assert p._slots == [] and all(loop.is_closed() for loop in loops)
    assert p.complete("s", USER, TOOLS).stop_reason == "tool_calls"  # used again: a new loop
    p.close()


def test_the_configuration_is_named_by_the_inspect_model_string():
    from cab_core.analysis.configurations import configuration_labels

    cfg = {"name": "openai_gpt-4o", "label": "openai/gpt-4o", "model_id": "openai/gpt-4o", "provider": "inspect"}
    assert configuration_labels([{"model": "openai_gpt-4o", "harness": "reference", "sim": "mujoco",
                                  "model_cfg": cfg}]) == ["openai/gpt-4o (reference, mujoco)"]


# -- Inspect's OpenAI-compatible provider on a scripted server -----------------------------------------

def test_a_rate_limit_with_retry_after_and_a_server_error_recover():
    rate = (429, _error("Rate limit reached for requests", "requests", "rate_limit_exceeded"), {"retry-after": "1"})
    server = (500, _error("The server had an error"), {})
    with Scripted([rate, server, (200, _completion(), {})]) as s:
        p = provider(s.url)
        r = p.complete("sys", USER, TOOLS)
        p.close()
    assert [path for _, path, _ in s.requests] == ["/v1/chat/completions"] * 3
    assert s.requests[1][0] - s.requests[0][0] >= 1.0  # the server's Retry-After, not the 0.05 s backoff
    assert r.waited_s == pytest.approx(1.0 + 0.1)  # Retry-After, then the server backoff's second step (top of range)
    assert r.stop_reason == "tool_calls" and [(c.name, c.arguments) for c in r.message.parts] == [("done", {"report": "r"})]
    assert (r.usage.input_tokens, r.usage.output_tokens) == (10, 5)


def test_shared_limits_take_the_real_usage_and_a_retry_after_pauses_the_credential(tmp_path):
    from cab_core.kits.harness.limits import Limiter, LimitSettings
    from cab_harness_reference.loop import limited_complete

    t = [1000.0]
    lim = Limiter("k", LimitSettings(tokens_per_minute=20, window_s=10, margin_s=0), tmp_path,
                  clock=lambda: t[0], sleep=lambda s: t.__setitem__(0, t[0] + s))
    rate = (429, _error("Rate limit reached", "requests", "rate_limit_exceeded"), {"retry-after": "1"})
    with Scripted([rate, (200, _completion(), {})]) as s:
        p = provider(s.url)
        p.retry.limiter = lim  # as the loop's limiter_for sets it
        resp, _ = limited_complete(p, lim, "sys", USER, TOOLS, estimated_tokens=1)
        p.close()
    assert resp.stop_reason == "tool_calls" and len(s.requests) == 2
    assert json.loads(next(tmp_path.rglob("*.json")).read_text())["paused_until"] == 1001.0  # every worker waits
    with lim.request(10):  # the answer's 15 tokens (not the estimate of 1) and 10 more exceed 20 a minute
        pass
    assert t[0] == pytest.approx(1010.0)


@pytest.mark.parametrize("reply,kind,requests", [
    ((500, _error("The server had an error"), {}), "server", 3),
    ((529, _error("Overloaded", "overloaded_error"), {}), "overloaded", 3),
    ((401, _error("Incorrect API key provided", "invalid_request_error", "invalid_api_key"), {}), "auth", 1),
    ((429, _error("You exceeded your current quota", "insufficient_quota", "insufficient_quota"), {}), "quota", 1),
    ((400, _error("Invalid value for 'tools'", "invalid_request_error"), {}), "bad_request", 1),
])
def test_a_failure_inspect_gives_up_on_is_one_of_cabs_kinds(reply, kind, requests):
    with Scripted([reply]) as s:
        p = provider(s.url)
        with pytest.raises(ProviderError) as e:
            p.complete("sys", USER, TOOLS)
        p.close()
    assert e.value.kind == kind and e.value.status == reply[0]
    assert len(s.requests) == requests and e.value.attempts == requests
    assert e.value.infrastructure is (kind != "bad_request")
    assert e.value.url == s.url


def test_a_request_over_the_context_window_is_the_models_context_length():
    too_long = (400, _error("This model's maximum context length is 8192 tokens", "invalid_request_error",
                            "context_length_exceeded"), {})
    with Scripted([too_long]) as s:
        p = provider(s.url)
        with pytest.raises(ProviderError) as e:
            p.complete("sys", USER, TOOLS)
        p.close()
    assert e.value.kind == "context_length" and not e.value.infrastructure and len(s.requests) == 1


def test_connection_refused_is_unreachable_after_inspects_retries():
    url = f"http://127.0.0.1:{closed_port()}/v1"
    p = provider(url, retry={"max_attempts": 2, "base_delay_s": {"unreachable": 0.05}})
    with pytest.raises(ProviderError) as e:
        p.complete("sys", USER, TOOLS)
    p.close()
    assert e.value.kind == "unreachable" and e.value.infrastructure and e.value.attempts == 2
    assert e.value.waited_s == pytest.approx(0.05)
    assert e.value.summary() == (f"provider unreachable at {url} (connection refused): is the server running, "
                                 "and is model.base_url right?")


def test_an_exception_inspect_raises_is_classified_through_its_cause():
    from inspect_ai.model._model import ModelGenerateError

    class Status(Exception):
        status_code = 503

    wrapped = ModelGenerateError("failed", status_code=503)
    wrapped.__cause__ = Status("unavailable")
    assert classify_error(wrapped).kind == "server"
    assert classify_error(ConnectionRefusedError(111, "Connection refused")).reason == "connection refused"
    assert classify_error(RuntimeError("custom_outputs ran out of values")).kind == "other"


# -- whole attempts ------------------------------------------------------------------------------------

def _cab(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*CAB, *args, "task=click_bell", "sim=mujoco", "record.video=false",
                           "sweep.preflight_network=false"], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, **(env or {})))


def _events(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def oracle_calls(tmp_path_factory) -> list[tuple[str, dict]]:
    """The calls click_bell's oracle makes on MuJoCo (seed 0), in order, ``done`` last."""
    pytest.importorskip("mujoco")
    out = tmp_path_factory.mktemp("oracle") / "attempt"
    r = _cab("model=oracle", f"hydra.run.dir={out}")
    assert r.returncode == 0, r.stderr[-2000:]
    calls = [(e["tool"], e.get("arguments") or {}) for e in _events(out) if e["kind"] == "call"]
    assert calls[-1][0] == "done" and any(name == "capture_head" for name, _ in calls)
    return calls


@pytest.mark.sim
def test_mockllm_making_the_oracles_calls_succeeds_on_mujoco(oracle_calls, tmp_path):
    from inspect_ai.model import ModelOutput, ModelUsage

    from cab_core.analysis.attempts import scan

    outputs = []
    for i, (name, args) in enumerate(oracle_calls):
        o = ModelOutput.for_tool_call("mockllm/model", name, args, tool_call_id=f"call_{i}")
        o.usage = ModelUsage(input_tokens=1000 + i, output_tokens=20, total_tokens=1020 + i)
        outputs.append(o.model_dump(mode="json"))
    script = tmp_path / "outputs.json"
    script.write_text(json.dumps(outputs))
    out = tmp_path / "run" / "attempt"
    r = _cab("model=inspect", "model.model_id=mockllm/model", f"+model.model_args.custom_outputs={script}",
             "model.pricing={input_per_mtok: 1.0, output_per_mtok: 10.0}", f"hydra.run.dir={out}")
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads((out / "result.json").read_text())
    assert res["verdict"]["success"] is True and res["termination"]["reason"] == "done"
    assert res["model"] == "mockllm_model"
    events = _events(out)
    assert [(e["tool"], e.get("arguments") or {}) for e in events if e["kind"] == "call"] == oracle_calls
    turns = [e for e in events if e["kind"] == "model_turn"]
    assert [t["model"] for t in turns] == ["mockllm/model"] * len(oracle_calls)
    assert [t["tool_calls"][0]["call_id"] for t in turns] == [f"call_{i}" for i in range(len(oracle_calls))]
    n = len(oracle_calls)
    inputs = sum(1000 + i for i in range(n))
    usage = res["agent"]["usage"]
    assert (usage["input_tokens"], usage["output_tokens"]) == (inputs, 20 * n)
    assert usage["usd"] == pytest.approx(inputs * 1.0 / 1e6 + 20 * n * 10.0 / 1e6)
    (attempt,) = scan(tmp_path / "run").attempts
    assert attempt.config == "mockllm/model (reference, mujoco)"  # named by the Inspect model string


@pytest.mark.sim
def test_an_outage_ends_the_attempt_unscored(tmp_path):
    pytest.importorskip("mujoco")
    url = f"http://127.0.0.1:{closed_port()}/v1"
    out = tmp_path / "attempt"
    r = _cab("model=inspect", "model.model_id=openai-api/fake/m", "model.retry.max_attempts=2",
             "+model.retry.base_delay_s.unreachable=0.05", "+model.model_args.max_retries=0", f"hydra.run.dir={out}",
             env={"FAKE_BASE_URL": url})
    assert r.returncode == 4, r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1] == (
        f"cab: provider unreachable at {url} (connection refused): is the server running, and is model.base_url "
        "right? The attempt is recorded as an infrastructure failure, not scored.")
    res = json.loads((out / "result.json").read_text())
    assert res["termination"]["reason"] == "provider_failure"
    assert res["verdict"]["success"] is None and res["verdict"]["excluded"] == "provider_failure"
    (failure,) = [e for e in _events(out) if e["kind"] == "provider_failure"]
    assert (failure["error_kind"], failure["attempts"], failure["infrastructure"]) == ("unreachable", 2, True)


# -- the same requests as cab's own provider --------------------------------------------------------

class Recording(FakeOpenAIServer):
    """cab's fake OpenAI-compatible server, keeping each request's JSON body."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.bodies: list[dict] = []

    def answer(self, body: dict) -> dict:
        self.bodies.append(body)
        return super().answer(body)


#: keywords of cab's tool schemas that Inspect's schema model (``JSONSchema``) does not hold
NOT_IN_INSPECTS_SCHEMA = {"title", "minItems", "maxItems", "exclusiveMinimum"}
#: keywords Inspect's OpenAI-compatible provider leaves out of tool schemas (its ``schema_exclude_fields``)
EXCLUDED_BY_OPENAI_API = {"pattern", "minLength", "maxLength", "minimum", "maximum", "examples"}


def _without(schema, keys: set[str]):
    """``schema`` without the keywords ``keys`` at any depth (property names are not keywords), and
    without ``default: null`` (Inspect's schema model leaves out every null)."""
    if isinstance(schema, list):
        return [_without(s, keys) for s in schema]
    if not isinstance(schema, dict):
        return schema
    return {k: ({p: _without(s, keys) for p, s in v.items()} if k == "properties" else _without(v, keys))
            for k, v in schema.items() if k not in keys and not (k == "default" and v is None)}


def _inspect_shape(body: dict) -> dict:
    """What Inspect's OpenAI-compatible provider sends differently, made as cab's provider sends it:
    ``tool_choice: auto`` (the API's default when tools are given) left out; an assistant message
    without text has content ``""`` where cab sends null; an image part carries ``detail: auto`` (the
    API's default); a tool carries ``strict: true`` (Inspect's ``strict_tools``). Tool schemas are
    compared apart (:func:`_schemas`)."""
    body = json.loads(json.dumps(body))
    assert body.pop("tool_choice") == "auto"
    for m in body["messages"]:
        if m["role"] == "assistant" and m.get("content") == "":
            m["content"] = None
        for part in m["content"] if isinstance(m.get("content"), list) else []:
            if part["type"] == "image_url":
                assert part["image_url"].pop("detail") == "auto"
    for t in body["tools"]:
        assert t["function"].pop("strict") is True
    return body


def _schemas(body: dict) -> list[dict]:
    return [t["function"].pop("parameters") for t in body["tools"]]


@pytest.mark.sim
def test_inspect_sends_the_requests_cabs_own_provider_sends(oracle_calls, tmp_path):
    """One scripted model (cab's fake server answering the oracle's calls turn by turn), behind cab's
    ``openai_compatible`` provider and behind Inspect's ``openai-api`` provider: the same system prompt,
    the same tools, the same context policy's messages, the same images (byte for byte), modulo the
    fields :func:`_inspect_shape` names; and each tool schema is cab's without the keywords Inspect's
    schema model does not hold (title, minItems, maxItems, exclusiveMinimum, the object's own
    description, ``default: null``), those its OpenAI-compatible provider leaves out (the bounds:
    pattern, min/maxLength, minimum/maximum; the tools' descriptions state them too), with ``$defs``
    inlined and ``required: []`` where cab's object has no ``required``."""
    from cab_core.tools import build_registry

    bodies = {}
    for which in ("cab", "inspect"):
        with Recording(script=tuple(oracle_calls)) as s:
            if which == "cab":
                r = _cab("model=openai_compatible", f"model.model_id={MODEL_ID}", f"model.base_url={s.base_url}",
                         "+model.probe=false", f"hydra.run.dir={tmp_path / which}")
            else:
                r = _cab("model=inspect", f"model.model_id=openai-api/fake/{MODEL_ID}", f"hydra.run.dir={tmp_path / which}",
                         env={"FAKE_BASE_URL": s.base_url})
            assert r.returncode == 0, r.stderr[-3000:]
            assert json.loads((tmp_path / which / "result.json").read_text())["verdict"]["success"] is True
            bodies[which] = s.bodies
    cab, inspect = bodies["cab"], [_inspect_shape(b) for b in bodies["inspect"]]
    assert len(cab) == len(inspect) == len(oracle_calls)
    images = [p for m in cab[-1]["messages"] if isinstance(m["content"], list) for p in m["content"]
              if p["type"] == "image_url"]
    assert images and all(re.match(r"data:image/png;base64,", p["image_url"]["url"]) for p in images)
    specs = {t["name"]: t["parameters"] for t in (d.spec() for d in build_registry().values())}
    for c, i in zip(cab, inspect):
        ci, ii = _schemas(c), _schemas(i)
        assert c == i  # model, max_tokens, messages (system prompt, context policy, images), tool names and descriptions
        assert ci == [specs[t["function"]["name"]] for t in c["tools"]]  # cab sends its schemas as they are
        from cab_harness_reference.google_provider import inline_schema

        expected = [dict({"required": []}, **_without(inline_schema(s), NOT_IN_INSPECTS_SCHEMA | EXCLUDED_BY_OPENAI_API))
                    for s in ci]
        for e in expected:
            e.pop("description", None)  # the arguments object's own description (Inspect's ToolParams has none)
        assert ii == expected
