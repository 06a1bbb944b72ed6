"""Vendor launchers and MCP harness settings, without a simulator: the command lines Claude Code
and Codex CLI are started with, the checks made before any simulator starts, and the usage read
back from each vendor's JSON stream. (tests/test_vendor_cli.py runs the real CLIs.)"""
from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

pytest.importorskip("mcp")

from cab_core.errors import ConfigError, MissingDependency  # noqa: E402
from cab_core.plugins import create  # noqa: E402
from cab_harness_mcp.harness import McpSettings  # noqa: E402
from cab_harness_mcp.launchers import TOKEN_ENV, ClaudeCodeLauncher, CodexLauncher  # noqa: E402
from cab_harness_mcp.transport import HttpServerThread  # noqa: E402

CONF = Path(__file__).resolve().parents[1] / "plugins" / "harness_mcp" / "cab_harness_mcp" / "conf" / "model"


def model_cfg(name: str) -> dict:
    import yaml

    return yaml.safe_load((CONF / f"{name}.yaml").read_text())


def fake_cli(tmp_path: Path, name: str, version_line: str) -> Path:
    """An executable that only answers --version (the launcher's pre-flight reads nothing else)."""
    d = tmp_path / "bin"
    d.mkdir(exist_ok=True)
    exe = d / name
    exe.write_text(f"#!/bin/sh\necho '{version_line}'\n")
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    return d


@pytest.mark.parametrize("cfg, message", [
    ({"transport": "sse"}, "transport must be stdio or http"),
    ({"port": 70000}, "port must be an integer"),
    ({"idle_timeout_s": 0}, "idle_timeout_s must be positive"),
    ({"linger_s": -1}, "linger_s must be a non-negative"),
    ({"colour": "blue"}, "unknown option(s) ['colour']"),
])
def test_settings_refuse_bad_values(cfg, message):
    with pytest.raises(ConfigError) as e:
        McpSettings.from_cfg({"name": "mcp", **cfg})
    assert message in str(e.value)


def test_http_listens_on_loopback_only():
    server = object()
    with pytest.raises(ConfigError, match="loopback only"):
        HttpServerThread(server, "0.0.0.0", 0, True, None)
    t = HttpServerThread(server, "127.0.0.1", 0, True, None)
    try:
        assert t.url == f"http://127.0.0.1:{t.port}/mcp" and t.port > 0 and len(t.token) >= 24
    finally:
        t._sock.close()


def test_harnesses_are_registered_plugins():
    assert type(create("harnesses", "mcp", {"name": "mcp"})).__name__ == "McpHarness"
    assert isinstance(create("harnesses", "claude_code", {"name": "claude_code"}), ClaudeCodeLauncher)
    assert isinstance(create("harnesses", "codex", {"name": "codex"}), CodexLauncher)
    with pytest.raises(ConfigError, match="serves its CLI over http"):
        ClaudeCodeLauncher({"transport": "stdio"})


def test_missing_cli_names_the_install_command(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(MissingDependency) as e:
        ClaudeCodeLauncher({}).preflight(model_cfg("opus5_claude_code"))
    assert "npm install -g @anthropic-ai/claude-code@2.1.212" in str(e.value)
    with pytest.raises(MissingDependency) as e:
        CodexLauncher({}).preflight(model_cfg("astra_codex"))
    assert "npm install -g @openai/codex@0.154.0" in str(e.value)


def test_pinned_version_and_key_are_checked_before_the_simulator(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", f"{fake_cli(tmp_path, 'claude', '2.0.1 (Claude Code)')}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-test")
    with pytest.raises(ConfigError, match=r"claude_code 2\.0\.1 is installed but the configuration pins 2\.1\.212"):
        ClaudeCodeLauncher({}).preflight(model_cfg("opus5_claude_code"))
    cfg = model_cfg("opus5_claude_code")
    cfg["vendor"]["version"] = None  # any version accepted, and recorded
    launcher = ClaudeCodeLauncher({})
    launcher.preflight(cfg)
    assert launcher.version == "2.0.1"
    monkeypatch.delenv("ANTHROPIC_API_KEY")
    with pytest.raises(ConfigError, match="ANTHROPIC_API_KEY"):
        ClaudeCodeLauncher({}).preflight(cfg)


@pytest.fixture
def served(tmp_path):
    t = HttpServerThread(object(), "127.0.0.1", 0, True, None)
    yield t
    t._sock.close()


def test_claude_code_command_line(tmp_path, monkeypatch, served):
    monkeypatch.setenv("PATH", f"{fake_cli(tmp_path, 'claude', '2.1.212 (Claude Code)')}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("ANTHROPIC_API_KEY", "sk-test")
    monkeypatch.delenv("ANTHROPIC_BASE_URL", raising=False)
    launcher = ClaudeCodeLauncher({})
    launcher.preflight(model_cfg("opus5_claude_code"))
    launcher.task_prompt = "TASK PROMPT"
    launcher._out = tmp_path
    argv = launcher.command(served, tmp_path / "work")
    assert argv[1:3] == ["-p", "TASK PROMPT"]
    opt = {argv[i]: argv[i + 1] for i in range(1, len(argv) - 1) if argv[i].startswith("--")}
    assert opt["--output-format"] == "stream-json" and "--verbose" in argv
    assert "--strict-mcp-config" in argv and "--no-session-persistence" in argv
    # the benchmark's tools allowed; of the built-ins only ToolSearch (it loads deferred tool definitions)
    assert opt["--allowedTools"] == "mcp__cab" and opt["--tools"] == "ToolSearch"
    assert "--disallowedTools" not in argv
    assert opt["--model"] == "claude-opus-5" and opt["--effort"] == "high"
    config_file = Path(opt["--mcp-config"])
    assert oct(config_file.stat().st_mode & 0o777) == "0o600"
    server = json.loads(config_file.read_text())["mcpServers"]["cab"]
    assert server == {"type": "http", "url": served.url, "headers": {"Authorization": f"Bearer {served.token}"}}
    env = launcher.env(served)
    # time-outs above the longest call: run_code's 180 s sandbox limit
    assert int(env["MCP_TOOL_TIMEOUT"]) == 610_000 and int(env["MCP_TIMEOUT"]) == 120_000
    assert env["DISABLE_AUTOUPDATER"] == "1" and env["CLAUDE_CODE_DISABLE_NONESSENTIAL_TRAFFIC"] == "1"
    assert "ANTHROPIC_BASE_URL" not in env  # Claude Code's default endpoint


@pytest.mark.parametrize("launcher_cls, env_var, version", [
    (ClaudeCodeLauncher, "ANTHROPIC_BASE_URL", "2.1.212 (Claude Code)"),
    (CodexLauncher, "OPENAI_BASE_URL", "codex-cli 0.154.0"),
])
def test_base_url_from_the_model_config_else_the_provider_variable(tmp_path, monkeypatch, served, launcher_cls,
                                                                   env_var, version):
    name = launcher_cls.default_command
    monkeypatch.setenv("PATH", f"{fake_cli(tmp_path, name, version)}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv(launcher_cls.default_api_key_env, "sk-test")
    monkeypatch.setenv(env_var, "http://127.0.0.1:9/from-env")
    cfg = model_cfg("opus5_claude_code" if name == "claude" else "astra_codex")
    launcher = launcher_cls({})
    launcher.preflight(cfg)
    assert launcher.base_url() == "http://127.0.0.1:9/from-env"
    cfg["base_url"] = "http://127.0.0.1:9/from-config"
    launcher.preflight(cfg)
    assert launcher.base_url() == "http://127.0.0.1:9/from-config"
    launcher.task_prompt, launcher._out = "TASK PROMPT", tmp_path
    argv, env = launcher.command(served, tmp_path / "work"), launcher.env(served)
    if launcher_cls is ClaudeCodeLauncher:
        assert env["ANTHROPIC_BASE_URL"] == "http://127.0.0.1:9/from-config"
    else:  # Codex 0.154 ignores OPENAI_BASE_URL: the launcher passes the URL as a config override
        assert 'openai_base_url="http://127.0.0.1:9/from-config"' in argv


def test_codex_command_line(tmp_path, monkeypatch, served):
    monkeypatch.setenv("PATH", f"{fake_cli(tmp_path, 'codex', 'codex-cli 0.154.0')}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    monkeypatch.delenv("OPENAI_BASE_URL", raising=False)
    monkeypatch.delenv("CODEX_API_KEY", raising=False)
    launcher = CodexLauncher({})
    launcher.preflight(model_cfg("astra_codex"))
    launcher.task_prompt = "TASK PROMPT"
    work = tmp_path / "work"
    argv = launcher.command(served, work)
    assert argv[1:3] == ["exec", "--json"] and argv[-1] == "TASK PROMPT"
    assert "--skip-git-repo-check" in argv and "--ignore-user-config" in argv
    assert argv[argv.index("--sandbox") + 1] == "read-only" and argv[argv.index("--cd") + 1] == str(work)
    assert argv[argv.index("--model") + 1] == "gpt-6-astra"
    overrides = dict(argv[i + 1].split("=", 1) for i, a in enumerate(argv) if a == "-c")
    assert overrides == {
        "mcp_servers.cab.url": json.dumps(served.url),
        "mcp_servers.cab.bearer_token_env_var": json.dumps(TOKEN_ENV),
        "mcp_servers.cab.startup_timeout_sec": "120",
        "mcp_servers.cab.tool_timeout_sec": "610",
        "web_search": '"disabled"',
        "model_reasoning_effort": '"high"',
    }
    env = launcher.env(served)
    assert env[TOKEN_ENV] == served.token
    assert env["CODEX_API_KEY"] == "sk-test"  # codex exec reads its key from CODEX_API_KEY only


def test_usage_from_the_vendor_streams(tmp_path):
    claude = tmp_path / "claude.jsonl"
    claude.write_text("\n".join(json.dumps(e) for e in [
        {"type": "system", "subtype": "init"},
        {"type": "assistant", "message": {"content": []}},
        {"type": "result", "subtype": "success", "is_error": False, "num_turns": 4, "duration_ms": 81234,
         "total_cost_usd": 0.4321, "usage": {"input_tokens": 1200, "output_tokens": 3400,
                                             "cache_read_input_tokens": 50000, "cache_creation_input_tokens": 7000}},
    ]) + "\nnot json\n")
    u = ClaudeCodeLauncher({}).usage(claude)
    assert u == {"complete": True, "input_tokens": 1200, "output_tokens": 3400, "cache_read_tokens": 50000,
                 "cache_write_tokens": 7000, "usd": 0.4321, "turns": 4, "duration_s": 81.234,
                 "is_error": False, "subtype": "success"}
    codex = tmp_path / "codex.jsonl"
    codex.write_text("\n".join(json.dumps(e) for e in [
        {"type": "thread.started"},
        {"type": "turn.completed", "usage": {"input_tokens": 1000, "cached_input_tokens": 600, "output_tokens": 90,
                                             "reasoning_output_tokens": 40}},
        {"type": "turn.completed", "usage": {"input_tokens": 2000, "cached_input_tokens": 1500,
                                             "cache_write_input_tokens": 200, "output_tokens": 10}},
    ]))
    assert CodexLauncher({}).usage(codex) == {"complete": True, "input_tokens": 700, "output_tokens": 100,
                                              "cache_read_tokens": 2100, "cache_write_tokens": 200,
                                              "reasoning_tokens": 40, "usd": None, "turns": 2}
    assert CodexLauncher({}).usage(tmp_path / "missing.jsonl") == {"complete": False}
