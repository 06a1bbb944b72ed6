"""Plan before spending (issue 28): ``sweep.dry_run=true`` prints the jobs per configuration, each
model's provider, endpoint, key and model list, a cost range with its source and an ETA, and runs
nothing; the pre-flight refuses a sweep or a single run whose configuration cannot run (a missing
key, an endpoint that does not answer, a model it does not list) in one line per problem, before
any attempt or folder. The endpoints are fakes speaking the providers' model-list APIs over HTTP."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
from test_cli_mistakes import BIN
from test_probe import MODEL, FakeEndpoint

from cab_harness_mcp.launchers import ClaudeCodeLauncher, CodexLauncher
from cab_harness_reference import checks, probe
from cab_harness_reference.loop import ReferenceHarness

KEYS = ("ANTHROPIC_API_KEY", "OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY", "XAI_API_KEY",
        "MOONSHOT_API_KEY", "DASHSCOPE_API_KEY", "ANTHROPIC_BASE_URL", "OPENAI_BASE_URL")


class ModelList:
    """A model API's ``GET .../models`` on 127.0.0.1: the OpenAI and Anthropic shape (``data`` of
    ``{"id": ...}``), or the Google one (``models`` of ``{"name": "models/..."}``) under ``/v1beta``;
    ``status`` other than 200 answers that status with an error body. Records each request."""

    def __init__(self, ids: list[str], status: int = 200):
        self.ids, self.status, self.requests = ids, status, []
        outer = self

        class H(BaseHTTPRequestHandler):
            def log_message(self, *a):  # quiet
                pass

            def do_GET(self):  # noqa: N802
                outer.requests.append((self.path, {k.lower(): v for k, v in self.headers.items()}))
                path = self.path.split("?")[0]
                if outer.status != 200:
                    code, body = outer.status, {"error": {"type": "authentication_error", "message": "invalid x-api-key"}}
                elif "nolist" in path:
                    code, body = 404, {"error": {"message": f"no route {path}"}}
                elif path.endswith("/v1beta/models"):
                    code, body = 200, {"models": [{"name": f"models/{i}"} for i in outer.ids]}
                elif path.endswith("/models"):
                    code, body = 200, {"object": "list", "data": [{"id": i, "object": "model"} for i in outer.ids],
                                       "has_more": False}
                else:
                    code, body = 404, {"error": {"message": f"no route {path}"}}
                data = json.dumps(body).encode()
                self.send_response(code)
                self.send_header("content-type", "application/json")
                self.send_header("content-length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), H)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cab(args: list[str], cwd, **env) -> subprocess.CompletedProcess:
    e = {k: v for k, v in os.environ.items() if k not in KEYS}
    e.update({k: v for k, v in env.items() if v is not None})
    args = sorted(args, key=lambda a: not a.startswith("-"))  # options before the overrides (argparse)
    return subprocess.run([os.path.join(BIN, "cab"), *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=e)


def local(tmp_path, url: str, model_id: str = "modelA") -> list[str]:
    """``model=local``: qwen_local's settings against a local OpenAI-compatible server at ``url``
    (no key; not probed: the probe has its own tests), in a config dir beside the run's folder."""
    d = tmp_path.parent / f"{tmp_path.name}-conf" / "model"
    d.mkdir(parents=True, exist_ok=True)
    (d / "local.yaml").write_text(f"defaults: [qwen_local]\nname: local\nbase_url: {url}/v1\n"
                                  f"model_id: {model_id}\nprobe: false\n")
    return [f"--config-dir={d.parent}"]


# --- the plan ------------------------------------------------------------------------------------

def test_the_plan_of_a_sweep_counts_jobs_per_configuration_and_asks_each_endpoint(tmp_path):
    with ModelList(["modelA", "other"]) as server:
        r = cab(["-m", "model=idle,local", "task=click_bell", "sim=mujoco", "attempt=1,2,3",
                 *local(tmp_path, server.url), "sweep.dry_run=true", "hydra.launcher.n_jobs=2"], tmp_path)
    assert r.returncode == 0, r.stderr
    out = r.stdout.splitlines()
    assert out[0] == "cab plan: 6 job(s) in 2 configuration(s); 2 attempt(s) in flight (hydra.launcher.n_jobs)"
    assert "  idle (direct, mujoco): 3 job(s)" in out
    assert "  local (reference, mujoco): 3 job(s)" in out
    assert f"    provider openai_compatible, endpoint {server.url}/v1: answers, lists the model; no key needed" in out
    assert "    cost $0.00-$0.00 ($0.00-$0.00 per attempt: model.pricing is null)" in out
    assert [p.split("?")[0] for p, _ in server.requests] == ["/v1/models"]  # once for three jobs
    assert os.listdir(tmp_path) == []  # no sweep folder, nothing run


def test_a_model_the_endpoint_does_not_list_cannot_run(tmp_path):
    with ModelList(["modelA"]) as server:
        r = cab(["-m", "model=local", "task=click_bell", "sim=mujoco", *local(tmp_path, server.url, "modelZ"),
                 "sweep.dry_run=true"], tmp_path)
    assert r.returncode == 2, r.stderr
    assert (f"    PROBLEM: the endpoint {server.url}/v1 does not list the model 'modelZ' (it lists: modelA): "
            "fix model.model_id") in r.stdout.splitlines()
    assert r.stderr == "cab: 1 problem(s): a configuration cannot run (listed above)\n"
    assert os.listdir(tmp_path) == []


def _earlier_record(root, usage: dict, wall_s: float, reason: str = "done") -> None:
    d = root / "outputs" / "click_bell" / "opus5" / "mujoco" / "2026-01-01_00-00-00"
    d.mkdir(parents=True)
    (d / "result.json").write_text(json.dumps({"task": "click_bell", "model": "opus5", "sim": "mujoco",
                                               "termination": {"reason": reason}, "verdict": {"success": False},
                                               "timing": {"wall_seconds": wall_s}}))
    (d / "events.jsonl").write_text(json.dumps({"seq": 9, "kind": "model_usage_total", **usage}) + "\n")


def test_the_cost_comes_from_earlier_records_of_the_model_else_from_the_paper(tmp_path):
    """opus5 at 5/25 USD per million tokens: 100k input and 20k output tokens are $1.00 an attempt."""
    args = ["-m", "model=opus5", "task=click_bell", "sim=mujoco", "attempt=1,2", "sweep.dry_run=true",
            "hydra.launcher.n_jobs=1"]
    with ModelList(["claude-opus-5-20260101"]) as server:
        env = {"ANTHROPIC_API_KEY": "sk-test", "ANTHROPIC_BASE_URL": server.url}
        paper = cab(args, tmp_path, **env)
        _earlier_record(tmp_path, {"input_tokens": 100_000, "output_tokens": 20_000, "usd": 1.0}, 600.0)
        mine = cab(args, tmp_path, **env)
    assert paper.returncode == 0, paper.stderr
    assert f"    provider anthropic, endpoint {server.url}: answers, lists the model; key ANTHROPIC_API_KEY present" \
        in paper.stdout.splitlines()
    assert "    cost $4.96-$10.58 ($2.48-$5.29 per attempt: the paper's per-attempt IQR (model.paper_usage))" \
        in paper.stdout.splitlines()
    assert "    time per attempt 19.9 min (the paper's median)" in paper.stdout.splitlines()
    assert "cab plan: ETA 40 min at 1 attempt(s) in flight" in paper.stdout.splitlines()  # 2 x 1193.1 s
    assert mine.returncode == 0, mine.stderr
    lines = mine.stdout.splitlines()
    assert "    cost $2.00-$2.00 ($1.00-$1.00 per attempt: 1 earlier record(s))" in lines
    assert "    time per attempt 10.0 min (mean of 1 earlier record(s))" in lines
    assert "cab plan: estimated cost $2.00-$2.00" in lines
    assert "cab plan: ETA 20 min at 1 attempt(s) in flight" in lines
    _, headers = server.requests[0]
    assert (server.requests[0][0].split("?")[0], headers["x-api-key"], headers["anthropic-version"]) == \
        ("/v1/models", "sk-test", checks.ANTHROPIC_VERSION)


def test_the_paper_experiment_is_planned_without_running_anything(tmp_path):
    t0 = time.monotonic()
    r = cab(["experiment=paper", "sweep.dry_run=true", "sweep.preflight_network=false"], tmp_path,
            ANTHROPIC_API_KEY="sk-test")
    took = time.monotonic() - t0
    lines = r.stdout.splitlines()
    assert lines[0].startswith("cab plan: 675 job(s) in 9 configuration(s); "), r.stdout + r.stderr
    assert sum(1 for x in lines if x.startswith("  ") and x.endswith(": 75 job(s)")) == 9
    assert "    provider anthropic, endpoint https://api.anthropic.com: not asked; key ANTHROPIC_API_KEY present" in lines
    assert "    provider openai, endpoint https://api.openai.com/v1: not asked; key OPENAI_API_KEY MISSING" in lines
    assert any(x.startswith("cab plan: estimated cost $") for x in lines)
    assert any(x.startswith("cab plan: ETA ") for x in lines)
    assert r.returncode == 2  # the other keys are missing here
    assert os.listdir(tmp_path) == []
    print(f"experiment=paper sweep.dry_run=true: {took:.1f} s")


# --- the pre-flight ------------------------------------------------------------------------------

def test_a_sweep_with_a_missing_key_runs_nothing(tmp_path):
    r = cab(["-m", "model=idle,opus5", "task=click_bell", "sim=mujoco"], tmp_path)
    assert (r.returncode, r.stderr) == (2, "cab: refused: opus5 (reference, mujoco): ANTHROPIC_API_KEY is not set: "
                                            "model 'opus5' (provider anthropic) needs it in the environment\n")
    assert os.listdir(tmp_path) == []  # the idle job did not run: no sweep folder


def test_a_sweep_against_a_server_that_does_not_answer_runs_nothing(tmp_path):
    url = f"http://127.0.0.1:{closed_port()}"
    r = cab(["-m", "model=idle,local", "task=click_bell", "sim=mujoco", *local(tmp_path, url)], tmp_path)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"cab: refused: local (reference, mujoco): the endpoint {url}/v1 does not answer (")
    assert "start the server, or fix model.base_url" in r.stderr
    assert os.listdir(tmp_path) == []


def test_offline_the_pre_flight_checks_keys_only(tmp_path):
    url = f"http://127.0.0.1:{closed_port()}"
    r = cab(["model=local", "task=click_bell", "sim=mujoco", *local(tmp_path, url), "sweep.dry_run=true",
             "sweep.preflight_network=false"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[:3] == [
        "cab plan: 1 job(s) in 1 configuration(s); 1 attempt(s) in flight (hydra.launcher.n_jobs)",
        "  local (reference, mujoco): 1 job(s)",
        f"    provider openai_compatible, endpoint {url}/v1: not asked; no key needed"]
    assert os.listdir(tmp_path) == []


def test_a_single_run_against_a_server_that_does_not_answer_is_one_line(tmp_path):
    url = f"http://127.0.0.1:{closed_port()}"
    r = cab(["model=local", "task=click_bell", "sim=mujoco", *local(tmp_path, url)], tmp_path)
    assert r.returncode == 2 and r.stdout == "", r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"cab: the endpoint {url}/v1 does not answer ("), r.stderr
    assert os.listdir(tmp_path) == []  # before Hydra made the run folder, before any simulator


# --- the reference harness's check_model ---------------------------------------------------------

def _check(cfg: dict, **env) -> object:
    with pytest.MonkeyPatch.context() as mp:
        for k in KEYS:
            mp.delenv(k, raising=False)
        for k, v in env.items():
            mp.setenv(k, v)
        return ReferenceHarness().check_model(cfg)


def test_a_refused_key_is_a_problem_naming_its_variable():
    with ModelList([], status=401) as server:
        c = _check({"name": "gpt56", "provider": "openai", "model_id": "gpt-5.6", "base_url": server.url + "/v1"},
                   OPENAI_API_KEY="sk-bad")
    assert (c.key_env, c.key_present, c.reachable, c.model_listed) == ("OPENAI_API_KEY", True, True, None)
    assert c.problems == [f"the endpoint {server.url}/v1 refuses the key in OPENAI_API_KEY (HTTP 401 on GET "
                          "/models): set a valid key"]
    assert server.requests[0][1]["authorization"] == "Bearer sk-bad"


def test_google_lists_its_models_under_v1beta_with_the_key_as_a_parameter():
    with ModelList(["gemini-3.6-flash"]) as server:
        c = _check({"name": "g", "provider": "google", "model_id": "gemini-3.6-flash", "base_url": server.url},
                   GEMINI_API_KEY="g-key")
    assert (c.provider, c.key_env, c.reachable, c.model_listed, c.problems) == \
        ("google", "GEMINI_API_KEY", True, True, [])
    path = server.requests[0][0]
    assert path.startswith("/v1beta/models?") and "key=g-key" in path


def test_a_dated_id_counts_as_its_alias_and_nothing_else_does():
    assert checks._knows(["claude-opus-5-20260101"], "claude-opus-5")
    assert not checks._knows(["claude-opus-5-mini"], "claude-opus-5")
    assert not checks._knows(["claude-opus-50"], "claude-opus-5")


def test_an_endpoint_without_a_model_list_answers_and_its_list_is_unknown():
    with ModelList(["m"]) as server:  # 404 below /nolist
        c = _check({"name": "q", "provider": "openai_compatible", "model_id": "m", "api_key_env": None,
                    "base_url": server.url + "/nolist/x", "probe": False})
    assert (c.reachable, c.model_listed, c.key_present, c.problems) == (True, None, None, [])


def test_no_network_no_request_and_a_missing_key_is_the_providers_own_line():
    c = _check({"name": "opus5", "provider": "anthropic", "model_id": "claude-opus-5"})
    assert (c.endpoint, c.key_present, c.reachable) == ("https://api.anthropic.com", False, None)
    assert c.problems == ["ANTHROPIC_API_KEY is not set: model 'opus5' (provider anthropic) needs it in the environment"]


def test_a_local_server_without_vision_cannot_run_and_quirks_the_harness_handles_are_notes():
    cfg = {"name": "local", "provider": "openai_compatible", "model_id": MODEL, "api_key_env": None}
    probe.clear_cache()
    with FakeEndpoint("vllm", image_cap=0) as srv:
        blind = _check({**cfg, "base_url": srv.url})
    with FakeEndpoint("llama.cpp", jinja=False) as srv:  # the harness describes the tools in the prompt
        no_jinja = _check({**cfg, "base_url": srv.url})
    with FakeEndpoint("vllm", tool_images=False) as srv:  # the harness moves images to a user message
        no_tool_images = _check({**cfg, "base_url": srv.url})
    assert blind.capabilities["images"] is False
    assert len(blind.problems) == 1 and blind.problems[0].startswith("the endpoint refuses images"), blind.problems
    assert (no_jinja.capabilities["tools"], no_jinja.problems) == ("rejected", [])
    assert any("--jinja" in p for p in no_jinja.capabilities["problems"])
    assert (no_tool_images.capabilities["images_in_tool_results"], no_tool_images.problems) == (False, [])
    assert any("images are refused in tool messages" in p for p in no_tool_images.capabilities["problems"])


def test_claude_code_and_codex_need_their_cli_on_path_and_their_key(monkeypatch):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-test")
    monkeypatch.setenv("PATH", "")
    codex = CodexLauncher({}).check_model({"name": "astra_codex", "api_key_env": "OPENAI_API_KEY"})
    claude = ClaudeCodeLauncher({}).check_model({"name": "opus5_claude_code", "api_key_env": "ANTHROPIC_API_KEY"})
    assert (codex.provider, codex.key_env, codex.key_present) == ("codex", "OPENAI_API_KEY", False)
    assert codex.problems == ["codex ('codex') is not on PATH: install it with: npm install -g @openai/codex@0.154.0",
                              "codex needs the environment variable OPENAI_API_KEY (model.vendor.api_key_env)"]
    assert (claude.key_present, len(claude.problems)) == (True, 1) and "claude-code" in claude.problems[0]


def test_the_plan_of_a_sweep_being_resumed_counts_only_what_is_left(tmp_path):
    pytest.importorskip("mujoco")
    sweep = ["-m", "model=idle", "task=click_bell", "sim=mujoco", "record.video=false", "hydra.launcher.n_jobs=1",
             f"hydra.sweep.dir={tmp_path / 's'}"]
    ran = cab([*sweep, "attempt=1"], tmp_path)
    assert ran.returncode == 0, ran.stderr[-2000:]
    again = cab([*sweep, "attempt=1", "sweep.dry_run=true"], tmp_path)
    assert again.returncode == 0, again.stderr
    assert again.stdout.splitlines()[:2] == [
        "cab plan: 1 job(s) in 1 configuration(s), 0 still to run; 1 attempt(s) in flight (hydra.launcher.n_jobs)",
        "  idle (direct, mujoco): 1 job(s), 0 to run"]
    more = cab([*sweep, "attempt=1,2,3", "sweep.dry_run=true"], tmp_path)  # another sweep: refused there
    assert more.returncode == 2, more.stderr
    lines = more.stdout.splitlines()
    assert lines[:2] == [
        "cab plan: 3 job(s) in 1 configuration(s), 2 still to run; 1 attempt(s) in flight (hydra.launcher.n_jobs)",
        "  idle (direct, mujoco): 3 job(s), 2 to run"]
    assert lines[-1] == (f"  PROBLEM: {tmp_path / 's'} holds a sweep with another configuration: running this "
                         "command there would be refused; resume it with its own overrides, or choose a new "
                         "hydra.sweep.dir")
