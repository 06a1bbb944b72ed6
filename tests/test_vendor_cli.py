"""The vendor harnesses with the real CLIs: Claude Code 2.1.212 and Codex CLI 0.154.0 (installed by
scripts/install-node-tools.sh) each play the agent of a real attempt, started exactly as a user
starts one (``cab +model=opus5_claude_code task=beat_block_hammer``), against a local scripted model
that speaks its provider's streaming wire format (tests/fake_model_apis.py). No network, no key.

The scripted model looks once (capture_head), gives up (done, claim false) and says so. The tests
check both ends: the attempt's records (termination, claim, the charged calls, the vendor's
transcript, the usage the model reported) and what the CLI sent the model (the benchmark's tools
and nothing that reaches files, shell or web beyond what the paper's configuration keeps, the
capture's image inside the tool result, the key, the model settings)."""
from __future__ import annotations

import base64
import io
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcp")
pytest.importorskip("sapien")

from fake_model_apis import FakeAnthropic, FakeResponses, Request, Turn  # noqa: E402

from cab_core.tools import build_registry  # noqa: E402

pytestmark = [pytest.mark.sim, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[1]
NODE_BIN = Path(os.environ.get("CAB_NODE_TOOLS", REPO / ".cab_cache" / "node-tools")) / "node_modules" / ".bin"
TASK = "beat_block_hammer"
REPORT = "Looked at the scene once; stopping without attempting the task."
KEY = "test-key-not-secret"
# environment a developer's shell may carry that would point a CLI elsewhere
FOREIGN_ENV = ("ANTHROPIC_", "OPENAI_", "CODEX_", "CLAUDE_", "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY",
               "http_proxy", "https_proxy", "all_proxy")


def cli(name: str) -> Path:
    exe = NODE_BIN / name
    if not exe.exists():
        if os.environ.get("CI"):
            pytest.fail(f"{name} is not installed: run scripts/install-node-tools.sh")
        pytest.skip(f"{name} is not installed (scripts/install-node-tools.sh)")
    return exe


def run_attempt(model: str, tmp_path: Path, env: dict[str, str]) -> Path:
    """``cab +model=<model>`` as a subprocess, HOME in a fresh directory (no user configuration);
    returns the attempt's output directory."""
    home, out = tmp_path / "home", tmp_path / "attempt"
    home.mkdir()
    full = {k: v for k, v in os.environ.items() if not k.startswith(FOREIGN_ENV)}
    full.update(HOME=str(home), PATH=f"{NODE_BIN}{os.pathsep}{os.environ.get('PATH', '')}", **env)
    cab = shutil.which("cab") or "cab"
    p = subprocess.run([cab, f"+model={model}", f"task={TASK}", f"hydra.run.dir={out}"], env=full,
                       capture_output=True, text=True, timeout=600)
    stderr_log = out / "vendor_stderr.log"
    assert p.returncode == 0, f"cab failed ({p.returncode}): {p.stderr[-3000:]}\n" + (
        stderr_log.read_text()[-3000:] if stderr_log.exists() else "")
    return out


def cab_tools() -> set[str]:
    return set(build_registry())


def pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)))


def same_image_as_recorded(png: bytes, out: Path, obs_id: str = "obs_0001") -> bool:
    """The image the model got is the observation the attempt recorded, pixel for pixel."""
    recorded = pixels((out / "observations" / f"{obs_id}.png").read_bytes())
    got = pixels(png)
    return got.shape == recorded.shape == (480, 640, 3) and np.array_equal(got, recorded)


def check_record(out: Path, usage: dict) -> None:
    """What every vendor attempt must leave: done with the claim false, the two charged calls,
    the vendor's stream, and the usage the scripted model reported, in the shared buckets."""
    result = json.loads((out / "result.json").read_text())
    assert result["termination"]["reason"] == "done"
    assert result["claim"] == {"success_claim": False, "report": REPORT}
    assert result["verdict"]["success"] is False
    assert result["budget"]["tool_calls_used"] == 1  # capture_head; done is free
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    assert [e["tool"] for e in events if e["kind"] == "call"] == ["capture_head", "done"]
    transcript = (out / "vendor_transcript.jsonl").read_text().splitlines()
    assert transcript and all(json.loads(line) for line in transcript)
    total = next(e for e in events if e["kind"] == "model_usage_total")
    assert {k: total[k] for k in usage} == usage
    exit_event = next(e for e in events if e["kind"] == "vendor_exit")
    assert exit_event["exit_code"] == 0


# -- Claude Code ----------------------------------------------------------------------------------

def anthropic_usage(i: int) -> dict:
    return {"input_tokens": 100 * i, "output_tokens": 10 * i, "cache_read_input_tokens": 1000 * i,
            "cache_creation_input_tokens": 50 * i}


def claude_script() -> list[Turn]:
    """Look, give up, say so."""
    return [
        Turn([{"type": "text", "text": "Looking first."},
              {"type": "tool_use", "id": "toolu_01", "name": "mcp__cab__capture_head", "input": {}}],
             anthropic_usage(1), "tool_use"),
        Turn([{"type": "tool_use", "id": "toolu_02", "name": "mcp__cab__done",
               "input": {"report": REPORT, "success_claim": False}}], anthropic_usage(2), "tool_use"),
        Turn([{"type": "text", "text": "Finished."}], anthropic_usage(3)),
    ]


def tool_result(req: Request, tool_use_id: str) -> dict:
    return next(block for m in req.body["messages"] if m["role"] == "user" and isinstance(m["content"], list)
                for block in m["content"] if block.get("type") == "tool_result" and block["tool_use_id"] == tool_use_id)


def tool_names(req: Request) -> list[str]:
    return sorted(t["name"] for t in req.body["tools"])


def test_claude_code_runs_an_attempt_against_a_scripted_messages_api(tmp_path):
    cli("claude")
    script = claude_script()
    with FakeAnthropic(list(script)) as api:
        out = run_attempt("opus5_claude_code", tmp_path, {"ANTHROPIC_BASE_URL": api.url, "ANTHROPIC_API_KEY": KEY})
    assert not api.script and len(api.model_requests) == len(script)
    # nothing but the model's requests and the client's reachability probe (no telemetry, no updates)
    assert {(r.method, r.path.split("?")[0]) for r in api.requests} <= {
        ("HEAD", "/"), ("POST", "/v1/messages"), ("POST", "/v1/messages/count_tokens")}
    first = api.model_requests[0]
    assert first.headers["x-api-key"] == KEY
    assert first.body["model"] == "claude-opus-5" and first.body["output_config"] == {"effort": "high"}
    assert first.body["stream"] is True
    # exactly the benchmark's tools, in every request: every built-in (Bash, Read, Write, WebFetch,
    # Task, Cron*, ...) is gone (ToolSearch, kept, is offered only while Claude Code defers MCP tools,
    # which it does not for this endpoint)
    cab_names = sorted(f"mcp__cab__{n}" for n in cab_tools())
    assert all(tool_names(r) == cab_names for r in api.model_requests)
    assert "hammer" in json.dumps(first.body["messages"][0])

    # the capture reached the model as text + image, the image the attempt recorded
    seen = tool_result(api.model_requests[1], "toolu_01")
    assert [c["type"] for c in seen["content"]] == ["text", "text", "image"]
    assert json.loads(seen["content"][0]["text"])["obs_id"] == "obs_0001"
    img = seen["content"][2]["source"]
    assert img["type"] == "base64" and img["media_type"] == "image/png"
    assert same_image_as_recorded(base64.b64decode(img["data"]), out)
    assert json.loads(tool_result(api.model_requests[2], "toolu_02")["content"][0]["text"])["ok"] is True

    sums = {k: sum(t.usage[k] for t in script) for k in anthropic_usage(1)}
    # Claude Code's own cost at the paper's rates (5 / 25 USD per M tokens, cache 0.5 / 6.25)
    usd = (sums["input_tokens"] * 5 + sums["output_tokens"] * 25 + sums["cache_read_input_tokens"] * 0.5
           + sums["cache_creation_input_tokens"] * 6.25) / 1e6
    check_record(out, {"input_tokens": sums["input_tokens"], "output_tokens": sums["output_tokens"],
                       "cache_read_tokens": sums["cache_read_input_tokens"],
                       "cache_write_tokens": sums["cache_creation_input_tokens"], "turns": len(script),
                       "usd": pytest.approx(usd), "source": "claude_code"})


# -- Codex CLI --------------------------------------------------------------------------------------

# gpt-6-astra runs in Codex's code mode: its tools are JavaScript functions inside the ``exec`` tool.
LOOK = """text(JSON.stringify(ALL_TOOLS.map((t) => t.name)));
const shot = await tools.mcp__cab__capture_head({});
for (const c of shot.content) { if (c.type === "image") { image(c); } else { text(c.text); } }"""
# the shell Codex keeps, in its read-only sandbox: reading works, writing fails
PROBE = """const r = await tools.exec_command({cmd: "echo x > probe.txt; echo write_rc=$?; head -c 11 /etc/os-release"});
text(r.output);"""
GIVE_UP = f"""const r = await tools.mcp__cab__done({{report: {json.dumps(REPORT)}, success_claim: false}});
text(r.content[0].text);"""
# what Codex 0.154.0 keeps beside the benchmark's tools for gpt-6-astra (paper: computation and tool
# composition in its execution environment, a read-only sandbox, no web search)
CODEX_TOP_TOOLS = {"exec", "wait", "request_user_input", "request_user_input_async", "sleep", "followup_task",
                   "interrupt_agent", "list_agents", "send_message", "spawn_agent", "wait_agent"}
CODEX_NESTED_BUILTINS = {"apply_patch", "clock__curr_time", "create_goal", "exec_command", "get_goal",
                         "list_mcp_resource_templates", "list_mcp_resources", "read_mcp_resource", "update_goal",
                         "view_image", "write_stdin"}


def responses_usage(i: int) -> dict:
    return {"input_tokens": 1000 * i, "input_tokens_details": {"cached_tokens": 300 * i},
            "output_tokens": 20 * i, "output_tokens_details": {"reasoning_tokens": 5 * i}, "total_tokens": 1020 * i}


def exec_call(n: int, code: str) -> dict:
    return {"type": "custom_tool_call", "id": f"ctc_{n}", "call_id": f"call_{n}", "name": "exec", "input": code}


def codex_script() -> list[Turn]:
    return [
        Turn([exec_call(1, LOOK)], responses_usage(1)),
        Turn([exec_call(2, PROBE)], responses_usage(4)),
        Turn([exec_call(3, GIVE_UP)], responses_usage(2)),
        Turn([{"type": "message", "id": "msg_4", "role": "assistant",
               "content": [{"type": "output_text", "text": "Finished.", "annotations": []}]}], responses_usage(3)),
    ]


def call_output(req: Request, call_id: str) -> list[dict]:
    return next(it["output"] for it in req.body["input"]
                if it.get("type") == "custom_tool_call_output" and it["call_id"] == call_id)


def top_level_tools(req: Request) -> set[str]:
    return {t["name"] for it in req.body["input"] if it.get("type") == "additional_tools"
            for ns in it["tools"] for t in ns.get("tools", [ns])}


def test_codex_runs_an_attempt_against_a_scripted_responses_api(tmp_path):
    cli("codex")
    # Codex refuses to set up its sandbox helper under the system's temporary directory, where
    # tmp_path lives: its own temporary directory is moved aside so that CODEX_HOME is not inside it
    codex_home, codex_tmp = tmp_path / "codex_home", tmp_path / "codex_tmp"
    codex_home.mkdir()
    codex_tmp.mkdir()
    script = codex_script()
    with FakeResponses(list(script)) as api:
        out = run_attempt("astra_codex", tmp_path, {"OPENAI_BASE_URL": f"{api.url}/v1", "OPENAI_API_KEY": KEY,
                                                    "CODEX_HOME": str(codex_home), "TMPDIR": str(codex_tmp)})
    assert not api.script and len(api.model_requests) == len(script)
    # the key configured for the model (OPENAI_API_KEY) reached the API on every request
    assert all(r.headers.get("authorization") == f"Bearer {KEY}" for r in api.requests)
    first = api.model_requests[0]
    assert first.body["model"] == "gpt-6-astra" and first.body["reasoning"]["effort"] == "high"
    assert first.body["stream"] is True
    # the model's own tools: no web search; the benchmark's tools are nested in exec
    assert top_level_tools(first) == CODEX_TOP_TOOLS
    assert "web_search" not in json.dumps(first.body["input"])
    # read-only sandbox, as the request shows it: turn metadata and the filesystem permissions
    assert json.loads(first.headers["x-codex-turn-metadata"])["sandbox_mode"] == "read-only"
    context = next(c["text"] for it in first.body["input"] if it.get("role") == "user"
                   for c in it["content"] if "<environment_context>" in c.get("text", ""))
    assert 'access="read"' in context and 'access="write"' not in context
    assert str(out / "vendor_workdir") in context

    looked = call_output(api.model_requests[1], "call_1")
    listed = json.loads(looked[1]["text"])
    assert set(listed) == CODEX_NESTED_BUILTINS | {f"mcp__cab__{n}" for n in cab_tools()}
    assert json.loads(looked[2]["text"])["obs_id"] == "obs_0001"
    image = next(c for c in looked if c["type"] == "input_image")
    prefix = "data:image/png;base64,"
    assert image["image_url"].startswith(prefix)
    assert same_image_as_recorded(base64.b64decode(image["image_url"][len(prefix):]), out)
    # and as the shell finds it: reading works, writing fails, nothing is written
    shell = call_output(api.model_requests[2], "call_2")[1]["text"]
    assert "Read-only file system" in shell and "write_rc=1" in shell and "PRETTY_NAME" in shell
    assert list((out / "vendor_workdir").iterdir()) == []
    assert json.loads(call_output(api.model_requests[3], "call_3")[1]["text"])["ok"] is True

    total = {k: sum(t.usage[k] for t in script) for k in ("input_tokens", "output_tokens")}
    cached = sum(t.usage["input_tokens_details"]["cached_tokens"] for t in script)
    reasoning = sum(t.usage["output_tokens_details"]["reasoning_tokens"] for t in script)
    check_record(out, {"input_tokens": total["input_tokens"] - cached, "cache_read_tokens": cached,
                       "cache_write_tokens": 0, "output_tokens": total["output_tokens"],
                       "reasoning_tokens": reasoning, "source": "codex", "turns": 1,
                       # no cost in Codex's stream: the model config's rates (10 / 50 USD per M tokens;
                       # cache reads at the input rate, the config giving none of their own)
                       "usd": pytest.approx((total["input_tokens"] * 10 + total["output_tokens"] * 50) / 1e6)})
