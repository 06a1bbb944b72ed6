"""``harness=mcp``: serve one attempt to an MCP client.

The thread that built the attempt stays its only owner: it executes the calls the server queues
(:mod:`.bridge`), one at a time, and watches for the ways an attempt ends besides ``done`` and the
budgets, which the episode itself enforces:

- the client closes stdio (``client_disconnected``);
- no request for ``idle_timeout_s`` (``client_idle``; HTTP, where a client can vanish silently);
- the wall-clock budget runs out while the client is thinking (``wall_budget``);
- the operator interrupts cab (``interrupted``).

Whatever the ending, ``result.json`` is written at once (the verdict: ``done`` is answered right
after it); then the video is rendered from the attempt's samples, while the server keeps answering
(every call gets "the attempt has ended" at once), and ``result.json`` is written again with the
video. The server stops when its client has gone: stdio closed, or over HTTP every MCP session ended
by its client (the DELETE of session termination); at the latest ``linger_s`` after the last
answer (and the video). The attempt's records are the same as under the reference harness, plus ``mcp_*`` events.

Who played: every client identity of the MCP handshake (``clientInfo`` name and version, per MCP
session) is recorded as an ``mcp_client`` event when first seen and in ``result.json``'s ``agent``
block (:mod:`cab_core.kits.harness.agent_info`). The attempt's configuration name (``model``) is the one the
user gave (``model.name=my-agent``, or a model config of its own such as a vendor launcher's);
unnamed (the ``mcp_client`` placeholder that ``harness=mcp`` selects, or an in-process agent's
config, e.g. ``model=oracle``, that plays no part here) it is ``mcp:<client name>`` after the first
client that identified itself, and stays ``mcp_client`` when none did (:func:`attempt_model_name`).
The output directory is named before any client connects, so it keeps the configured name.
"""
from __future__ import annotations

import json
import logging
import os
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING

from cab_core.contracts.harness import ModelCheck
from cab_core.errors import AttemptEnded, ConfigError
from cab_core.kits.harness import prompts, stdio
from cab_core.kits.harness.agent_info import AgentRecord, ClientInfo
from cab_core.kits.harness.catalog import motion_rules
from cab_core.kits.registry import task_info

from .bridge import CallBridge, Job
from .server import build_server, instructions_text, tool_list, tool_result
from .transport import HttpServerThread, ServerThread, StdioServerThread

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.harness import AttemptSession

log = logging.getLogger(__name__)

ENDPOINT_FILE = "mcp_endpoint.json"
PLACEHOLDER = "mcp_client"  # the model config harness=mcp selects (conf/model/mcp_client.yaml): no name given


def configured_name(model_cfg: dict) -> str | None:
    """The configuration name the user gave, None for an unnamed attempt: the ``mcp_client``
    placeholder, or an in-process agent's own config (``oracle``, ``idle``, ``scripted``: its
    ``name`` is its ``agent``), which plays no part in an attempt served over MCP. A renamed one
    (``model=oracle model.name=my-agent``) is named."""
    name = model_cfg.get("name")
    if not name or name == PLACEHOLDER or (model_cfg.get("agent") and name == model_cfg["agent"]):
        return None
    return str(name)


def client_model_name(client_name: str) -> str | None:
    """``mcp:<client name>``, the name made safe for paths and tables (letters, digits, ``._-``;
    anything else becomes ``-``; at most 64 characters); None when nothing is left."""
    token = re.sub(r"[^A-Za-z0-9._-]+", "-", client_name).strip("-.")[:64]
    return f"mcp:{token}" if token else None


def attempt_model_name(model_cfg: dict, client: ClientInfo | None) -> tuple[str, str]:
    """(``model`` of the attempt, how it was named: ``config`` | ``client`` | ``placeholder``)."""
    named = configured_name(model_cfg)
    if named is not None:
        return named, "config"
    derived = client_model_name(client.name) if client is not None else None
    return (derived, "client") if derived else (PLACEHOLDER, "placeholder")


@dataclass
class McpSettings:
    """The ``harness`` config group of ``harness=mcp`` (conf/harness/mcp.yaml)."""
    transport: str = "stdio"            # stdio | http
    host: str = "127.0.0.1"
    port: int = 0                       # 0: any free port (written to mcp_endpoint.json)
    auth: bool = True                   # http: require the bearer token of mcp_endpoint.json
    idle_timeout_s: float | None = 900.0
    linger_s: float = 5.0
    max_images_per_result: int = 6
    startup_timeout_s: float = 30.0

    @classmethod
    def from_cfg(cls, cfg: dict | None, **overrides) -> McpSettings:
        cfg = {k: v for k, v in dict(cfg or {}).items() if k != "name"}
        cfg.update(overrides)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ConfigError(f"harness: unknown option(s) {unknown}; known: {sorted(known)}")
        s = cls(**cfg)
        if s.transport not in ("stdio", "http"):
            raise ConfigError(f"harness.transport must be stdio or http, got {s.transport!r}")
        if not isinstance(s.port, int) or not 0 <= s.port <= 65535:
            raise ConfigError(f"harness.port must be an integer in 0..65535, got {s.port!r}")
        for k in ("linger_s", "startup_timeout_s"):
            if not isinstance(getattr(s, k), (int, float)) or getattr(s, k) < 0:
                raise ConfigError(f"harness.{k} must be a non-negative number, got {getattr(s, k)!r}")
        if s.idle_timeout_s is not None and (not isinstance(s.idle_timeout_s, (int, float)) or s.idle_timeout_s <= 0):
            raise ConfigError(f"harness.idle_timeout_s must be positive or null, got {s.idle_timeout_s!r}")
        return s


def _interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def write_private_json(path: Path, obj) -> None:
    """A JSON file only its owner can read (it holds the attempt's bearer token)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        json.dump(obj, f, indent=2)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cab-harness-mcp")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "0"


class McpHarness:
    """Serves one attempt over MCP; ``run`` returns when the attempt has ended and the server
    has stopped."""

    def __init__(self, cfg: dict | None = None, **overrides):
        self.settings = McpSettings.from_cfg(cfg, **overrides)
        self._stdio = None
        self._clients: list[ClientInfo] = []           # every client identity recorded, in order
        self._sessions: dict[str | None, int] = {}     # transport session -> its number (1, 2, ...)
        self._model_cfg: dict = {}
        self.transport: ServerThread | None = None
        self.bridge: CallBridge | None = None
        self.tools: list = []
        self._info: dict = {}
        self.stopped_because: str | None = None  # why serving stopped after the attempt was recorded

    # -- before the simulator starts ----------------------------------------------------------
    def preflight(self, model_cfg: dict) -> None:
        """Claim stdout for the protocol before anything (a simulator, a renderer) can print."""
        if self.settings.transport == "stdio" and self._stdio is None:
            self._stdio = stdio.claim()

    def check_model(self, model_cfg: dict, network: bool = True) -> ModelCheck:
        """Nothing to check before a sweep: the agent is whichever MCP client connects, with its own
        credentials (the vendor launchers check their CLI and key)."""
        return ModelCheck()

    # -- hooks for the vendor launchers ---------------------------------------------------------
    def on_serving(self, episode: AttemptSession, transport: ServerThread) -> None:
        """Called once the server accepts connections."""

    def agent_gone(self) -> str | None:
        """A reason to end the attempt because the agent itself has finished, if it has."""
        return None

    def ready_to_finish(self, ended_for_s: float) -> bool:
        """Whether to score and write the record now, ``ended_for_s`` after the attempt ended."""
        return True

    def before_finish(self, episode: AttemptSession) -> None:
        """Last records of the harness (the records close when the attempt is finished)."""

    def on_stop(self) -> None:
        """Called when the server has stopped, whatever happened."""

    # -- serving starts while the world is built -------------------------------------------------
    def before_build(self, spec) -> None:
        """Start the server from what the spec alone determines (tools, prompt, budgets): a client
        gets its ``initialize`` and ``tools/list`` answered at once; calls wait in the queue until
        the attempt exists."""
        if self.transport is not None:
            return
        s = self.settings
        self.preflight(spec.model_cfg)
        budget = {"tool_calls_limit": spec.budget_tool_calls, "sim_seconds_limit": spec.budget_sim_seconds}
        system = prompts.system_prompt(budget, motion_rules(), run_code=prompts.run_code_limits(spec))
        self.task_prompt = instructions_text(system, prompts.first_user_message(task_info(spec.task).instruction)
                                             + prompts.continuation_note(getattr(spec, "fork", None)))
        self.tools = tool_list()
        self.bridge = CallBridge()
        server = build_server(self.tools, self.bridge, self.task_prompt, _version())
        if s.transport == "stdio":
            self.transport = StdioServerThread(server, self._stdio)
        else:
            self.transport = HttpServerThread(server, s.host, s.port, s.auth, s.idle_timeout_s)
        self.transport.start(s.startup_timeout_s)
        self._announce(spec)

    def close(self) -> None:
        """Stop serving (the world could not be built)."""
        if self.transport is not None:
            self.transport.stop()
        self.on_stop()

    # -- the attempt --------------------------------------------------------------------------
    agent_kind = "mcp_client"  # the ``kind`` of result.json's ``agent`` block

    def run(self, episode: AttemptSession, model_cfg: dict) -> None:
        self._model_cfg = dict(model_cfg or {})
        self.before_build(episode.spec)  # when the runner did not call it
        episode.recorder.event("mcp_server_start", **self._info)
        self._attribute(episode)
        self._note_clients(episode)  # those that connected while the world was built
        # a stdio client that lets go stops its server with SIGTERM: the attempt is recorded first
        previous = signal.signal(signal.SIGTERM, _interrupt) if _main_thread() else None
        try:
            self.on_serving(episode, self.transport)
            self._serve(episode, self.bridge, self.transport)
        except KeyboardInterrupt:
            episode.end("interrupted", "cab was interrupted or terminated")
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
            self.close()

    def _announce(self, spec) -> None:
        transport = self.transport
        self._info = {"transport": self.settings.transport, "tools": len(self.tools), "server": "cab",
                      "version": _version()}
        if isinstance(transport, HttpServerThread):
            self._info["url"] = transport.url
            endpoint = {"url": transport.url, "transport": "streamable-http",
                        "headers": ({"Authorization": f"Bearer {transport.token}"} if transport.token else {})}
            out = Path(spec.output_dir)
            out.mkdir(parents=True, exist_ok=True)
            path = out / ENDPOINT_FILE
            write_private_json(path, endpoint)
            print(f"cab: attempt {spec.task} served over MCP at {transport.url} (endpoint and token: {path})",
                  file=sys.stderr, flush=True)

    def _serve(self, episode: AttemptSession, bridge: CallBridge, transport: ServerThread) -> None:
        s = self.settings
        ended_at: float | None = None
        answered_at = 0.0  # when the last call was answered after the record was written
        video_done = False
        while True:
            job = bridge.next(timeout=0.05)
            self._note_clients(episode)  # before the call: a client is recorded before its first call
            answer = self._execute(episode, job) if job is not None else None
            if not episode.ended:
                reason = self._ending(episode, bridge, transport)
                if reason is not None:
                    episode.end(*reason)
            late: list[Job] = []
            if episode.ended:
                now = time.monotonic()
                if ended_at is None:
                    ended_at = now
                    episode.recorder.event("mcp_attempt_ended", reason=episode.termination["reason"],
                                           client_connected=not transport.finished, queued_calls=bridge.pending())
                if episode.result is None and self.ready_to_finish(now - ended_at):
                    self.before_finish(episode)
                    episode.finish()  # result.json now, not when the client finally lets go; closes the records
                    late = bridge.close(tool_result({"error": f"the attempt has ended ({episode.termination['reason']})",
                                                     "attempt_ended": True}))
            if job is not None:  # answered after the record is written, when the call ended the attempt
                job.future.set_result(answer)
            for queued in late:  # calls that came before the record was written
                queued.future.set_result(self._execute(episode, queued))
            if episode.result is None:
                continue
            if job is not None or late or not answered_at:
                answered_at = time.monotonic()
            if not video_done:
                video_done = True
                finish_video = getattr(episode, "finish_video", None)  # an AttemptSession may have none
                if finish_video is not None:
                    finish_video()  # the video, after the answer; the server answers later calls meanwhile
                    answered_at = time.monotonic()
            if transport.finished:
                self.stopped_because = "transport_finished"
            elif self._client_gone(transport):
                self.stopped_because = "sessions_ended"
            elif time.monotonic() - answered_at >= s.linger_s:
                self.stopped_because = "linger"
            else:
                continue
            break

    @staticmethod
    def _client_gone(transport: ServerThread) -> bool:
        """Over HTTP: every MCP session opened has been ended by its client (DELETE), so nobody
        waits for an answer. On stdio the client is gone when the transport has finished."""
        return isinstance(transport, HttpServerThread) and transport.open_sessions == 0

    def _ending(self, episode: AttemptSession, bridge: CallBridge, transport: ServerThread) -> tuple[str, str] | None:
        s = self.settings
        if transport.finished:
            if transport.error is not None:
                return "error", f"the MCP transport failed: {transport.error!r}"
            return "client_disconnected", "the MCP client closed the connection before done"
        gone = self.agent_gone()
        if gone is not None:
            return "no_done", gone
        if episode.ledger.exhausted_reason() == "wall_budget":
            return "wall_budget", "wall-clock budget spent while waiting for the client"
        if s.idle_timeout_s is not None and bridge.idle_seconds() > s.idle_timeout_s:
            return "client_idle", f"no request from the MCP client for {s.idle_timeout_s:g} s"
        return None

    def _note_clients(self, episode: AttemptSession) -> None:
        """Record the client identities the server has seen since the last look (an ``mcp_client``
        event each) and re-attribute the attempt. Once result.json is written the records are
        closed: a client that comes later is answered "the attempt has ended" and not recorded."""
        new = self.bridge.new_clients() if self.bridge is not None else []
        if not new or episode.result is not None:
            return
        for seen in new:
            session = self._sessions.setdefault(seen.session, len(self._sessions) + 1)
            client = ClientInfo(seen.name, seen.version, session)
            self._clients.append(client)
            episode.recorder.event("mcp_client", client=client.label, name=client.name, version=client.version,
                                   session=session)
        self._attribute(episode)

    def _attribute(self, episode: AttemptSession) -> None:
        """The attempt's configuration name and ``agent`` block, from the config and the clients
        recorded so far (kept current, so that whoever writes result.json writes them)."""
        first = self._clients[0] if self._clients else None
        episode.spec.model, named_by = attempt_model_name(self._model_cfg, first)
        episode.agent = AgentRecord(self.agent_kind, named_by, first, list(self._clients)).as_dict()

    def _execute(self, episode: AttemptSession, job: Job):
        """Run one queued call; returns its MCP result (the caller delivers it)."""
        try:
            r = episode.call(job.name, job.arguments)
        except AttemptEnded as e:
            return tool_result({"error": str(e), "attempt_ended": True})
        except BaseException as e:  # never leave the client hanging on a future
            job.future.set_result(tool_result({"error": f"internal error: {e!r}", "attempt_ended": episode.ended}))
            raise
        payload = dict(r.payload)
        images, withheld = prompts.result_images(episode, r.obs_ids, self.settings.max_images_per_result)
        if withheld:
            payload.setdefault("images_not_attached", withheld)
        return tool_result(payload, images)
