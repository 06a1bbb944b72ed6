"""``cab-mcp-script``: drive an attempt served over MCP with a fixed list of tool calls, through
the official MCP Python client. It checks a set-up end to end without a model (the calls of a
recorded attempt, e.g. an oracle's, replay the same physics on the same seed), and it is how the
tests act as an MCP client.

    cab-mcp-script calls.jsonl -- cab +harness=mcp task=beat_block_hammer hydra.run.dir=out
    cab-mcp-script calls.jsonl --endpoint out/mcp_endpoint.json

``calls.jsonl`` holds ``{"tool": name, "args": {...}}`` items (JSON list or JSON lines), the format
of the ``scripted`` agent; :func:`calls_from_events` extracts them from a recorded ``events.jsonl``.
"""
from __future__ import annotations

import argparse
import json
import sys
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path

import anyio


@dataclass
class CallOutcome:
    tool: str
    payload: dict
    is_error: bool
    images: int


@dataclass
class ScriptRun:
    tools: list[dict] = field(default_factory=list)
    instructions: str | None = None
    outcomes: list[CallOutcome] = field(default_factory=list)


def load_calls(path: str | Path) -> list[dict]:
    text = Path(path).read_text()
    items = json.loads(text) if text.lstrip().startswith("[") else [json.loads(line) for line in text.splitlines() if line.strip()]
    for i, it in enumerate(items):
        if not isinstance(it, dict) or "tool" not in it:
            raise ValueError(f"{path}: item {i} must be an object with a 'tool' key")
    return items


def calls_from_events(events_path: str | Path) -> list[dict]:
    """The agent's direct calls, in order, from a recorded ``events.jsonl``."""
    calls = []
    for line in Path(events_path).read_text().splitlines():
        e = json.loads(line)
        if e.get("kind") == "call":
            calls.append({"tool": e["tool"], "args": e.get("arguments") or {}})
    return calls


@asynccontextmanager
async def connect(command: list[str] | None = None, url: str | None = None, headers: dict | None = None,
                  env: dict | None = None, cwd: str | None = None, client_info: tuple[str, str] | None = None):
    """An initialised ``ClientSession`` over stdio (spawning ``command``) or streamable HTTP;
    ``client_info``: the (name, version) it gives in its handshake (default: the SDK's own)."""
    from mcp import ClientSession
    from mcp_types import Implementation

    if command:
        from mcp.client.stdio import StdioServerParameters, stdio_client

        params = StdioServerParameters(command=command[0], args=command[1:], env=env, cwd=cwd)
        transport = stdio_client(params)
    else:
        from mcp.client.streamable_http import streamable_http_client
        from mcp.shared._httpx_utils import create_mcp_http_client

        transport = streamable_http_client(url, http_client=create_mcp_http_client(headers=headers or {}))
    async with transport as streams:
        read, write = streams[0], streams[1]
        info = Implementation(name=client_info[0], version=client_info[1]) if client_info else None
        async with ClientSession(read, write, client_info=info) as session:
            await session.initialize()
            yield session


def outcome(tool: str, result) -> CallOutcome:
    texts = [c.text for c in result.content if getattr(c, "type", None) == "text"]
    try:
        payload = json.loads(texts[0]) if texts else {}
    except json.JSONDecodeError:
        payload = {"text": texts[0]}
    images = sum(1 for c in result.content if getattr(c, "type", None) == "image")
    return CallOutcome(tool, payload, bool(result.is_error), images)


async def run_script(session, calls: list[dict], stop_after: int | None = None) -> ScriptRun:
    """List the tools, then make ``calls`` in order until ``done``, an ended attempt or ``stop_after``."""
    run = ScriptRun(instructions=session.instructions)
    listed = await session.list_tools()
    run.tools = [t.model_dump(by_alias=True, exclude_none=True) for t in listed.tools]
    for i, c in enumerate(calls):
        if stop_after is not None and i >= stop_after:
            break
        res = await session.call_tool(c["tool"], c.get("args") or {})
        o = outcome(c["tool"], res)
        run.outcomes.append(o)
        if c["tool"] == "done" and not o.is_error or o.payload.get("attempt_ended"):
            break
    return run


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = None
    if "--" in argv:
        k = argv.index("--")
        argv, command = argv[:k], argv[k + 1:]
    ap = argparse.ArgumentParser(prog="cab-mcp-script", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("calls", help="JSON/JSONL file of {tool, args} items, or a recorded events.jsonl")
    ap.add_argument("--endpoint", help="mcp_endpoint.json of an attempt served with harness.transport=http")
    ap.add_argument("--stop-after", type=int, default=None, help="disconnect after this many calls")
    a = ap.parse_args(argv)
    if bool(command) == bool(a.endpoint):
        ap.error("give either a server command after '--' or --endpoint")
    calls = calls_from_events(a.calls) if Path(a.calls).name == "events.jsonl" else load_calls(a.calls)
    url = headers = None
    if a.endpoint:
        ep = json.loads(Path(a.endpoint).read_text())
        url, headers = ep["url"], ep.get("headers") or {}

    async def go():
        async with connect(command, url, headers) as session:
            return await run_script(session, calls, a.stop_after)

    run = anyio.run(go)
    for o in run.outcomes:
        print(json.dumps({"tool": o.tool, "is_error": o.is_error, "images": o.images, "payload": o.payload},
                         default=str))
    last = run.outcomes[-1] if run.outcomes else None
    sys.exit(0 if last is not None and last.tool == "done" and not last.is_error else 1)


if __name__ == "__main__":  # pragma: no cover
    main()
