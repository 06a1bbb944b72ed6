"""Limits shared by every worker of a sweep (cab_core.kits.harness.limits, the reference harness's
use of them) and the spend caps per attempt (``budget.cost_usd``) and per sweep
(``sweep.max_cost_usd``). The workers are separate processes talking to one fake
OpenAI-compatible server through the real ``openai`` SDK; the per-minute window is scaled down
(``limits.window_s``) so that a test takes seconds."""
from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("openai")

from fake_json_api import JsonServer  # noqa: E402

from cab_core.attempt.budget import BudgetLedger  # noqa: E402
from cab_core.errors import ConfigError  # noqa: E402
from cab_core.kits.harness.limits import Limiter, LimitSettings, credential_key  # noqa: E402
from cab_harness_reference.loop import ReferenceHarness  # noqa: E402
from cab_harness_reference.types import Capabilities, Message, Provider, Response, ToolCall, Usage  # noqa: E402

CAB = shutil.which("cab") or str(Path(sys.executable).with_name("cab"))


class LimitedChat(JsonServer):
    """``POST /v1/chat/completions`` as an OpenAI-compatible server with a rate limit of ``rpm``
    requests per ``window_s`` (a request over it gets 429 with ``Retry-After``), answering each
    request after ``delay_s``; it records each request's arrival time and the most requests it had
    in flight at once. ``first_429_after_s``: the first request is refused with that Retry-After."""

    base_path = "/v1"

    def __init__(self, rpm: int | None = None, window_s: float = 60.0, delay_s: float = 0.0,
                 first_429_after_s: float | None = None, usage: tuple[int, int] = (100, 10), done_call: bool = False):
        super().__init__()
        self.rpm, self.window_s, self.delay_s = rpm, window_s, delay_s
        self.first_429 = first_429_after_s
        self.usage, self.done_call = usage, done_call
        self.arrivals: list[float] = []  # accepted requests
        self.refused: list[float] = []  # answered 429
        self.in_flight = self.max_in_flight = 0
        self.lock = threading.Lock()
        self.refused_once = threading.Event()

    def answer(self, path, body, headers):
        now = time.time()
        with self.lock:
            if self.first_429 is not None and not self.refused:
                self.refused.append(now)
                self.refused_once.set()
                return 429, {"error": {"message": "Rate limit reached", "type": "requests", "code": "rate_limit_exceeded"}}, \
                    {"retry-after": str(self.first_429)}
            recent = [t for t in self.arrivals if t > now - self.window_s]
            if self.rpm is not None and len(recent) >= self.rpm:
                self.refused.append(now)
                return 429, {"error": {"message": "Rate limit reached", "type": "requests",
                                       "code": "rate_limit_exceeded"}}, {"retry-after": "1"}
            self.arrivals.append(now)
            self.in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self.in_flight)
        try:
            time.sleep(self.delay_s)
        finally:
            with self.lock:
                self.in_flight -= 1
        n = len(self.arrivals)
        message = {"role": "assistant", "content": "ok"}
        finish = "stop"
        if self.done_call:
            message = {"role": "assistant", "content": None, "tool_calls": [{
                "id": f"call_{n}", "type": "function",
                "function": {"name": "done", "arguments": json.dumps({"report": "gave up", "success_claim": False})}}]}
            finish = "tool_calls"
        return 200, {"id": f"chatcmpl-{n}", "object": "chat.completion", "created": int(now),
                     "model": body.get("model", "m"),
                     "choices": [{"index": 0, "message": message, "finish_reason": finish}],
                     "usage": {"prompt_tokens": self.usage[0], "completion_tokens": self.usage[1],
                               "total_tokens": sum(self.usage)}}, {}


# A worker: one request to an unlimited server first (the SDK's first request in a process does
# its one-time set-up before it sends, up to a second on a loaded machine, which the limiter's
# margin_s covers in a real minute but not in this test's scaled-down window), then n requests
# under the limits.
WORKER = """
import json, sys
from cab_harness_reference.loop import create_provider, limited_complete, limiter_for
from cab_harness_reference.types import Message, Text
cfg, n, warm = json.loads(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
create_provider(dict(cfg, base_url=warm, limits={})).complete("system", [Message("user", [Text("warm")])], [])
provider = create_provider(cfg)
limiter = limiter_for(cfg, provider)
if len(sys.argv) > 4:  # wait for the test's word
    print("ready", flush=True)
    sys.stdin.readline()
for i in range(n):
    limited_complete(provider, limiter, "system", [Message("user", [Text(f"request {i}")])], [], 50)
print(json.dumps({"waited_on_limits_s": limiter.waited_s}))
"""


def model_cfg(url: str, **limits) -> dict:
    return {"name": "fake", "provider": "openai_compatible", "model_id": "fake-model", "base_url": url,
            "api_key_env": "FAKE_LIMITS_KEY", "timeout_s": 30, "limits": limits,
            "retry": {"max_attempts": 4, "base_delay_s": {"rate_limit": 5, "timeout": 1, "server": 1}}}


@pytest.fixture(scope="module")
def warm_server():
    with LimitedChat() as server:
        yield server


def start_workers(cfg: dict, n: int, each: int, limits_dir: Path, warm: LimitedChat,
                  wait: bool = False) -> list[subprocess.Popen]:
    """``n`` worker processes making ``each`` requests; with ``wait``, each prints ``ready`` when set
    up and starts when a line is written to its stdin."""
    env = dict(os.environ, CAB_LIMITS_DIR=str(limits_dir), FAKE_LIMITS_KEY="sk-test-limits")
    return [subprocess.Popen([sys.executable, "-c", WORKER, json.dumps(cfg), str(each), warm.url,
                              *(["wait"] if wait else [])], env=env, stdin=subprocess.PIPE if wait else None,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(n)]


def finish(procs: list[subprocess.Popen]) -> list[dict]:
    out = []
    for p in procs:
        stdout, stderr = p.communicate(timeout=120)
        assert p.returncode == 0, stderr[-2000:]
        out.append(json.loads(stdout.strip().splitlines()[-1]))
    return out


def most_in_any_window(times: list[float], window: float) -> int:
    times = sorted(times)
    return max((sum(1 for u in times[i:] if u < t + window) for i, t in enumerate(times)), default=0)


# -- the acceptance test: 4 workers never exceed R requests in any window ----------------------

def test_four_worker_processes_never_exceed_the_requests_per_window(tmp_path, warm_server):
    r, window = 5, 2.0
    with LimitedChat(rpm=r, window_s=window) as server:
        cfg = model_cfg(server.url, requests_per_minute=r, window_s=window, margin_s=0.25)
        results = finish(go(start_workers(cfg, 4, 5, tmp_path / "limits", warm_server, wait=True)))
    assert len(server.arrivals) == 20 and server.refused == []  # the server never had to refuse one
    assert most_in_any_window(server.arrivals, window) <= r
    assert max(server.arrivals) - min(server.arrivals) >= 3 * window  # 20 requests at 5 a window
    assert sum(x["waited_on_limits_s"] for x in results) > 3 * window  # the waiting was measured


def test_retry_after_from_one_worker_pauses_every_worker_of_the_credential(tmp_path, warm_server):
    pause = 3.0
    with LimitedChat(first_429_after_s=pause) as server:
        cfg = model_cfg(server.url, requests_per_minute=1000)
        second = start_workers(cfg, 1, 1, tmp_path / "limits", warm_server, wait=True)
        assert second[0].stdout.readline().strip() == "ready"
        first = start_workers(cfg, 1, 1, tmp_path / "limits", warm_server)
        assert server.refused_once.wait(60)
        second[0].stdin.write("go\n")  # after the first worker's 429, before its pause ends
        second[0].stdin.flush()
        results = finish(first + second)
    (refused_at,) = server.refused
    assert len(server.arrivals) == 2
    assert min(server.arrivals) >= refused_at + pause - 0.05  # neither worker sent before the pause ended
    assert results[1]["waited_on_limits_s"] > 1.0  # the second waited on the pause it never got itself


def go(workers: list[subprocess.Popen]) -> list[subprocess.Popen]:
    """Start workers made with ``wait`` together, once every one of them is set up."""
    for w in workers:
        assert w.stdout.readline().strip() == "ready"
    for w in workers:
        w.stdin.write("go\n")
        w.stdin.flush()
    return workers


def test_requests_in_flight_are_capped_per_provider_endpoint(tmp_path, warm_server):
    with LimitedChat(delay_s=0.4) as server:
        results = finish(go(start_workers(model_cfg(server.url, max_concurrent=2), 4, 3, tmp_path / "limits",
                                          warm_server, wait=True)))
    assert len(server.arrivals) == 12
    assert server.max_in_flight == 2
    assert sum(x["waited_on_limits_s"] for x in results) > 0.4


def test_tokens_per_minute_hold_back_the_request_that_would_exceed_them(tmp_path):
    t = [1000.0]
    lim = Limiter("k", LimitSettings(tokens_per_minute=100, window_s=10, margin_s=0), tmp_path,
                  clock=lambda: t[0], sleep=lambda s: t.__setitem__(0, t[0] + s))
    with lim.request(60) as g:
        g.settle(70)  # the real usage replaces the estimate
    with lim.request(30) as g:  # 70 + 30 fit in the window
        g.settle(30)
    assert t[0] == 1000.0 and lim.waited_s == 0
    with lim.request(10):  # 110 would not: it waits until the first has left the window
        pass
    assert t[0] == pytest.approx(1010.0) and lim.waited_s == pytest.approx(10.0)


def test_waiting_on_a_limit_sleeps_instead_of_burning_the_cpu(tmp_path):
    lim = Limiter("k", LimitSettings(requests_per_minute=1, window_s=2.0, margin_s=0.0, max_concurrent=1), tmp_path)
    with lim.request():
        pass
    cpu0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    with lim.request():  # the window's one request is spent: ~2 s asleep
        pass
    cpu1 = resource.getrusage(resource.RUSAGE_SELF)
    assert time.monotonic() - t0 >= 1.9
    assert (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime) < 0.2

    other = Limiter("k", LimitSettings(max_concurrent=1), tmp_path)
    held = threading.Event()

    def hold():
        with other.request():
            held.set()
            time.sleep(2.0)

    holder = threading.Thread(target=hold)
    holder.start()
    held.wait(10)
    cpu0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    with lim.request():  # blocks in flock until the holder's slot is free
        pass
    cpu1 = resource.getrusage(resource.RUSAGE_SELF)
    holder.join()
    assert time.monotonic() - t0 >= 1.5
    assert (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime) < 0.2


def test_the_state_is_keyed_by_a_hash_of_the_credential_never_the_key(tmp_path):
    a = credential_key("openai", "https://api.example/v1", "sk-secret-1")
    assert a == credential_key("openai", "https://api.example/v1", "sk-secret-1")
    assert a != credential_key("openai", "https://api.example/v1", "sk-secret-2")
    assert a != credential_key("openai", "https://other.example/v1", "sk-secret-1")
    lim = Limiter(a, LimitSettings(requests_per_minute=3), tmp_path)
    lim.pause(0.0)
    with lim.request(5):
        pass
    assert all("sk-secret" not in p.name and "sk-secret" not in p.read_text()
               for p in tmp_path.rglob("*") if p.is_file())


@pytest.mark.parametrize("limits, message", [
    ({"requests_per_minute": 0}, "model.limits.requests_per_minute=0: must be a positive integer or null"),
    ({"tokens_per_minute": 1.5}, "model.limits.tokens_per_minute=1.5: must be a positive integer or null"),
    ({"max_concurent": 2}, "model.limits: unknown key 'max_concurent'"),
])
def test_bad_limits_are_one_typed_line(limits, message):
    with pytest.raises(ConfigError) as e:
        LimitSettings.from_cfg(limits)
    assert str(e.value).startswith(message)


# -- the spend cap of one attempt ---------------------------------------------------------------

class PricedProvider(Provider):
    """Answers every request with one ``capture_head`` call costing 1000 input and 100 output tokens."""
    name = "priced"
    capabilities = Capabilities(images_in_tool_results=True)

    def __init__(self):
        self.requests = 0

    def check_credentials(self):
        pass

    def complete(self, system, messages, tools):
        self.requests += 1
        return Response(Message("assistant", [ToolCall(f"c{self.requests}", "capture_head", {})]), "tool_calls",
                        Usage(input_tokens=1000, output_tokens=100), model="priced-1")


class Recorder:
    def __init__(self):
        self.events = []

    def event(self, kind, **data):
        self.events.append((kind, data))
        return data


class Spec:
    sandbox: dict = {}
    run_code_max_internal_calls = 500
    budget_cost_usd = 0.04


class PricedEpisode:
    """The session the harness drives, with the engine's own budget ledger."""
    instruction = "Click the bell."

    def __init__(self):
        self.ended, self.termination, self.agent = False, None, None
        self.spec = Spec()
        self.ledger = BudgetLedger.create(50, 60.0, 600.0, 0.004, cost_usd=Spec.budget_cost_usd)
        self.recorder = Recorder()

    def tool_specs(self):
        return [{"name": "capture_head", "description": "", "parameters": {"type": "object", "properties": {}}}]

    def end(self, reason, detail=""):
        if not self.ended:
            self.ended, self.termination = True, {"reason": reason, "detail": detail}

    def call(self, name, args):
        from cab_core.kits.harness import ToolResponse
        self.ledger.charge_call()
        return ToolResponse(name, {"ok": True}, [])


def test_an_attempt_ends_as_cost_budget_once_its_spend_reaches_the_cap():
    # 1000 input + 100 output tokens at 10 and 50 USD/M: 0.015 USD a response; the cap 0.04 is
    # reached by the third, whose calls are made; no fourth request is sent
    provider, episode = PricedProvider(), PricedEpisode()
    model = {"name": "priced", "provider": "priced", "pricing": {"input_per_mtok": 10.0, "output_per_mtok": 50.0}}
    ReferenceHarness({}, provider=provider).run(episode, model)
    assert provider.requests == 3
    assert episode.termination["reason"] == "cost_budget"
    assert "0.04 USD" in episode.termination["detail"]
    assert episode.ledger.summary()["cost_usd_used"] == pytest.approx(0.045)
    assert int(episode.ledger.tool_calls.usage) == 3
    assert episode.agent["usage"] == {"input_tokens": 3000, "output_tokens": 300, "usd": pytest.approx(0.045),
                                      "waited_on_limits_s": 0.0, "waited_on_retries_s": 0.0}


# -- the spend cap of a sweep ---------------------------------------------------------------------

def test_a_sweep_starts_no_attempt_once_its_spend_reaches_the_cap(tmp_path):
    # each attempt: one response (100 input + 10 output tokens at 1000 USD/M: 0.11 USD) calling done;
    # the cap 0.25 is reached by the third attempt, so the fourth is never started
    sweep = tmp_path / "sweep"
    with LimitedChat(usage=(100, 10), done_call=True) as server:
        r = subprocess.run([CAB, "-m", "task=click_bell", "sim=mujoco", "model=qwen_local",
                            f"model.base_url={server.url}", "model.probe=false",
                            "model.pricing={input_per_mtok: 1000.0, output_per_mtok: 1000.0}",
                            "attempt=1,2,3,4", "record.video=false", "sweep.max_cost_usd=0.25",
                            "sweep.preflight_network=false", "hydra.launcher.n_jobs=1", f"hydra.sweep.dir={sweep}"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=600)
        requests = len(server.arrivals)
    out = r.stdout + r.stderr
    results = sorted(sweep.rglob("result.json"))
    assert requests == 3 and len(results) == 3, out[-3000:]
    usds = [json.loads(p.read_text())["agent"]["usage"]["usd"] for p in results]
    assert usds == [pytest.approx(0.11)] * 3
    assert 0.25 <= sum(usds) < 0.25 + 0.11  # stopped within one attempt's cost
    assert "NOT STARTED: the sweep has spent $0.33, its cap sweep.max_cost_usd=0.25 (raise it to resume)" in out
    assert "| $0.22 spent, 220 tokens |" in out  # the progress line of the second attempt
    assert r.returncode != 0 and "1 missing" in out and "resume" in out.splitlines()[-1]


def test_a_sweeps_spend_counts_finished_attempts_and_the_turns_of_those_in_flight(tmp_path):
    from cab_core.sweep.spend import sweep_spend

    done, flying, old = tmp_path / "a" / "attempt-1", tmp_path / "a" / "attempt-2", tmp_path / "b" / "attempt-1"
    for d in (done, flying, old):
        d.mkdir(parents=True)
    (done / "events.jsonl").write_text(json.dumps({"kind": "model_turn", "cost": {"usd": 9.0}}) + "\n")
    (done / "result.json").write_text(json.dumps({"agent": {"usage": {
        "input_tokens": 900_000, "output_tokens": 100_000, "usd": 1.0, "waited_on_limits_s": 30.0}}}))
    turn = {"kind": "model_turn", "usage": {"input_tokens": 100_000, "cache_read_tokens": 50_000, "output_tokens": 50_000},
            "cost": {"usd": 0.1}, "waited_on_limits_s": 2.5}
    (flying / "events.jsonl").write_text(json.dumps(turn) + "\n" + json.dumps({"kind": "call"}) + "\n"
                                         + json.dumps(turn) + "\n" + '{"kind": "model_tu')  # a line being written
    (old / "events.jsonl").write_text(json.dumps({"kind": "model_usage_total", "input_tokens": 1000, "output_tokens": 0,
                                                  "usd": 0.03, "waited_on_limits_s": 0.0}) + "\n")
    spend = sweep_spend(tmp_path)
    assert spend.usd == pytest.approx(1.23) and spend.tokens == 1_401_000 and spend.attempts == 3
    assert spend.words() == "$1.23 spent, 1.4M tokens, 35 s waiting on limits"
    (flying / "events.jsonl").write_text(json.dumps(turn) + "\n")  # changed: read again
    assert sweep_spend(tmp_path).usd == pytest.approx(1.13)


@pytest.mark.parametrize("headers, wait", [
    ({"retry-after": "7"}, 7.0),
    ({"retry-after-ms": "1500", "retry-after": "9"}, 1.5),
    ({"retry-after": "Fri, 01 Jan 1999 00:00:00 GMT"}, 0.0),  # a date already past: no wait
    ({}, 60.0),  # none: the backoff's draw (the top of its range here)
])
def test_a_retry_waits_what_the_servers_retry_after_says(headers, wait):
    from fake_json_api import TopOfRange

    from cab_harness_reference.retry import RetryPolicy, call_with_retries
    from cab_harness_reference.types import ProviderError

    class Refused(Exception):
        class response:  # noqa: N801 - the shape of an SDK error's HTTP response
            pass

    Refused.response.headers = headers
    sleeps: list[float] = []
    tries = iter([Refused("429"), "answer"])

    def once():
        t = next(tries)
        if isinstance(t, Exception):
            raise t
        return t

    policy = RetryPolicy(sleep=sleeps.append, rng=TopOfRange())
    assert call_with_retries(once, lambda e: ProviderError("rate_limit", str(e), 429), policy)[0] == "answer"
    assert sleeps == [pytest.approx(wait)]
