"""Vendor harnesses: Claude Code and Codex CLI run headless as the agent of one attempt.

The attempt is served over streamable HTTP on loopback (:class:`.harness.McpHarness`), and the
vendor CLI is started as a child process pointed at it, with only the benchmark's tools allowed
(paper, "Vendor harnesses"):

- Claude Code: ``claude -p`` with an MCP config file, ``--strict-mcp-config`` (no other MCP
  server), ``--allowedTools mcp__cab`` (the benchmark's tools run without asking), ``--tools
  ToolSearch`` (every other built-in tool gone), no session persistence.
- Codex CLI: ``codex exec`` with ``-c mcp_servers.cab.*`` overrides (user config ignored), a
  read-only sandbox, web search off, and start-up and tool time-outs above the longest motion.

Both run in an empty scratch directory inside the attempt's records, so neither can read the
benchmark's source from its working directory (a machine-wide isolation still needs a container;
the paper's "repository-free read-only containers"). The vendor's own stream (JSON lines) is kept as
``vendor_transcript.jsonl``, its usage summarised in ``vendor_usage.json`` and in the same
``model_usage_total`` event the reference harness writes, so reports treat both alike.

Vendor settings live in the model config under ``vendor:`` (conf/model/opus5_claude_code.yaml,
conf/model/astra_codex.yaml); the pinned CLI version is checked before any simulator starts. The
model API's address is ``model.base_url``, else the provider's variable (``ANTHROPIC_BASE_URL``,
``OPENAI_BASE_URL``), else the CLI's default, as for the reference harness's providers.

Verified with the real CLIs (tests/test_vendor_cli.py: a full attempt each, against a local model
server speaking the provider's streaming wire format):

- Claude Code 2.1.212: every flag above is accepted; the model sees exactly the 31 ``mcp__cab__*``
  tools. The guessed deny list of built-ins left 13 (Cron*, Task*, Workflow, SendMessage,
  EnterWorktree, ...), hence the allow list ``--tools``. ``--tools ""`` would also drop ToolSearch,
  which Claude Code needs when it defers MCP tools (the paper's runs used it): with
  ``ENABLE_TOOL_SEARCH=true`` the first request then carried no tool at all (4 runs of 4), where
  ``--tools ToolSearch`` gave ToolSearch (against a local endpoint Claude Code then drops tool
  search and lists the MCP tools; it also sent the first request without tools in 4 runs of 13, so
  that mode is not under test). Tool results reach the model as text + image blocks; ``result``
  in the stream carries summed usage and Claude Code's own cost.
- Codex CLI 0.154.0: the overrides and flags above are accepted. Two differences from the
  documentation the launcher was first written from: the key must be in ``CODEX_API_KEY`` (with only
  ``OPENAI_API_KEY`` set, requests go out without one), and ``OPENAI_BASE_URL`` is ignored (the
  config key ``openai_base_url`` works). For gpt-6-astra Codex runs in code mode: the model's tools
  are ``exec`` (JavaScript that calls nested tools), ``wait``, ``request_user_input[_async]``,
  ``sleep`` and the multi-agent tools; the benchmark's tools are nested in ``exec`` as
  ``tools.mcp__cab__<name>`` beside ``exec_command``, ``apply_patch``, ``view_image``, goals and MCP
  resources, and are listed to the model only through ``ALL_TOOLS``. The request shows the
  read-only sandbox (``sandbox_mode`` in the turn metadata, read-only filesystem permissions), and
  the shell keeps to it (a write fails with "Read-only file system"); with ``CODEX_HOME`` inside
  the system's temporary directory, Codex sets up no sandbox helper and every shell command fails.
  It tries the Responses API over WebSocket first and falls back to HTTP streaming. Usage comes
  from ``turn.completed`` (summed over the turn's requests), without cost.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

from cab_core.contracts.harness import ModelCheck
from cab_core.errors import ConfigError, MissingDependency
from cab_core.kits.harness.pricing import Usage, cost

from .harness import McpHarness, write_private_json
from .transport import HttpServerThread

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.harness import AttemptSession

TRANSCRIPT = "vendor_transcript.jsonl"
USAGE = "vendor_usage.json"
STDERR = "vendor_stderr.log"
TOKEN_ENV = "CAB_MCP_TOKEN"

# The only Claude Code built-in tool kept (``--tools``): it loads tool definitions when Claude Code
# defers them (paper, "Vendor harnesses"); every file, shell, web, delegation, task and scheduling
# tool is left out. A deny list misses the built-ins it does not name (2.1.212 also has Cron*,
# Workflow, SendMessage, ...), and ``--tools ""`` leaves deferred MCP tools unreachable.
CLAUDE_TOOLS = ("ToolSearch",)
# Claude Code settings (environment) for a reproducible headless run: no update in the middle of
# a sweep, no telemetry, error reporting or other traffic beside the model's requests.
CLAUDE_ENV = {"DISABLE_AUTOUPDATER": "1", "CLAUDE_CODE_DISABLE_NONESSENTIAL_TRAFFIC": "1"}


class VendorLauncher(McpHarness):
    """Common life cycle: check the CLI, serve over HTTP, start the CLI, collect its records."""

    vendor = "vendor"
    default_command = ""
    install_hint = ""
    default_api_key_env: str | None = None
    base_url_env: str | None = None

    def __init__(self, cfg: dict | None = None):
        cfg = dict(cfg or {})
        cfg.setdefault("transport", "http")
        cfg.setdefault("linger_s", 0.0)
        super().__init__(cfg)
        if self.settings.transport != "http":
            raise ConfigError(f"harness={cfg.get('name', self.vendor)} serves its CLI over http; "
                              f"transport={self.settings.transport!r} is not supported")
        self.proc: subprocess.Popen | None = None
        self.vcfg: dict = {}
        self.version: str | None = None
        self._out: Path | None = None
        self._files: list = []

    # -- configuration ------------------------------------------------------------------------
    def _vendor_cfg(self, model_cfg: dict) -> dict:
        v = dict(model_cfg.get("vendor") or {})
        v.setdefault("command", self.default_command)
        v.setdefault("version", None)
        v.setdefault("api_key_env", model_cfg.get("api_key_env", self.default_api_key_env))
        v.setdefault("exit_grace_s", 120.0)
        v.setdefault("tool_timeout_s", 610.0)
        v.setdefault("startup_timeout_s", 120.0)
        v.setdefault("extra_args", [])
        v.setdefault("env", {})
        if not isinstance(v["extra_args"], list) or not all(isinstance(a, str) for a in v["extra_args"]):
            raise ConfigError("model.vendor.extra_args must be a list of strings")
        return v

    def preflight(self, model_cfg: dict) -> None:
        """The CLI exists, has the pinned version, and its key is set: before any simulator starts."""
        super().preflight(model_cfg)
        self.vcfg = v = self._vendor_cfg(model_cfg)
        exe = shutil.which(v["command"])
        if exe is None:
            raise MissingDependency(f"{self.vendor} ({v['command']!r} not found on PATH)", self.install_hint)
        try:
            out = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.TimeoutExpired) as e:
            raise ConfigError(f"{v['command']} --version failed: {e}") from e
        m = re.search(r"\d+\.\d+\.\d+", out.stdout + out.stderr)
        self.version = m.group(0) if m else (out.stdout or out.stderr).strip()[:80]
        if v["version"] and self.version != str(v["version"]):
            raise ConfigError(f"{self.vendor} {self.version} is installed but the configuration pins "
                              f"{v['version']} (model.vendor.version); install it with: {self.install_hint}, "
                              "or set model.vendor.version=null to run another version")
        key = v.get("api_key_env")
        if key and not os.environ.get(key):
            raise ConfigError(f"{self.vendor} needs the environment variable {key} (model.vendor.api_key_env)")
        self.model_cfg = model_cfg

    def check_model(self, model_cfg: dict, network: bool = True) -> ModelCheck:
        """Before a sweep: the CLI is on PATH and its key is set (its version and its endpoint are the
        CLI's to check when an attempt starts it: ``preflight``)."""
        try:
            v = self._vendor_cfg(model_cfg)
        except ConfigError as e:
            return ModelCheck(provider=self.vendor, problems=[str(e)])
        key = v.get("api_key_env")
        check = ModelCheck(provider=self.vendor, key_env=key, key_present=bool(os.environ.get(key)) if key else None,
                           endpoint=model_cfg.get("base_url") or (os.environ.get(self.base_url_env)
                                                                   if self.base_url_env else None))
        if shutil.which(v["command"]) is None:
            check.problems.append(f"{self.vendor} ({v['command']!r}) is not on PATH: install it with: {self.install_hint}")
        if check.key_present is False:
            check.problems.append(f"{self.vendor} needs the environment variable {key} (model.vendor.api_key_env)")
        return check

    def base_url(self) -> str | None:
        """The model API's base URL: ``model.base_url``, else the provider's environment variable,
        else None (the CLI's default endpoint); the reference harness's providers read the same."""
        return self.model_cfg.get("base_url") or (os.environ.get(self.base_url_env) if self.base_url_env else None)

    # -- the vendor process -------------------------------------------------------------------
    def command(self, transport: HttpServerThread, workdir: Path) -> list[str]:  # pragma: no cover - abstract
        raise NotImplementedError

    def env(self, transport: HttpServerThread) -> dict[str, str]:
        env = dict(os.environ)
        env.update({str(k): str(v) for k, v in (self.vcfg.get("env") or {}).items()})
        if transport.token:
            env[TOKEN_ENV] = transport.token
        return env

    def on_serving(self, episode: AttemptSession, transport) -> None:
        self._out = out = Path(episode.out)
        workdir = out / "vendor_workdir"
        workdir.mkdir(exist_ok=True)
        argv = self.command(transport, workdir)
        stdout = open(out / TRANSCRIPT, "wb")
        stderr = open(out / STDERR, "wb")
        self._files = [stdout, stderr]
        shown = [a if a != self.task_prompt else "<task prompt>" for a in argv]
        episode.recorder.event("vendor_start", vendor=self.vendor, version=self.version, argv=shown,
                               model=self.model_cfg.get("model_id"), workdir=workdir.name)
        self.proc = subprocess.Popen(argv, cwd=workdir, env=self.env(transport), stdin=subprocess.DEVNULL,
                                     stdout=stdout, stderr=stderr, start_new_session=True)

    def agent_gone(self) -> str | None:
        if self.proc is not None and self.proc.poll() is not None:
            return f"{self.vendor} exited (code {self.proc.returncode}) without calling done"
        return None

    def ready_to_finish(self, ended_for_s: float) -> bool:
        return self.proc is None or self.proc.poll() is not None or ended_for_s >= float(self.vcfg["exit_grace_s"])

    def _terminate(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        for sig, wait in ((signal.SIGTERM, 10), (signal.SIGKILL, 10)):
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                return
            try:
                self.proc.wait(wait)
                return
            except subprocess.TimeoutExpired:
                continue

    def before_finish(self, episode: AttemptSession) -> None:
        self._terminate()
        for f in self._files:
            f.close()
        usage = self.usage(self._out / TRANSCRIPT)
        usage["exit_code"] = None if self.proc is None else self.proc.returncode
        (self._out / USAGE).write_text(json.dumps(usage, indent=2))
        episode.recorder.event("vendor_exit", vendor=self.vendor, exit_code=usage["exit_code"])
        totals = {k: usage.get(k, 0) for k in ("input_tokens", "output_tokens", "reasoning_tokens",
                                                 "cache_read_tokens", "cache_write_tokens")}
        usd = usage.get("usd")
        if usd is None:
            usd = cost(Usage(**totals), self.model_cfg.get("pricing")).get("usd")
        episode.recorder.event("model_usage_total", **totals, usd=usd, waited_s=0.0,
                               latency_s=usage.get("duration_s", 0.0), turns=usage.get("turns", 0),
                               source=self.vendor)

    def on_stop(self) -> None:
        self._terminate()
        for f in self._files:
            if not f.closed:
                f.close()

    # -- transcript -----------------------------------------------------------------------------
    @staticmethod
    def events(path: Path) -> list[dict]:
        out = []
        if path.exists():
            for line in path.read_text(errors="replace").splitlines():
                try:
                    e = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if isinstance(e, dict):
                    out.append(e)
        return out

    def usage(self, transcript: Path) -> dict:  # pragma: no cover - abstract
        raise NotImplementedError


class ClaudeCodeLauncher(VendorLauncher):
    """``harness=claude_code``: ``claude -p`` with the attempt as its only MCP server."""

    vendor = "claude_code"
    default_command = "claude"
    install_hint = "npm install -g @anthropic-ai/claude-code@2.1.212"
    default_api_key_env = "ANTHROPIC_API_KEY"
    base_url_env = "ANTHROPIC_BASE_URL"

    def command(self, transport: HttpServerThread, workdir: Path) -> list[str]:
        headers = {"Authorization": f"Bearer {transport.token}"} if transport.token else {}
        config = {"mcpServers": {"cab": {"type": "http", "url": transport.url, "headers": headers}}}
        path = self._out / "vendor_mcp_config.json"
        write_private_json(path, config)
        v = self.vcfg
        argv = [shutil.which(v["command"]) or v["command"], "-p", self.task_prompt,
                "--output-format", "stream-json", "--verbose",
                "--mcp-config", str(path), "--strict-mcp-config",
                "--allowedTools", "mcp__cab", "--tools", ",".join(CLAUDE_TOOLS),
                "--no-session-persistence"]
        if self.model_cfg.get("model_id"):
            argv += ["--model", str(self.model_cfg["model_id"])]
        if self.model_cfg.get("effort"):
            argv += ["--effort", str(self.model_cfg["effort"])]
        return argv + list(v["extra_args"])

    def env(self, transport: HttpServerThread) -> dict[str, str]:
        env = super().env(transport)
        for k, val in CLAUDE_ENV.items():
            env.setdefault(k, val)
        if self.base_url():
            env["ANTHROPIC_BASE_URL"] = self.base_url()
        # MCP start-up and per-call time-outs, in milliseconds, above the longest motion
        env.setdefault("MCP_TIMEOUT", str(int(float(self.vcfg["startup_timeout_s"]) * 1000)))
        env.setdefault("MCP_TOOL_TIMEOUT", str(int(float(self.vcfg["tool_timeout_s"]) * 1000)))
        return env

    def usage(self, transcript: Path) -> dict:
        """From the stream's final ``result`` event (usage, cost, turns, duration)."""
        result = next((e for e in reversed(self.events(transcript)) if e.get("type") == "result"), None)
        if result is None:
            return {"complete": False}
        u = result.get("usage") or {}
        return {"complete": True, "input_tokens": int(u.get("input_tokens") or 0),
                "output_tokens": int(u.get("output_tokens") or 0),
                "cache_read_tokens": int(u.get("cache_read_input_tokens") or 0),
                "cache_write_tokens": int(u.get("cache_creation_input_tokens") or 0),
                "usd": result.get("total_cost_usd"), "turns": int(result.get("num_turns") or 0),
                "duration_s": float(result.get("duration_ms") or 0) / 1000.0,
                "is_error": bool(result.get("is_error")), "subtype": result.get("subtype")}


class CodexLauncher(VendorLauncher):
    """``harness=codex``: ``codex exec --json`` with the attempt as its only MCP server."""

    vendor = "codex"
    default_command = "codex"
    install_hint = "npm install -g @openai/codex@0.154.0"
    default_api_key_env = "OPENAI_API_KEY"
    base_url_env = "OPENAI_BASE_URL"

    def command(self, transport: HttpServerThread, workdir: Path) -> list[str]:
        v = self.vcfg
        cfg = {
            "mcp_servers.cab.url": json.dumps(transport.url),
            "mcp_servers.cab.startup_timeout_sec": str(int(float(v["startup_timeout_s"]))),
            "mcp_servers.cab.tool_timeout_sec": str(int(float(v["tool_timeout_s"]))),
            "web_search": json.dumps("disabled"),
        }
        if transport.token:
            cfg["mcp_servers.cab.bearer_token_env_var"] = json.dumps(TOKEN_ENV)
        if self.model_cfg.get("reasoning_effort"):
            cfg["model_reasoning_effort"] = json.dumps(str(self.model_cfg["reasoning_effort"]))
        base_url = self.base_url()
        if base_url:
            cfg["openai_base_url"] = json.dumps(base_url)
        argv = [shutil.which(v["command"]) or v["command"], "exec", "--json", "--skip-git-repo-check",
                "--ignore-user-config", "--sandbox", "read-only", "--cd", str(workdir)]
        if self.model_cfg.get("model_id"):
            argv += ["--model", str(self.model_cfg["model_id"])]
        for k, val in cfg.items():
            argv += ["-c", f"{k}={val}"]
        return argv + list(v["extra_args"]) + [self.task_prompt]

    def env(self, transport: HttpServerThread) -> dict[str, str]:
        """``codex exec`` takes its API key from ``CODEX_API_KEY`` (0.154.0 sends no key taken from
        ``OPENAI_API_KEY``): the configured key variable is handed over under that name."""
        env = super().env(transport)
        key = self.vcfg.get("api_key_env")
        if key and os.environ.get(key):
            env["CODEX_API_KEY"] = os.environ[key]
        return env

    def usage(self, transcript: Path) -> dict:
        """Summed over the stream's ``turn.completed`` events."""
        turns = [e for e in self.events(transcript) if e.get("type") == "turn.completed"]
        if not turns:
            return {"complete": False}
        tot = {"input_tokens": 0, "output_tokens": 0, "cache_read_tokens": 0, "cache_write_tokens": 0,
               "reasoning_tokens": 0}
        for e in turns:
            u = e.get("usage") or {}
            cached = int(u.get("cached_input_tokens") or 0)
            written = int(u.get("cache_write_input_tokens") or 0)
            tot["input_tokens"] += int(u.get("input_tokens") or 0) - cached - written
            tot["cache_read_tokens"] += cached
            tot["cache_write_tokens"] += written
            tot["output_tokens"] += int(u.get("output_tokens") or 0)
            tot["reasoning_tokens"] += int(u.get("reasoning_output_tokens") or 0)
        return {"complete": True, **tot, "usd": None, "turns": len(turns)}
