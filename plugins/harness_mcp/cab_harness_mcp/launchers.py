"""Vendor harnesses: Claude Code and Codex CLI run headless as the agent of one attempt.

The attempt is served over streamable HTTP on loopback (:class:`.harness.McpHarness`), and the
vendor CLI is started as a child process pointed at it, with only the benchmark's tools allowed:

- Claude Code: an MCP config file, ``--strict-mcp-config`` (no other MCP server), ``--allowedTools
  mcp__cab`` and its built-in file, shell, web and delegation tools disallowed, no session
  persistence (paper, "Vendor harnesses").
- Codex CLI: ``codex exec`` with ``-c mcp_servers.cab.*`` overrides (user config ignored), a
  read-only sandbox, web search off, and start-up and tool time-outs above the longest motion.

Both run in an empty scratch directory inside the attempt's records, so neither can read the
benchmark's source from its working directory (a machine-wide isolation still needs a container;
the paper's "repository-free read-only containers"). The vendor's own stream (JSON lines) is kept as
``vendor_transcript.jsonl``, its usage summarised in ``vendor_usage.json`` and in the same
``model_usage_total`` event the reference harness writes, so reports treat both alike.

Vendor settings live in the model config under ``vendor:`` (conf/model/opus5_claude_code.yaml,
conf/model/astra_codex.yaml); the pinned CLI version is checked before any simulator starts.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

from cab_core.errors import ConfigError, MissingDependency

from .harness import McpHarness
from .transport import HttpServerThread

TRANSCRIPT = "vendor_transcript.jsonl"
USAGE = "vendor_usage.json"
STDERR = "vendor_stderr.log"
TOKEN_ENV = "CAB_MCP_TOKEN"

# Claude Code's built-in tools that the evaluation disables (file, shell, web, delegation).
CLAUDE_BUILTINS = ("Bash", "BashOutput", "KillShell", "Edit", "MultiEdit", "Write", "Read", "Glob", "Grep", "LS",
                   "NotebookEdit", "NotebookRead", "WebFetch", "WebSearch", "Task", "Agent", "TodoWrite",
                   "ExitPlanMode", "SlashCommand", "Skill")


class VendorLauncher(McpHarness):
    """Common life cycle: check the CLI, serve over HTTP, start the CLI, collect its records."""

    vendor = "vendor"
    default_command = ""
    install_hint = ""
    default_api_key_env: str | None = None

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

    # -- the vendor process -------------------------------------------------------------------
    def command(self, transport: HttpServerThread, workdir: Path) -> list[str]:  # pragma: no cover - abstract
        raise NotImplementedError

    def env(self, transport: HttpServerThread) -> dict[str, str]:
        env = dict(os.environ)
        env.update({str(k): str(v) for k, v in (self.vcfg.get("env") or {}).items()})
        if transport.token:
            env[TOKEN_ENV] = transport.token
        return env

    def on_serving(self, episode, transport) -> None:
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

    def before_finish(self, episode) -> None:
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
            from cab_harness_reference.pricing import cost
            from cab_harness_reference.types import Usage

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

    def command(self, transport: HttpServerThread, workdir: Path) -> list[str]:
        headers = {"Authorization": f"Bearer {transport.token}"} if transport.token else {}
        config = {"mcpServers": {"cab": {"type": "http", "url": transport.url, "headers": headers}}}
        path = self._out / "vendor_mcp_config.json"
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            json.dump(config, f, indent=2)
        v = self.vcfg
        argv = [shutil.which(v["command"]) or v["command"], "-p", self.task_prompt,
                "--output-format", "stream-json", "--verbose",
                "--mcp-config", str(path), "--strict-mcp-config",
                "--allowedTools", "mcp__cab", "--disallowedTools", ",".join(CLAUDE_BUILTINS),
                "--no-session-persistence"]
        if self.model_cfg.get("model_id"):
            argv += ["--model", str(self.model_cfg["model_id"])]
        if self.model_cfg.get("effort"):
            argv += ["--effort", str(self.model_cfg["effort"])]
        return argv + list(v["extra_args"])

    def env(self, transport: HttpServerThread) -> dict[str, str]:
        env = super().env(transport)
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
        argv = [shutil.which(v["command"]) or v["command"], "exec", "--json", "--skip-git-repo-check",
                "--ignore-user-config", "--sandbox", "read-only", "--cd", str(workdir)]
        if self.model_cfg.get("model_id"):
            argv += ["--model", str(self.model_cfg["model_id"])]
        for k, val in cfg.items():
            argv += ["-c", f"{k}={val}"]
        return argv + list(v["extra_args"]) + [self.task_prompt]

    def usage(self, transcript: Path) -> dict:
        """Summed over the stream's ``turn.completed`` events."""
        turns = [e for e in self.events(transcript) if e.get("type") == "turn.completed"]
        if not turns:
            return {"complete": False}
        tot = {"input_tokens": 0, "output_tokens": 0, "cache_read_tokens": 0, "reasoning_tokens": 0}
        for e in turns:
            u = e.get("usage") or {}
            cached = int(u.get("cached_input_tokens") or 0)
            tot["input_tokens"] += int(u.get("input_tokens") or 0) - cached
            tot["cache_read_tokens"] += cached
            tot["output_tokens"] += int(u.get("output_tokens") or 0)
            tot["reasoning_tokens"] += int(u.get("reasoning_output_tokens") or 0)
        return {"complete": True, **tot, "usd": None, "turns": len(turns)}
