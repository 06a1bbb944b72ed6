"""The MCP surface of one attempt: the tool list, tool results, the server object.

Everything here is built from the episode's own registry, so a client sees exactly the tools, names
and input schemas the reference harness gives a model (``Episode.tool_specs``). Results carry the
tool's JSON payload as text and the images the call produced as PNG image content, and never
``structuredContent`` (Claude Code drops the whole content array, images included, when a result
also has structured content; DESIGN.md)."""
from __future__ import annotations

import base64
import json
from typing import Any

import mcp_types as types
from mcp.server.lowlevel import Server
from mcp.shared.exceptions import MCPError

from cab_core.kits.harness.catalog import tool_catalog

from .bridge import CallBridge, SeenClient

SERVER_NAME = "cab"
# Claude Code loads MCP tool definitions lazily (ToolSearch) unless a tool asks to be always loaded;
# the benchmark's surface is small and every tool matters, so all are loaded up front.
ALWAYS_LOAD = {"anthropic/alwaysLoad": True}


def tool_list() -> list[types.Tool]:
    """The attempt's tools as MCP tools: the registry every episode is built from, so names,
    descriptions and input schemas are the reference harness's (``Episode.tool_specs``), with
    observation tools marked read-only and motion tools destructive."""
    tools = []
    for d in tool_catalog():
        spec = d.spec()
        tools.append(types.Tool(
            name=spec["name"], description=spec["description"], input_schema=spec["parameters"],
            annotations=types.ToolAnnotations(read_only_hint=bool(d.read_only), destructive_hint=bool(d.destructive),
                                              idempotent_hint=bool(d.read_only) and not d.advances_physics,
                                              open_world_hint=False),
            meta=dict(ALWAYS_LOAD)))
    return tools


def png_b64(png: bytes) -> str:
    return base64.b64encode(png).decode("ascii")


def tool_result(payload: dict, images: list[tuple[str, bytes]] = ()) -> types.CallToolResult:
    """Text (the JSON payload) plus one PNG per image, labelled by its observation id. A payload
    with an ``error`` is marked ``isError`` so clients show it as a failed call."""
    content: list[Any] = [types.TextContent(type="text", text=json.dumps(payload, default=str))]
    for obs_id, png in images:
        content.append(types.TextContent(type="text", text=f"[image {obs_id}]"))
        content.append(types.ImageContent(type="image", data=png_b64(png), mime_type="image/png"))
    return types.CallToolResult(content=content, is_error=bool(payload.get("error")))


def client_of(ctx) -> SeenClient | None:
    """The client's ``clientInfo`` (name, version) from its ``initialize`` handshake (or, on the
    handshake-less protocol, from the request's envelope), with the HTTP session it came in;
    None when the client gave none."""
    try:
        params = ctx.session.client_params
        info = params.client_info if params is not None else None
    except AttributeError:
        return None
    if info is None or not isinstance(getattr(info, "name", None), str):
        return None
    request = getattr(ctx, "request", None)  # the HTTP request (streamable HTTP); None on stdio
    headers = getattr(request, "headers", None)
    session = headers.get("mcp-session-id") if headers is not None else None
    return SeenClient(info.name, str(getattr(info, "version", "") or ""), session)


def instructions_text(system: str, instruction: str) -> str:
    """What a client is told at initialisation: the system prompt every harness gives (cab_core.kits.harness.prompts), then the task."""
    return f"{system}\n\n# Task\n{instruction}\n"


def build_server(tools: list[types.Tool], bridge: CallBridge, task_prompt: str, version: str) -> Server:
    """A low-level MCP server whose tool calls go through ``bridge`` to the attempt's owner thread.
    The task prompt is both its ``instructions`` and the prompt ``attempt`` (clients show prompts
    as commands). Each client identity is reported to the bridge when its handshake completes
    (``notifications/initialized``) and again with its requests (a client that skips the
    notification, or a handshake-less one, is still seen before its first call)."""
    by_name = {t.name: t for t in tools}

    async def initialized(ctx, params) -> None:  # the handshake is complete: note who the client is
        bridge.saw(client_of(ctx))
        bridge.touch()

    async def list_tools(ctx, params) -> types.ListToolsResult:
        bridge.saw(client_of(ctx))
        bridge.touch()
        return types.ListToolsResult(tools=tools)

    async def call_tool(ctx, params: types.CallToolRequestParams) -> types.CallToolResult:
        # An unknown name is still dispatched: the episode charges and records it like any invalid
        # call, as the reference harness does, and answers with a typed error payload.
        args = params.arguments if isinstance(params.arguments, dict) else {}
        return await bridge.call(params.name, dict(args), client_of(ctx))

    async def list_prompts(ctx, params) -> types.ListPromptsResult:
        bridge.saw(client_of(ctx))
        bridge.touch()
        return types.ListPromptsResult(prompts=[types.Prompt(
            name="attempt", description="The benchmark task of this attempt, with its rules and budgets")])

    async def get_prompt(ctx, params: types.GetPromptRequestParams) -> types.GetPromptResult:
        bridge.saw(client_of(ctx))
        bridge.touch()
        if params.name != "attempt":
            raise MCPError(code=types.INVALID_PARAMS, message=f"unknown prompt {params.name!r}; the only prompt is 'attempt'")
        return types.GetPromptResult(description="The benchmark task of this attempt", messages=[
            types.PromptMessage(role="user", content=types.TextContent(type="text", text=task_prompt))])

    server = Server(SERVER_NAME, version=version, title="cab robot API (one attempt)",
                    instructions=task_prompt, on_list_tools=list_tools, on_call_tool=call_tool,
                    on_list_prompts=list_prompts, on_get_prompt=get_prompt,
                    get_tool_input_schema=lambda name: by_name[name].input_schema if name in by_name else None)
    server.add_notification_handler("notifications/initialized", types.NotificationParams, initialized)
    return server
