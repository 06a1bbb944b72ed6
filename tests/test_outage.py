"""An outage is never scored; Ctrl-C is never scored (issue 28, "Deliver" 3).

Each provider's real SDK against a local HTTP server that speaks its wire format (Anthropic Messages,
OpenAI Responses, OpenAI-compatible Chat Completions, Gemini generateContent): a 429 with
``Retry-After`` (honoured), 500, 529 / overloaded, timeouts, slow answers within the timeout, 401,
quota exhausted and a refused connection, each classified by kind with the endpoint named and the
retries counted. Then the record: an attempt that ended on an infrastructure failure or was
interrupted is excluded (``verdict.excluded``) and listed with its reason; end to end, a single run
against a refused port exits 4 with one line naming the URL, and Ctrl-C of a single run exits 130
with one line, writes an ``interrupted`` record and leaves the folder reusable."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

try:
    import cab_harness_reference  # noqa: F401
except ImportError:  # the plugin is not installed in this environment: use the source tree
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plugins" / "harness_reference"))

from fake_json_api import JsonServer, TopOfRange  # noqa: E402

from cab_core.attempt.records.result_format import RECORD_VERSION, AttemptRecord, parse_record  # noqa: E402
from cab_harness_reference.types import Message, ProviderError, Text, ToolSpec  # noqa: E402

TOOLS = [ToolSpec("done", "Finish", {"type": "object", "properties": {"report": {"type": "string"}},
                                     "required": ["report"]})]
RETRY = {"max_attempts": 3, "base_delay_s": {"rate_limit": 5.0, "server": 2.0, "overloaded": 3.0,
                                             "timeout": 1.0, "unreachable": 1.0}}


@dataclass
class Reply:
    status: int
    body: dict
    headers: dict = field(default_factory=dict)
    delay_s: float = 0.0  # the answer comes this late (a slow server, or one past the client's timeout)


class Scripted(JsonServer):
    """Pops the next :class:`Reply` per POST (the last one answers every request after it)."""

    def __init__(self, replies: list[Reply], base_path: str = ""):
        self.base_path = base_path
        super().__init__()
        self.replies = list(replies)
        self.paths: list[str] = []

    def answer(self, path, body, headers):
        self.paths.append(path)
        r = self.replies.pop(0) if len(self.replies) > 1 else self.replies[0]
        if r.delay_s:
            time.sleep(r.delay_s)
        return r.status, r.body, r.headers


def closed_port() -> int:
    """A port on 127.0.0.1 that nothing listens on (bound, then released)."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# -- the four wire formats ------------------------------------------------------------------------
def _anthropic_err(etype, msg):
    return {"type": "error", "error": {"type": etype, "message": msg}}


def _openai_err(msg, etype, code=None):
    return {"error": {"message": msg, "type": etype, "code": code, "param": None}}


def _google_err(code, status, msg):
    return {"error": {"code": code, "status": status, "message": msg}}


OPENAI_RATE = _openai_err("Rate limit reached for requests per min (RPM): Limit 500", "requests", "rate_limit_exceeded")
OPENAI_QUOTA = _openai_err("You exceeded your current quota, please check your plan and billing details.",
                           "insufficient_quota", "insufficient_quota")
OPENAI_AUTH = _openai_err("Incorrect API key provided: sk-test.", "invalid_request_error", "invalid_api_key")

WIRE = {
    "anthropic": {
        "path": "",
        "ok": {"id": "msg_1", "type": "message", "role": "assistant", "model": "claude-opus-5",
               "content": [{"type": "tool_use", "id": "toolu_1", "name": "done", "input": {"report": "r"}}],
               "stop_reason": "tool_use", "stop_sequence": None, "usage": {"input_tokens": 10, "output_tokens": 5}},
        "rate_limit": (429, _anthropic_err("rate_limit_error", "Number of requests has exceeded your rate limit")),
        "server": (500, _anthropic_err("api_error", "Internal server error")),
        "overloaded": (529, _anthropic_err("overloaded_error", "Overloaded")),
        "auth": (401, _anthropic_err("authentication_error", "invalid x-api-key")),
        "quota": (400, _anthropic_err("invalid_request_error", "Your credit balance is too low to access the "
                                      "Anthropic API. Please go to Plans & Billing to upgrade or purchase credits.")),
        "retry_after": True,
    },
    "openai": {
        "path": "/v1",
        "ok": {"id": "resp_1", "object": "response", "created_at": 0, "model": "gpt-5.6", "status": "completed",
               "incomplete_details": None,
               "output": [{"type": "function_call", "id": "fc_1", "call_id": "c1", "name": "done",
                           "arguments": json.dumps({"report": "r"}), "status": "completed"}],
               "usage": {"input_tokens": 10, "output_tokens": 5, "total_tokens": 15,
                         "input_tokens_details": {"cached_tokens": 0}, "output_tokens_details": {"reasoning_tokens": 0}}},
        "rate_limit": (429, OPENAI_RATE),
        "server": (500, _openai_err("The server had an error while processing your request.", "server_error")),
        "overloaded": (529, _openai_err("Overloaded", "overloaded_error")),
        "auth": (401, OPENAI_AUTH),
        "quota": (429, OPENAI_QUOTA),
        "retry_after": True,
    },
    "openai_compatible": {
        "path": "/v1",
        "ok": {"id": "chatcmpl-1", "object": "chat.completion", "created": 0, "model": "qwen",
               "choices": [{"index": 0, "finish_reason": "tool_calls", "message": {
                   "role": "assistant", "content": None, "tool_calls": [{"id": "c1", "type": "function", "function": {
                       "name": "done", "arguments": json.dumps({"report": "r"})}}]}}],
               "usage": {"prompt_tokens": 10, "completion_tokens": 5, "total_tokens": 15}},
        "rate_limit": (429, OPENAI_RATE),
        "server": (500, _openai_err("Internal Server Error", "server_error")),
        "overloaded": (529, _openai_err("Overloaded", "overloaded_error")),
        "auth": (401, OPENAI_AUTH),
        "quota": (429, OPENAI_QUOTA),
        "retry_after": True,
    },
    "google": {
        "path": "",
        "ok": {"candidates": [{"content": {"role": "model", "parts": [
            {"functionCall": {"name": "done", "args": {"report": "r"}}}]}, "finishReason": "STOP", "index": 0}],
               "usageMetadata": {"promptTokenCount": 10, "candidatesTokenCount": 5, "totalTokenCount": 15},
               "modelVersion": "gemini-3.6-flash", "responseId": "resp-1"},
        "rate_limit": (429, _google_err(429, "RESOURCE_EXHAUSTED", "Resource has been exhausted (e.g. check quota).")),
        "server": (500, _google_err(500, "INTERNAL", "An internal error has occurred.")),
        "overloaded": (503, _google_err(503, "UNAVAILABLE", "The model is overloaded. Please try again later.")),
        "auth": (400, _google_err(400, "INVALID_ARGUMENT", "API key not valid. Please pass a valid API key.")),
        "quota": (429, _google_err(429, "RESOURCE_EXHAUSTED", "You exceeded your current quota, please check your "
                                   "plan and billing details.")),
        "retry_after": False,  # Gemini says when to retry in the body (RetryInfo), not in a header
    },
}
PROVIDERS = list(WIRE)


@pytest.fixture(autouse=True)
def _env(monkeypatch):
    for v in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy", "https_proxy", "all_proxy",
              "OPENAI_BASE_URL", "ANTHROPIC_BASE_URL"):
        monkeypatch.delenv(v, raising=False)
    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-ant-test")
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    monkeypatch.setenv("GEMINI_API_KEY", "g-test")


def make(provider: str, url: str, sleeps: list, timeout_s: float = 5.0):
    """The provider against ``url``: its waits appended to ``sleeps`` instead of slept, jitter at the top."""
    cfg = {"retry": RETRY, "timeout_s": timeout_s, "connect_timeout_s": timeout_s}
    if provider == "anthropic":
        from cab_harness_reference.anthropic_provider import AnthropicProvider

        p = AnthropicProvider({"name": "opus5", "model_id": "claude-opus-5", "base_url": url, **cfg})
        p.retry_policy.sleep, p.retry_policy.rng = sleeps.append, TopOfRange()
        return p
    if provider == "google":
        pytest.importorskip("google.genai")
        from cab_harness_reference.google_provider import GoogleProvider

        return GoogleProvider({"model_id": "gemini-3.6-flash", "base_url": url, **cfg}, sleep=sleeps.append,
                              rng=TopOfRange())
    pytest.importorskip("openai")
    if provider == "openai":
        from cab_harness_reference.openai_provider import OpenAIProvider as cls
    else:
        from cab_harness_reference.openai_compatible_provider import OpenAICompatibleProvider as cls
    return cls({"model": "m", "base_url": url, "api_key_env": None if provider == "openai_compatible" else "OPENAI_API_KEY",
                **cfg}, sleep=sleeps.append, rng=TopOfRange())


def ask(provider: str, replies: list[Reply], timeout_s: float = 5.0):
    """One request through the provider's retries; returns (response or ProviderError, sleeps, requests made, url)."""
    sleeps: list = []
    with Scripted(replies, WIRE[provider]["path"]) as srv:
        p = make(provider, srv.url, sleeps, timeout_s)
        try:
            out = p.complete("s", [Message("user", [Text("go")])], TOOLS)
        except ProviderError as e:
            out = e
        return out, sleeps, len(srv.paths), srv.url


def _failed(out, kind: str, url: str, attempts: int) -> ProviderError:
    assert isinstance(out, ProviderError), out
    assert out.kind == kind, (out.kind, str(out))
    assert out.attempts == attempts  # type: ignore[attr-defined]
    assert out.url == url.rstrip("/") and out.infrastructure
    assert f" at {out.url} (" in out.summary()
    return out


@pytest.mark.parametrize("provider", PROVIDERS)
def test_rate_limit_waits_its_retry_after_then_succeeds(provider):
    status, body = WIRE[provider]["rate_limit"]
    honoured = WIRE[provider]["retry_after"]
    out, sleeps, n, _ = ask(provider, [Reply(status, body, {"retry-after": "7"} if honoured else {}),
                                       Reply(200, WIRE[provider]["ok"])])
    assert not isinstance(out, ProviderError), out
    assert out.stop_reason == "tool_calls" and n == 2
    assert sleeps == ([7.0] if honoured else [5.0])  # the server's Retry-After, else the backoff's first step
    assert out.waited_s == pytest.approx(sleeps[0])


@pytest.mark.parametrize("provider", PROVIDERS)
@pytest.mark.parametrize("case,kind,delays", [("server", "server", [2.0, 4.0]),
                                               ("overloaded", "overloaded", [3.0, 6.0])])
def test_server_errors_are_retried_then_given_up_on_as_infrastructure(provider, case, kind, delays):
    status, body = WIRE[provider][case]
    out, sleeps, n, url = ask(provider, [Reply(status, body)])
    err = _failed(out, kind, url, 3)
    assert n == 3 and sleeps == delays and err.status == status


@pytest.mark.parametrize("provider", PROVIDERS)
@pytest.mark.parametrize("case", ["auth", "quota"])
def test_auth_and_quota_are_not_retried_but_are_infrastructure(provider, case):
    status, body = WIRE[provider][case]
    out, sleeps, n, url = ask(provider, [Reply(status, body)])
    _failed(out, case, url, 1)
    assert n == 1 and sleeps == []


@pytest.mark.parametrize("provider", PROVIDERS)
def test_a_server_slower_than_the_timeout_is_a_timeout_after_the_retries(provider):
    out, sleeps, n, url = ask(provider, [Reply(200, WIRE[provider]["ok"], delay_s=2.0)], timeout_s=0.5)
    _failed(out, "timeout", url, 3)
    assert n == 3 and sleeps == [1.0, 2.0]


@pytest.mark.parametrize("provider", PROVIDERS)
def test_a_slow_answer_within_the_timeout_succeeds_without_a_retry(provider):
    out, sleeps, n, _ = ask(provider, [Reply(200, WIRE[provider]["ok"], delay_s=0.6)], timeout_s=5.0)
    assert not isinstance(out, ProviderError), out
    assert out.stop_reason == "tool_calls" and n == 1 and sleeps == [] and out.latency_s >= 0.6


@pytest.mark.parametrize("provider", PROVIDERS)
def test_connection_refused_is_unreachable_naming_the_url(provider):
    url = f"http://127.0.0.1:{closed_port()}{WIRE[provider]['path']}"
    sleeps: list = []
    with pytest.raises(ProviderError) as ei:
        make(provider, url, sleeps).complete("s", [Message("user", [Text("go")])], TOOLS)
    err = _failed(ei.value, "unreachable", url, 3)
    assert sleeps == [1.0, 2.0] and err.reason == "connection refused"
    assert err.summary().startswith(f"provider unreachable at {url} (connection refused): is the server running")


# -- the record ------------------------------------------------------------------------------------
def _record(termination: dict, success=False) -> dict:
    return {"record_version": RECORD_VERSION, "task": "click_bell", "seed": 0, "attempt": 1, "sim": "mujoco",
            "model": "qwen_local", "harness": "reference", "verdict": {"success": success, "scoring": "latch"},
            "termination": termination, "claim": {}, "budget": {}, "timing": {}, "versions": {}}


@pytest.mark.parametrize("reason", ["provider_failure", "host_fault", "interrupted"])
def test_a_record_that_ends_on_an_unscored_termination_is_excluded(reason):
    rec = AttemptRecord.build(**_record({"reason": reason, "detail": "x"}, success=True))
    assert rec.excluded and rec.excluded_reason == reason
    assert rec.verdict.success is None and rec.verdict.excluded == reason
    old = parse_record(_record({"reason": reason, "detail": "x"}))  # written before the rule: scored then
    assert old.excluded and old.excluded_reason == reason and old.verdict.success is False


@pytest.mark.parametrize("reason", ["done", "no_done", "provider_rejected", "context_length_exceeded"])
def test_a_record_the_model_ended_is_scored(reason):
    rec = AttemptRecord.build(**_record({"reason": reason}))
    assert not rec.excluded and rec.excluded_reason is None and rec.verdict.success is False
    assert "excluded" not in rec.dump()["verdict"]


def test_the_loop_ends_on_an_infrastructure_kind_unscored_and_on_the_models_own_scored():
    from cab_harness_reference.loop import ReferenceHarness

    class Episode:
        def __init__(self):
            self.ended = None
            self.events: list = []
            self.ledger = self
            self.recorder = self

        def credit_wall(self, s):
            pass

        def event(self, kind, **kw):
            self.events.append((kind, kw))

        def end(self, reason, detail):
            self.ended = (reason, detail)

    url = "http://127.0.0.1:9/v1"
    for kind, reason in (("unreachable", "provider_failure"), ("quota", "provider_failure"),
                         ("auth", "provider_failure"), ("bad_request", "provider_rejected")):
        ep = Episode()
        e = ProviderError(kind, "x", 400 if kind == "bad_request" else None, url=url,
                          reason="connection refused" if kind == "unreachable" else None)
        assert ReferenceHarness._provider_failed(ep, e, 1, time.monotonic(), {"waited_s": 0.0}, None, [], 0,
                                                 None, None) is None
        assert ep.ended[0] == reason
        assert ep.events[-1][1]["url"] == url and ep.events[-1][1]["error_kind"] == kind
    assert ep.ended[1].startswith("bad_request (HTTP 400)")


# -- end to end: a single run ------------------------------------------------------------------------
def _cab(*args, **kw):
    return subprocess.run(["cab", *args], capture_output=True, text=True, timeout=300, **kw)


def _offline_overrides() -> list[str]:
    """Overrides that keep a single run from checking the endpoint before the attempt (the outage
    must happen during it): the pre-flight and the endpoint probe, where this cab has them."""
    from cab_core.conf import schema

    out = []
    sweep_fields = getattr(getattr(schema, "SweepSettings", None), "model_fields", None) or {}
    if "preflight_network" in sweep_fields or "preflight_network" in Path(schema.__file__).read_text():
        out.append("sweep.preflight_network=false")
    import cab_harness_reference

    yaml = Path(cab_harness_reference.__file__).parent / "conf" / "model" / "qwen_local.yaml"
    if yaml.is_file() and "\nprobe:" in yaml.read_text():
        out.append("model.probe=false")
    return out


@pytest.mark.sim
def test_a_single_run_against_a_refused_port_is_not_scored_and_exits_4(tmp_path):
    pytest.importorskip("mujoco")
    url = f"http://127.0.0.1:{closed_port()}/v1"
    out = tmp_path / "r"
    r = _cab("model=qwen_local", f"model.base_url={url}", "model.retry.max_attempts=2", "task=click_bell",
             "sim=mujoco", f"hydra.run.dir={out}", "record.video=false", *_offline_overrides())
    assert r.returncode == 4, r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1] == (
        f"cab: provider unreachable at {url} (connection refused): is the server running, and is model.base_url "
        "right? The attempt is recorded as an infrastructure failure, not scored.")
    res = json.loads((out / "result.json").read_text())
    assert res["termination"]["reason"] == "provider_failure"
    assert res["verdict"]["success"] is None and res["verdict"]["excluded"] == "provider_failure"
    rep = subprocess.run(["cab-report", str(tmp_path)], capture_output=True, text=True, timeout=300)
    md = (tmp_path / "report.md").read_text()
    assert rep.returncode == 1, rep.stderr[-2000:]  # nothing left to measure: the one attempt is excluded
    assert rep.stderr.strip().splitlines()[-1] == f"cab-report: no finished attempt to measure under {tmp_path}"
    assert "Excluded, not scored (infrastructure failures, interrupted attempts; not the model's): 1: r excluded " \
           f"(provider_failure): provider unreachable at {url} (connection refused)" in md


class _Hanging(JsonServer):
    """A Chat Completions server whose first answer never comes (the model is thinking) and which
    answers ``done`` afterwards; ``asked`` is set when the first request arrives."""

    base_path = "/v1"

    def __init__(self):
        super().__init__()
        self.asked = threading.Event()
        self.release = threading.Event()
        self.n = 0

    def answer(self, path, body, headers):
        self.n += 1
        if self.n == 1:
            self.asked.set()
            self.release.wait(60)
            return None
        return 200, WIRE["openai_compatible"]["ok"], {}


@pytest.mark.sim
@pytest.mark.parametrize("sig,how", [(signal.SIGINT, "SIGINT (Ctrl-C)"), (signal.SIGTERM, "SIGTERM")])
def test_an_interrupted_single_run_is_recorded_unscored_and_its_folder_runs_again(tmp_path, sig, how):
    pytest.importorskip("mujoco")
    pytest.importorskip("openai")
    out = tmp_path / "r"
    with _Hanging() as srv:
        args = ["cab", "model=qwen_local", f"model.base_url={srv.url}", "task=click_bell", "sim=mujoco",
                f"hydra.run.dir={out}", "record.video=false", *_offline_overrides()]
        p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.default_int_handler))
        try:
            assert srv.asked.wait(240), "the attempt never asked the model"
            os.killpg(p.pid, sig)  # as Ctrl-C does: the whole process group
            _, err = p.communicate(timeout=120)
        finally:
            srv.release.set()
            if p.poll() is None:
                p.kill()
        assert p.returncode == 130, err[-3000:]
        assert err.strip().splitlines() == ["cab: interrupted; run the same command to run it again"]
        res = json.loads((out / "result.json").read_text())
        assert res["termination"] == {"reason": "interrupted", "detail": f"stopped by {how} while the agent "
                                      "played; not scored"}
        assert res["verdict"]["success"] is None and res["verdict"]["excluded"] == "interrupted"

        again = _cab(*args[1:])  # the same command, the same folder: the interrupted records are set aside
    assert again.returncode == 0, again.stderr[-3000:]
    assert "termination=done" in again.stdout
    assert json.loads((out / "result.json").read_text())["termination"]["reason"] == "done"
    aside = out / "set_aside" / "01-interrupted"
    assert json.loads((aside / "result.json").read_text())["termination"]["reason"] == "interrupted"
    assert (aside / "events.jsonl").is_file()


# -- a sweep's end ---------------------------------------------------------------------------------
@pytest.mark.parametrize("given_up", [True, False])
def test_a_sweep_that_ends_with_attempts_given_up_on_exits_4_with_the_resume_command(tmp_path, monkeypatch, capsys,
                                                                                    given_up):
    from omegaconf import OmegaConf

    from cab_core.apps import cli

    sweep = tmp_path / "sw"
    (sweep / "a").mkdir(parents=True)
    (sweep / "sweep.json").write_text(json.dumps({"n_jobs": 1}))
    rec = _record({"reason": "done"}, success=True)
    if given_up:
        rec = {**rec, "verdict": {"success": None, "excluded": "infrastructure_failure"},
               "termination": {"reason": "infrastructure_failure", "detail": "2 tries failed"},
               "infrastructure": {"failed": True, "failures": []}}
    (sweep / "a" / "result.json").write_text(json.dumps(rec))
    monkeypatch.setattr(cli, "_TYPED", ["-m", "model=qwen_local,opus5", "task=click_bell", f"hydra.sweep.dir={sweep}"])
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(sweep)}}})
    if not given_up:
        cli.SweepManifestCallback().on_multirun_end(config)
        assert capsys.readouterr().err == f"cab sweep: 1/1 attempts complete; {sweep}\n"
        return
    with pytest.raises(SystemExit) as ei:
        cli.SweepManifestCallback().on_multirun_end(config)
    assert ei.value.code == 4
    assert capsys.readouterr().err == (
        f"cab sweep: 0/1 attempts complete, 1 given up on for infrastructure failures (not scored), 0 missing; "
        f"{sweep}; run the same command to resume: cab -m model=qwen_local,opus5 task=click_bell "
        f"hydra.sweep.dir={sweep}\n")


# -- where an unscored record is listed ------------------------------------------------------------
def test_the_studio_and_the_export_list_an_unscored_record_with_its_reason(tmp_path):
    from cab_core.apps.export import _left_out
    from cab_core.apps.studio.tree import attempt_state

    d = tmp_path / "r"
    d.mkdir()
    detail = "provider unreachable at http://127.0.0.1:9/v1 (connection refused): is the server running?"
    (d / "result.json").write_text(json.dumps(AttemptRecord.build(**_record(
        {"reason": "provider_failure", "detail": detail})).dump()))
    a = attempt_state(d, "r", time.time())
    assert (a.state, a.success, a.why) == ("infra", None, f"provider_failure: {detail}")
    assert _left_out({"in_flight": [], "problems": [], "excluded": [("r", f"excluded (provider_failure): {detail}")]}) \
        == f"; left out: 1 not scored (r: excluded (provider_failure): {detail})"


def test_ctrl_c_of_a_sweep_is_one_line_with_the_resume_command(monkeypatch, capsys):
    from cab_core.apps import cli

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_hydra_entry", interrupted)
    monkeypatch.setattr(cli, "_SWEEP_DIR", "/sweeps/a")
    monkeypatch.setattr(cli, "_TYPED", ["-m", "model=qwen_local", "attempt=1,2", "hydra.sweep.dir=/sweeps/a"])
    with pytest.raises(SystemExit) as ei:
        cli._sweep_entry()
    assert ei.value.code == 130
    assert capsys.readouterr().err == (
        "cab: sweep /sweeps/a interrupted; finished attempts are kept, those in flight are not scored: run the same "
        "command to resume: cab -m model=qwen_local attempt=1,2 hydra.sweep.dir=/sweeps/a\n")
