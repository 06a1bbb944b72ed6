"""Entry point of the MCP harness (group ``cab``): harnesses ``mcp``, ``claude_code``, ``codex``.

The MCP SDK is imported only when a harness is created, so listing plugins stays cheap and a
missing SDK fails with the install command."""
from __future__ import annotations

import importlib.util

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook
from cab_core.errors import MissingDependency


def _require_sdk() -> None:
    """The SDK is found, not imported: a sweep's plan creates each harness to check its models, and
    importing the MCP SDK costs seconds (the harness's own modules import it when it runs)."""
    if any(importlib.util.find_spec(name) is None for name in ("mcp", "uvicorn")):  # pragma: no cover
        raise MissingDependency("the MCP Python SDK", "pip install 'mcp>=2.3,<3' uvicorn")


def create_mcp(cfg: dict | None = None):
    _require_sdk()
    # here and below, not at the top: cab loads every plugin at start-up, and the harness with the
    # MCP SDK costs 7.3 s (python -X importtime on top of cab_core.plugins, 2026-11-27)
    from .harness import McpHarness

    return McpHarness(cfg)


create_mcp.speaks_on_stdio = True  # cab reserves stdout for MCP frames (unless harness.transport=http)


def create_claude_code(cfg: dict | None = None):
    _require_sdk()
    from .launchers import ClaudeCodeLauncher

    return ClaudeCodeLauncher(cfg)


def create_codex(cfg: dict | None = None):
    _require_sdk()
    from .launchers import CodexLauncher

    return CodexLauncher(cfg)


#: the keys of a model configuration each harness reads (cab refuses any other under ``model.``):
#: an MCP client names itself (model.name); a vendor CLI is launched with its model and settings
_RECORDED = {"pricing", "paper_usage", "limits"}
create_mcp.config_keys = frozenset(_RECORDED)
create_claude_code.config_keys = frozenset(_RECORDED | {"model_id", "effort", "api_key_env", "base_url", "vendor"})
create_codex.config_keys = frozenset(_RECORDED | {"model_id", "reasoning_effort", "api_key_env", "base_url", "vendor"})


@hookimpl
def cab_harnesses():
    return {"mcp": create_mcp, "claude_code": create_claude_code, "codex": create_codex}


cab_config_dirs = config_dirs_hook("cab_harness_mcp")
