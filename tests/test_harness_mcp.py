"""The MCP harness: real attempts served by ``cab +harness=mcp`` (a separate process, as a client
would start it) to the official MCP Python client and to the MCP Inspector CLI.

The oracle's calls are recorded once by a direct-harness attempt and replayed by the MCP client on
the same seed: the same calls give the same physics, so the attempt served over MCP must succeed
with the same number of calls."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import anyio
import pytest

pytest.importorskip("mcp")
pytest.importorskip("sapien")

from cab_core.apps.cli import normalise_overrides
from cab_core.kits.harness.agent_info import ClientInfo
from cab_core.tools import build_registry  # noqa: E402
from cab_harness_mcp.harness import attempt_model_name, configured_name
from cab_harness_mcp.script_client import calls_from_events, connect, run_script  # noqa: E402

pytestmark = [pytest.mark.sim, pytest.mark.slow]

TASK = "beat_block_hammer"
REPO = Path(__file__).resolve().parents[1]
CAB = [shutil.which("cab") or "cab"]


def serve_cmd(out: Path, *overrides: str) -> list[str]:
    return [*CAB, "+harness=mcp", f"task={TASK}", f"hydra.run.dir={out}", *overrides]


def wait_for_endpoint(server: subprocess.Popen, out: Path, timeout: float = 300) -> tuple[Path, dict]:
    """The endpoint file an HTTP-served attempt writes once it listens, and its content."""
    ep_file = out / "mcp_endpoint.json"
    deadline = time.monotonic() + timeout
    while not ep_file.exists():
        assert server.poll() is None and time.monotonic() < deadline, "the server did not come up"
        time.sleep(0.1)
    time.sleep(0.2)  # written atomically, but give the listener a moment
    return ep_file, json.loads(ep_file.read_text())


def result(out: Path) -> dict:
    return json.loads((out / "result.json").read_text())


def events(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]


def reference_tools() -> list[dict]:
    """What the reference harness gives a model: Episode.tool_specs() is built from this registry."""
    return [t.spec() for t in build_registry().values()]


@pytest.fixture(scope="module")
def oracle_run(tmp_path_factory) -> tuple[Path, list[dict]]:
    out = tmp_path_factory.mktemp("direct") / "attempt"
    subprocess.run([*CAB, "+model=oracle", f"task={TASK}", f"hydra.run.dir={out}"], check=True,
                   capture_output=True, timeout=600)
    assert result(out)["verdict"]["success"] is True
    return out, calls_from_events(out / "events.jsonl")


def test_full_oracle_attempt_over_stdio(oracle_run, tmp_path):
    direct, calls = oracle_run
    out = tmp_path / "mcp"
    seen = {}

    async def go():
        async with connect(serve_cmd(out), client_info=("oracle-replay", "7.0")) as session:
            run = await run_script(session, calls)
            # result.json is written when done returns, before the client lets go
            seen["result_before_disconnect"] = (out / "result.json").exists()
            raw = await session.call_tool("capture_head", {})  # after the end: refused, attempt intact
            seen["after_end"] = raw
            return run

    run = anyio.run(go)
    assert seen["result_before_disconnect"]
    assert seen["after_end"].is_error and "attempt has ended" in seen["after_end"].content[0].text

    # the served tools are the reference harness's, name for name and schema for schema
    ref = reference_tools()
    assert [t["name"] for t in run.tools] == [t["name"] for t in ref]
    assert [t["inputSchema"] for t in run.tools] == [t["parameters"] for t in ref]
    assert [t["description"] for t in run.tools] == [t["description"] for t in ref]
    defs = build_registry()
    for t in run.tools:
        ann = t["annotations"]
        assert ann["readOnlyHint"] is defs[t["name"]].read_only
        assert ann["destructiveHint"] is defs[t["name"]].destructive
    by = {t["name"]: t["annotations"] for t in run.tools}
    assert by["capture_head"]["readOnlyHint"] and not by["capture_head"]["destructiveHint"]
    assert by["reach_tcp"]["destructiveHint"] and not by["reach_tcp"]["readOnlyHint"]
    assert "# Task" in run.instructions and "hammer" in run.instructions.lower()

    # the capture came back as text + image content, and every call went as the direct run's
    assert run.outcomes[0].tool == "capture_head" and run.outcomes[0].images == 1
    assert [o.tool for o in run.outcomes] == [c["tool"] for c in calls]
    assert not any(o.is_error for o in run.outcomes)

    r, d = result(out), result(direct)
    assert r["verdict"]["success"] is True
    assert r["termination"]["reason"] == "done"
    assert r["harness"] == "mcp" and r["model"] == "mcp:oracle-replay"  # unnamed: after its client
    assert r["budget"]["tool_calls_used"] == d["budget"]["tool_calls_used"]
    assert r["budget"]["sim_seconds_used"] == pytest.approx(d["budget"]["sim_seconds_used"])
    kinds = [e["kind"] for e in events(out)]
    assert kinds.count("call") == len(calls)
    assert "mcp_server_start" in kinds and "mcp_client" in kinds and "mcp_attempt_ended" in kinds
    client = next(e for e in events(out) if e["kind"] == "mcp_client")
    assert (client["client"], client["name"], client["version"]) == ("oracle-replay/7.0", "oracle-replay", "7.0")


# -- who played: client identity and configuration name ----------------------------------------

def compose_model(*overrides: str) -> dict:
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides([f"task={TASK}", *overrides]))
    return {"model": OmegaConf.to_container(cfg.model), "harness": cfg.harness.name}


def test_model_config_of_a_served_attempt():
    """harness=mcp selects the mcp_client placeholder (not the oracle, which plays no part);
    model.name names the configuration; the vendor launchers keep their own names."""
    assert compose_model("+harness=mcp") == {"model": {"name": "mcp_client", "harness": "mcp"}, "harness": "mcp"}
    assert compose_model("+harness=mcp", "model.name=my-agent")["model"] == {"name": "my-agent", "harness": "mcp"}
    assert compose_model()["model"]["name"] == "oracle"  # other attempts are unchanged
    for vendor in ("opus5_claude_code", "astra_codex"):
        assert compose_model(f"model={vendor}")["model"]["name"] == vendor
        assert configured_name(compose_model(f"model={vendor}")["model"]) == vendor

    client = ClientInfo("Claude Code/α", "2.1.212")
    assert attempt_model_name({"name": "mcp_client", "harness": "mcp"}, client) == ("mcp:Claude-Code", "client")
    assert attempt_model_name({"name": "mcp_client", "harness": "mcp"}, None) == ("mcp_client", "placeholder")
    assert attempt_model_name({"name": "mcp_client"}, ClientInfo("///", "1")) == ("mcp_client", "placeholder")
    assert attempt_model_name({"name": "my-agent", "harness": "mcp"}, client) == ("my-agent", "config")
    # an in-process agent's own config (model=oracle +harness=mcp) is unnamed; renamed, it is named
    assert attempt_model_name({"name": "oracle", "agent": "oracle", "harness": "direct"}, client) == ("mcp:Claude-Code", "client")
    assert attempt_model_name({"name": "mine", "agent": "oracle", "harness": "direct"}, client) == ("mine", "config")
    assert attempt_model_name({"name": "opus5_claude_code", "harness": "claude_code"}, client) == ("opus5_claude_code", "config")


def test_unnamed_attempt_is_attributed_to_its_client(tmp_path):
    """No model.name: the folder keeps the placeholder (named before any client connects), the
    record has mcp:<client name> and the client's name and version from its handshake."""
    async def go():
        # no hydra.run.dir: the default output folder, below the directory the server starts in
        async with connect([*CAB, "+harness=mcp", f"task={TASK}", "sim=mujoco"], cwd=str(tmp_path),
                           client_info=("Test Agent/α", "0.9.1")) as session:
            return await session.call_tool("done", {"report": "named by the client", "success_claim": False})

    done = anyio.run(go)
    assert not done.is_error
    [path] = list((tmp_path / "outputs").rglob("result.json"))
    out = path.parent
    rel = out.relative_to(tmp_path / "outputs").parts
    assert rel[0] == TASK and "mcp_client" in rel and "oracle" not in rel
    r = result(out)
    assert (r["model"], r["harness"], r["sim"]) == ("mcp:Test-Agent", "mcp", "mujoco")
    me = {"name": "Test Agent/α", "version": "0.9.1", "session": 1}
    assert r["agent"] == {"kind": "mcp_client", "named_by": "client", "client": me, "clients": [me]}
    ev = events(out)
    start = next(e for e in ev if e["kind"] == "attempt_start")
    assert start["config"]["model"] == "mcp_client"  # what was configured; result.json has the attribution
    clients = [e for e in ev if e["kind"] == "mcp_client"]
    assert [{k: e[k] for k in ("client", "name", "version", "session")} for e in clients] == [
        {"client": "Test Agent/α/0.9.1", "name": "Test Agent/α", "version": "0.9.1", "session": 1}]
    assert [e["kind"] for e in ev].index("mcp_client") < [e["kind"] for e in ev].index("call")


def test_named_attempt_over_http_records_every_client(tmp_path):
    """model.name names the configuration whoever connects; two clients in turn over HTTP (two
    MCP sessions) are both recorded, each before its first call."""
    out = tmp_path / "named"
    server = subprocess.Popen(serve_cmd(out, "sim=mujoco", "harness.transport=http", "harness.linger_s=0.5",
                                        "model.name=my-agent"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _, ep = wait_for_endpoint(server, out)

        async def session_of(name: str, version: str, tool: str, args: dict):
            async with connect(url=ep["url"], headers=ep["headers"], client_info=(name, version)) as session:
                return await session.call_tool(tool, args)

        first = anyio.run(session_of, "agent-a", "1.0", "get_arm_pose", {"arm": "left"})
        last = anyio.run(session_of, "agent-b", "2.5", "done", {"report": "second client", "success_claim": False})
        assert not first.is_error and not last.is_error
        assert server.wait(timeout=120) == 0
    finally:
        if server.poll() is None:
            server.kill()
    r = result(out)
    a = {"name": "agent-a", "version": "1.0", "session": 1}
    b = {"name": "agent-b", "version": "2.5", "session": 2}
    assert (r["model"], r["termination"]["reason"]) == ("my-agent", "done")
    assert r["agent"] == {"kind": "mcp_client", "named_by": "config", "client": a, "clients": [a, b]}
    seq = [(e["kind"], e.get("name") or e.get("tool")) for e in events(out) if e["kind"] in ("mcp_client", "call")]
    assert seq == [("mcp_client", "agent-a"), ("call", "get_arm_pose"), ("mcp_client", "agent-b"), ("call", "done")]
    assert out.name == "named"  # hydra.run.dir as given


def test_structured_content_never_sent(oracle_run, tmp_path):
    """Image-bearing results are text + image only (Claude Code drops images beside structured
    content); the raw frames on stdout are nothing but JSON-RPC, whatever the simulator prints."""
    out = tmp_path / "raw"
    frames = [
        {"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {
            "protocolVersion": "2025-06-18", "capabilities": {}, "clientInfo": {"name": "raw", "version": "1"}}},
        {"jsonrpc": "2.0", "method": "notifications/initialized"},
        {"jsonrpc": "2.0", "id": 2, "method": "tools/call", "params": {"name": "capture_head", "arguments": {}}},
        {"jsonrpc": "2.0", "id": 3, "method": "tools/call", "params": {"name": "done", "arguments": {
            "report": "raw frames", "success_claim": False}}},
    ]
    lines = _raw_session(serve_cmd(out, "hydra.verbose=true"), frames, expect_ids={1, 2, 3})
    cap = next(m for m in lines if m.get("id") == 2)["result"]
    assert "structuredContent" not in cap
    assert [c["type"] for c in cap["content"]] == ["text", "text", "image"]
    assert cap["content"][2]["mimeType"] == "image/png"
    assert json.loads(cap["content"][0]["text"])["obs_id"] == "obs_0001"
    assert result(out)["termination"]["reason"] == "done"


def _raw_session(cmd: list[str], frames: list[dict | str], expect_ids: set, timeout: float = 300) -> list[dict]:
    """Write frames to a server's stdin one by one, read its stdout: every line must be JSON-RPC."""
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    got: list[dict] = []
    try:
        for f in frames:
            proc.stdin.write(((f if isinstance(f, str) else json.dumps(f)) + "\n").encode())
            proc.stdin.flush()
        deadline = time.monotonic() + timeout
        while {m.get("id") for m in got if "id" in m} < expect_ids | ({None} if any(isinstance(f, str) for f in frames) else set()):
            assert time.monotonic() < deadline, f"no answer to all of {expect_ids}: {got}"
            line = proc.stdout.readline()
            assert line, f"server closed stdout early; got {got}"
            msg = json.loads(line)  # anything but a JSON-RPC frame on stdout fails here
            assert msg.get("jsonrpc") == "2.0"
            got.append(msg)
    finally:
        proc.stdin.close()
        proc.wait(timeout=120)
    assert proc.stdout.read() == b""
    return got


def test_malformed_requests_get_protocol_errors_and_lose_nothing(tmp_path):
    out = tmp_path / "malformed"
    frames = [
        "this is not json",
        '{"jsonrpc": "2.0", "id": 7, "method": "tools/call", "params": {"name": ',  # truncated JSON
        json.dumps({"id": 8, "method": 42}),  # JSON, not JSON-RPC
        {"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {
            "protocolVersion": "2025-06-18", "capabilities": {}, "clientInfo": {"name": "raw", "version": "1"}}},
        {"jsonrpc": "2.0", "method": "notifications/initialized"},
        {"jsonrpc": "2.0", "id": 2, "method": "tools/call", "params": {"nme": "capture_head"}},  # bad params
        {"jsonrpc": "2.0", "id": 3, "method": "no/such/method", "params": {}},
        {"jsonrpc": "2.0", "id": 4, "method": "tools/call", "params": {"name": "get_arm_pose", "arguments": {"arm": "left"}}},
        {"jsonrpc": "2.0", "id": 5, "method": "tools/call", "params": {"name": "done", "arguments": {
            "report": "after malformed frames", "success_claim": False}}},
    ]
    got = _raw_session(serve_cmd(out), frames, expect_ids={1, 2, 3, 4, 5, 8})
    errors = [m for m in got if "error" in m]
    assert [e["error"]["code"] for e in errors if e["id"] is None] == [-32700, -32700]
    assert next(e for e in errors if e["id"] == 8)["error"]["code"] == -32600
    assert next(e for e in errors if e["id"] == 2)["error"]["code"] == -32602
    assert next(e for e in errors if e["id"] == 3)["error"]["code"] == -32601
    pose = next(m for m in got if m.get("id") == 4)["result"]
    assert not pose.get("isError") and "tcp_pose" in json.loads(pose["content"][0]["text"])
    r = result(out)
    assert r["termination"]["reason"] == "done"
    assert r["budget"]["tool_calls_used"] == 1  # only the well-formed call was charged
    assert [e["tool"] for e in events(out) if e["kind"] == "call"] == ["get_arm_pose", "done"]


def test_client_disconnect_mid_attempt_leaves_a_scored_record(oracle_run, tmp_path):
    _, calls = oracle_run
    out = tmp_path / "gone"

    async def go():
        async with connect(serve_cmd(out)) as session:
            return await run_script(session, calls, stop_after=3)

    run = anyio.run(go)
    assert len(run.outcomes) == 3
    deadline = time.monotonic() + 120
    while not (out / "result.json").exists():
        assert time.monotonic() < deadline
        time.sleep(0.2)
    r = result(out)
    assert r["termination"]["reason"] == "client_disconnected"
    assert r["budget"]["tool_calls_used"] == 3
    assert r["verdict"]["success"] is False and "predicates" in r["verdict"]
    assert (out / "video.mp4").exists()
    assert [e["tool"] for e in events(out) if e["kind"] == "call"] == [c["tool"] for c in calls[:3]]


def test_budget_exhaustion_ends_the_attempt_and_tells_the_client(tmp_path):
    out = tmp_path / "budget"

    async def go():
        async with connect(serve_cmd(out, "budget.tool_calls=2")) as session:
            return [await session.call_tool("get_arm_pose", {"arm": "left"}) for _ in range(4)]

    res = anyio.run(go)
    payloads = [json.loads(r.content[0].text) for r in res]
    assert not res[0].is_error and not res[1].is_error
    assert res[2].is_error and payloads[2]["attempt_ended"] is True and payloads[2]["reason"] == "tool_budget"
    assert res[3].is_error and "attempt has ended" in payloads[3]["error"]
    r = result(out)
    assert r["termination"]["reason"] == "tool_budget" and r["budget"]["tool_calls_used"] == 2


# -- the MCP Inspector CLI ---------------------------------------------------------------------

def inspector_bin() -> Path | None:
    root = Path(os.environ.get("CAB_NODE_TOOLS", REPO / ".cab_cache" / "node-tools"))
    exe = root / "node_modules" / ".bin" / "mcp-inspector"
    return exe if exe.exists() else None


def inspector(*args: str, timeout: float = 120) -> dict:
    exe = inspector_bin()
    env = dict(os.environ, PATH=f"{exe.parent}{os.pathsep}{os.environ.get('PATH', '')}")
    # a generous connection time-out: on a loaded 2-core machine the first answer can take > 15 s
    p = subprocess.run([str(exe), "--cli", *args, "--connect-timeout", "120000"], capture_output=True, text=True,
                       timeout=timeout + 120, env=env)
    assert p.returncode == 0, f"inspector {args[2:]} failed ({p.returncode}): {p.stdout[-2000:]} {p.stderr[-2000:]}"
    return json.loads(p.stdout)


def test_mcp_inspector_cli_lists_tools_and_calls_them_on_a_real_attempt(tmp_path):
    if inspector_bin() is None:
        if os.environ.get("CI"):
            pytest.fail("the MCP Inspector is not installed: run scripts/install-node-tools.sh")
        pytest.skip("the MCP Inspector is not installed (scripts/install-node-tools.sh)")
    out = tmp_path / "inspected"
    server = subprocess.Popen(serve_cmd(out, "harness.transport=http"), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        ep_file, ep = wait_for_endpoint(server, out)
        assert oct(ep_file.stat().st_mode & 0o777) == "0o600"
        base = [ep["url"], "--transport", "http", "--header", f"Authorization: {ep['headers']['Authorization']}"]

        # no token, no attempt
        import urllib.error
        import urllib.request

        with pytest.raises(urllib.error.HTTPError) as denied:
            urllib.request.urlopen(urllib.request.Request(ep["url"], data=b"{}", method="POST"), timeout=10)
        assert denied.value.code == 401

        listed = inspector(*base, "--method", "tools/list")
        ref = reference_tools()
        assert [t["name"] for t in listed["tools"]] == [t["name"] for t in ref]
        assert [t["inputSchema"] for t in listed["tools"]] == [t["parameters"] for t in ref]

        cap = inspector(*base, "--method", "tools/call", "--tool-name", "capture_head")
        assert not cap.get("isError") and "structuredContent" not in cap
        assert [c["type"] for c in cap["content"]] == ["text", "text", "image"]

        done = inspector(*base, "--method", "tools/call", "--tool-name", "done",
                         "--tool-arg", "report=checked with the MCP Inspector", "success_claim=false")
        assert json.loads(done["content"][0]["text"])["ok"] is True
        assert server.wait(timeout=120) == 0
    finally:
        if server.poll() is None:
            server.kill()
    r = result(out)
    assert r["termination"]["reason"] == "done"
    assert r["budget"]["tool_calls_used"] == 1
    calls = [e for e in events(out) if e["kind"] == "call"]
    assert [e["tool"] for e in calls] == ["capture_head", "done"]
    assert calls[1]["arguments"] == {"report": "checked with the MCP Inspector", "success_claim": False}


def test_a_fork_served_over_mcp_continues_where_its_parent_stood(oracle_run, tmp_path):
    """``cab +harness=mcp fork.from=<oracle attempt> fork.at=3``: the client is told the attempt
    continues an earlier one, its first three calls are already spent, and the parent's remaining
    calls finish the task."""
    parent, calls = oracle_run
    out = tmp_path / "fork"

    async def go():
        async with connect([*CAB, "+harness=mcp", f"fork.from={parent}", "fork.at=3", f"hydra.run.dir={out}",
                            "record.video=false"]) as session:
            return await run_script(session, calls[3:])

    run = anyio.run(go)
    assert "continues an earlier one from the state after its tool call 3" in run.instructions
    assert run.outcomes[0].payload["budget"]["tool_calls_remaining"] == 42 - 4  # the prefix's 3, and this call
    r = result(out)
    assert r["verdict"]["success"] is True and r["fork"]["at"] == 3 and r["fork"]["exact"] is True
    assert r["budget"]["tool_calls_used"] == len([c for c in calls if c["tool"] != "done"])
