"""Issue 26, item 11: small protocol points of the MCP harness, and ``done`` answered before the video.

- A message whose id MCP does not allow (``null``, a boolean, an object, an array, a number with a
  fraction or an exponent, ``NaN``) is answered with -32600 (Invalid Request) and id null, over
  streamable HTTP (HTTP 400) and over stdio, instead of being taken for a notification.
- ``done`` is answered once the verdict is recorded (``result.json`` written, ``video`` null); the
  video is rendered after the answer and ``result.json`` written again with it listed. A failure or
  an interruption while rendering keeps the verdict.
- After the attempt has ended, the HTTP server keeps serving until its client ends its session
  (DELETE), so the client's session termination succeeds.

The servers run in this process (no simulator for the protocol checks; MuJoCo for the attempts).
"""
from __future__ import annotations

import json
import logging
import os
import threading
import urllib.error
import urllib.request
from pathlib import Path

import anyio
import pytest

pytest.importorskip("mcp")
pytest.importorskip("mujoco")

from hydra import compose, initialize_config_module  # noqa: E402

from cab_core.apps.cli import normalise_overrides  # noqa: E402
from cab_core.attempt.engine.episode import Episode  # noqa: E402
from cab_core.attempt.spec import attempt_spec  # noqa: E402
from cab_core.kits.harness.stdio import StdioChannel  # noqa: E402
from cab_core.plugins import all_tasks, create  # noqa: E402
from cab_harness_mcp.bridge import CallBridge  # noqa: E402
from cab_harness_mcp.harness import McpHarness  # noqa: E402
from cab_harness_mcp.script_client import connect  # noqa: E402
from cab_harness_mcp.server import build_server, tool_list  # noqa: E402
from cab_harness_mcp.transport import HttpServerThread, StdioServerThread  # noqa: E402

INIT = {"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {
    "protocolVersion": "2025-06-18", "capabilities": {}, "clientInfo": {"name": "raw", "version": "1"}}}
# the id as written in the request body, and why MCP refuses it
BAD_IDS = ["NaN", "Infinity", "{}", '{"a": 1}', "[]", "true", "false", "null", "1e308", "1.5", "2.0"]


def server():
    return build_server(tool_list(), CallBridge(), "the task", "0")


def result(out: Path) -> dict:
    return json.loads((out / "result.json").read_text())


def events(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]


# -- ids ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def http_server():
    t = HttpServerThread(server(), "127.0.0.1", 0, auth=False, session_idle_timeout=None).start()
    yield t
    t.stop()


def post(url: str, body: str, headers: dict | None = None) -> tuple[int, dict, str]:
    req = urllib.request.Request(url, data=body.encode(), method="POST", headers={
        "Content-Type": "application/json", "Accept": "application/json, text/event-stream", **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, {k.lower(): v for k, v in r.headers.items()}, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, {k.lower(): v for k, v in e.headers.items()}, e.read().decode()


def session_headers(url: str) -> dict:
    status, headers, _ = post(url, json.dumps(INIT))
    assert status == 200 and headers.get("mcp-session-id")
    h = {"mcp-session-id": headers["mcp-session-id"], "mcp-protocol-version": "2025-06-18"}
    assert post(url, json.dumps({"jsonrpc": "2.0", "method": "notifications/initialized"}), h)[0] == 202
    return h


def sse_messages(body: str) -> list[dict]:
    return [json.loads(line[5:]) for line in body.splitlines() if line.startswith("data:") and line[5:].strip()]


@pytest.mark.parametrize("rid", BAD_IDS)
def test_http_request_with_an_id_mcp_does_not_allow_gets_invalid_request(http_server, rid):
    """Was: HTTP 202 and no answer (the SDK took the message for a notification)."""
    h = session_headers(http_server.url)
    status, _, body = post(http_server.url, f'{{"jsonrpc": "2.0", "id": {rid}, "method": "tools/list"}}', h)
    assert status == 400
    err = json.loads(body)
    assert err["jsonrpc"] == "2.0" and err["id"] is None and err["error"]["code"] == -32600
    assert "id must be a string or an integer" in err["error"]["message"]


def test_http_well_formed_ids_are_still_answered(http_server):
    h = session_headers(http_server.url)
    for rid in ('"abc"', "7", "-3", "0"):
        status, _, body = post(http_server.url, f'{{"jsonrpc": "2.0", "id": {rid}, "method": "tools/list"}}', h)
        assert status == 200, body
        [msg] = sse_messages(body)
        assert msg["id"] == json.loads(rid) and len(msg["result"]["tools"]) == len(tool_list())
    # a notification (no id) is still accepted; a body that is not JSON is still the SDK's parse error
    assert post(http_server.url, '{"jsonrpc": "2.0", "method": "notifications/cancelled", '
                                 '"params": {"requestId": 99}}', h)[0] == 202
    status, _, body = post(http_server.url, '{"jsonrpc": "2.0", "id": ', h)
    assert status == 400 and json.loads(body)["error"]["code"] == -32700


def test_stdio_frames_with_an_id_mcp_does_not_allow_get_invalid_request():
    """Was: dropped without an answer (taken for notifications)."""
    in_r, in_w = os.pipe()
    out_r, out_w = os.pipe()
    t = StdioServerThread(server(), StdioChannel(in_r, out_w)).start()
    frames = [json.dumps(INIT), '{"jsonrpc": "2.0", "method": "notifications/initialized"}']
    frames += [f'{{"jsonrpc": "2.0", "id": {rid}, "method": "tools/list"}}' for rid in BAD_IDS]
    frames += ['{"jsonrpc": "2.0", "id": "last", "method": "ping"}']
    reader = os.fdopen(out_r, "rb")
    try:
        with os.fdopen(in_w, "wb", closefd=False) as w:
            w.write(("\n".join(frames) + "\n").encode())
            w.flush()
        got = []
        while not got or got[-1].get("id") != "last":
            line = reader.readline()
            assert line, f"the server closed stdout; got {got}"
            got.append(json.loads(line))
    finally:
        os.close(in_w)
        t.stop()
        reader.close()
        for fd in (in_r, out_w):
            os.close(fd)
    assert got[0]["id"] == 1 and "result" in got[0]
    errors = got[1:-1]
    assert len(errors) == len(BAD_IDS)
    for e in errors:
        assert e["id"] is None and e["error"]["code"] == -32600
        assert "id must be a string or an integer" in e["error"]["message"]
    assert got[-1] == {"jsonrpc": "2.0", "id": "last", "result": {}}


# -- done before the video ------------------------------------------------------------------------

def open_episode(out: Path, task: str = "click_bell") -> Episode:
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(
            [f"task={task}", "sim=mujoco", "record.video_size=[160,120]", "record.observers=[]"]))
    spec = attempt_spec(cfg, out)
    return Episode(spec, all_tasks()[spec.task], create("simulators", spec.sim, spec.sim_cfg),
                   create("planners", spec.planner, {}), create("embodiments", spec.embodiment, {}))


def watch_render(ep: Episode, before=None):
    """Count the video's rendering calls; ``before(samples, add)`` runs first (may raise)."""
    calls = []
    render = ep.sim.render_samples

    def spy(camera, samples, add):
        calls.append(len(samples))
        if before is not None:
            before(samples, add)
        return render(camera, samples, add)

    ep.sim.render_samples = spy
    return calls


def test_done_is_recorded_before_the_video_is_rendered(tmp_path):
    out = tmp_path / "a"
    ep = open_episode(out)
    try:
        rendered = watch_render(ep)
        assert ep.call("set_gripper", {"arm": "left", "pos": 0.5}).payload.get("error") is None
        done = ep.call("done", {"report": "checking the order", "success_claim": False})
        assert done.payload["ok"] is True
        first = ep.finish()
        # the verdict is on disk, the video is not rendered yet and not listed
        assert rendered == []
        on_disk = result(out)
        assert on_disk["termination"]["reason"] == "done" and "success" in on_disk["verdict"]
        assert on_disk["video"] is None and not (out / "video.mp4").exists()
        assert events(out)[-1]["kind"] == "attempt_end"
    finally:
        ep.close()
    [n] = rendered
    assert n > 1
    final = result(out)
    assert final["video"]["file"] == "video.mp4" and final["video"]["frames"] == n
    assert final["video"]["rendered"] == "after the attempt" and final["video"]["render_seconds"] >= 0
    assert "error" not in final["video"]
    assert (out / "video.mp4").stat().st_size > 0 and not (out / "video.partial.mp4").exists()
    same = ("video", "timing")  # the whole attempt's wall time counts the video, as before
    assert {k: v for k, v in final.items() if k not in same} == {k: v for k, v in on_disk.items() if k not in same}
    assert final["timing"]["wall_seconds"] >= on_disk["timing"]["wall_seconds"] + final["video"]["render_seconds"] - 0.01
    assert first is ep.result and first["video"] == final["video"]  # the dict finish() returned, completed
    assert events(out)[-1]["kind"] == "attempt_end"  # the video adds no event after the end


@pytest.mark.parametrize("fault", ["error", "interrupt"])
def test_a_failure_while_rendering_the_video_keeps_the_verdict(tmp_path, fault):
    out = tmp_path / fault
    ep = open_episode(out)

    render = ep.sim.render_samples

    def two_frames_then_fail(camera, samples, add):
        render(camera, samples[:2], add)
        raise RuntimeError("renderer lost") if fault == "error" else KeyboardInterrupt()

    ep.sim.render_samples = two_frames_then_fail
    ep.call("set_gripper", {"arm": "left", "pos": 0.5})
    ep.call("done", {"report": "the renderer fails", "success_claim": True})
    ep.finish()
    if fault == "interrupt":
        with pytest.raises(KeyboardInterrupt):
            ep.close()
    else:
        ep.close()
    r = result(out)
    assert r["termination"]["reason"] == "done" and r["claim"]["success_claim"] is True and "success" in r["verdict"]
    assert r["video"]["frames"] == 2 and (out / "video.mp4").stat().st_size > 0
    assert r["video"]["error"] == ("rendering failed: RuntimeError('renderer lost')" if fault == "error"
                                   else "interrupted")
    assert events(out)[-1]["kind"] == "attempt_end"


# -- over MCP: the answer before the video, the session ended by its client ------------------------

def test_mcp_done_answers_before_the_video_and_the_server_waits_for_the_session_to_end(tmp_path):
    """The client gets done's answer while the video is still to be rendered (the rendering waits
    for the client to have seen the answer), then ends its session (DELETE) after a moment, as a
    client that writes its last message does: the server is still there to accept it."""
    out = tmp_path / "served"
    ep = open_episode(out)
    answered, seen = threading.Event(), {}
    rendered = watch_render(ep, before=lambda samples, add: seen.setdefault("answered_first", answered.wait(60)))
    harness = McpHarness({"transport": "http", "auth": False, "linger_s": 120})
    harness.before_build(ep.spec)
    warnings: list[str] = []

    class Catch(logging.Handler):
        def emit(self, record):
            if record.levelno >= logging.WARNING:
                warnings.append(record.getMessage())

    catch = Catch()
    logging.getLogger("mcp").addHandler(catch)

    async def client():
        async with connect(url=harness.transport.url, client_info=("late-closer", "1")) as session:
            await session.call_tool("set_gripper", {"arm": "left", "pos": 0.5})
            res = await session.call_tool("done", {"report": "over http", "success_claim": False})
            seen["done"] = json.loads(res.content[0].text)
            seen["video_at_answer"] = result(out)["video"]
            answered.set()
            await anyio.sleep(1.0)  # the client's last words; the server keeps serving meanwhile
            seen["after"] = json.loads((await session.call_tool("get_arm_pose", {"arm": "left"})).content[0].text)

    errors = []

    def run_client():
        try:
            anyio.run(client)
        except BaseException as e:  # reported below
            errors.append(e)
        finally:
            answered.set()

    th = threading.Thread(target=run_client, daemon=True)
    th.start()
    try:
        harness.run(ep, {"name": "mcp_client"})  # this thread owns the simulator, as cab's does
    finally:
        th.join(180)
        ep.close()
        logging.getLogger("mcp").removeHandler(catch)
    assert not errors, errors
    assert seen["done"]["ok"] is True
    # the rendering waited for the client to hold the answer (it would wait in vain if the answer
    # waited for the video), and result.json had the verdict without the video then
    assert seen["answered_first"] is True and seen["video_at_answer"] is None
    assert seen["after"]["attempt_ended"] is True and "attempt has ended" in seen["after"]["error"]
    assert harness.stopped_because == "sessions_ended"  # the client's DELETE, not the end of linger_s
    assert not [w for w in warnings if "termination" in w.lower()], warnings
    r = result(out)
    assert r["termination"]["reason"] == "done" and r["video"]["frames"] == rendered[0]
    assert [e["tool"] for e in events(out) if e["kind"] == "call"] == ["set_gripper", "done"]
