"""Transports: stdio (the process's own stdin/stdout) and streamable HTTP on loopback.

Each runs the MCP server's event loop in a daemon thread (:class:`ServerThread`); the attempt's
owner thread never blocks on the network.

stdio serves on the channel of :mod:`cab_core.kits.harness.stdio` (claimed before any simulator exists, so
nothing but protocol frames reaches stdout). The framing (newline-delimited JSON-RPC) is this
package's own rather than the SDK's ``stdio_server`` for one reason: a line that is not JSON, or not
a JSON-RPC message, is answered with a JSON-RPC error (-32700 parse error, -32600 invalid request)
instead of being dropped silently, and the session goes on.

Ids. MCP allows a string or an integer as the id of a request or a response, never null (JSON-RPC
2.0 also allows null and fractions). The SDK's message types take a message whose id is anything
else (``null``, ``true``, an object, ``1.5``, ``1e308``, ``NaN``, which its JSON parser accepts) for
a notification with an extra key: over HTTP it answers 202 and nothing else, on stdio nothing at
all. Both transports check the id first (:func:`malformed_id`) and answer such a message with
-32600 (Invalid Request) and id null, as JSON-RPC 2.0 asks when the id cannot be taken; over HTTP
in :class:`JsonRpcGate`, an ASGI layer in front of the SDK's transport (status 400).
"""
from __future__ import annotations

import asyncio
import hmac
import json
import logging
import math
import os
import secrets
import socket
import threading

import anyio
import mcp_types as types
import pydantic_core
from mcp.shared.message import SessionMessage

from cab_core.errors import ConfigError, SimulatorError
from cab_core.kits.harness.stdio import StdioChannel

log = logging.getLogger(__name__)

LOOPBACK = ("127.0.0.1", "localhost", "::1")
MAX_LINE = 20 * 1024 * 1024  # a longer line is refused (FACTS A.11: the paper's gateway limit)


def framing_error(line: str, exc: Exception) -> types.JSONRPCError:
    """The JSON-RPC error answering a line that could not be taken as a message."""
    try:
        obj = json.loads(line)
    except ValueError:
        return types.JSONRPCError(jsonrpc="2.0", id=None, error=types.ErrorData(
            code=types.PARSE_ERROR, message="Parse error: the line is not valid JSON"))
    rid = obj.get("id") if isinstance(obj, dict) else None
    if not isinstance(rid, (int, str)) or isinstance(rid, bool):
        rid = None
    return types.JSONRPCError(jsonrpc="2.0", id=rid, error=types.ErrorData(
        code=types.INVALID_REQUEST, message=f"Invalid request: not a JSON-RPC 2.0 message ({str(exc)[:200]})"))


def _json_kind(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, float):
        return "a non-finite number" if not math.isfinite(v) else "a number written with a fraction or an exponent"
    return {dict: "an object", list: "an array", str: "a string", int: "an integer"}.get(type(v), type(v).__name__)


def malformed_id(obj) -> types.JSONRPCError | None:
    """The -32600 error (id null) for a message whose id MCP does not allow, None for any other
    message (whatever else is wrong with it is the SDK's to answer). ``obj``: the parsed message."""
    if not isinstance(obj, dict):
        what = "a batch (an array)" if isinstance(obj, list) else _json_kind(obj)
        return types.JSONRPCError(jsonrpc="2.0", id=None, error=types.ErrorData(
            code=types.INVALID_REQUEST, message=f"Invalid request: a message is a JSON object, not {what}"))
    if "id" not in obj:
        return None
    rid = obj["id"]
    if isinstance(rid, str) or (isinstance(rid, int) and not isinstance(rid, bool)):
        return None
    if rid is None and "error" in obj and "method" not in obj:
        return None  # JSON-RPC 2.0: an error response whose request's id could not be read
    kind = _json_kind(rid)
    return types.JSONRPCError(jsonrpc="2.0", id=None, error=types.ErrorData(
        code=types.INVALID_REQUEST, message=f"Invalid request: an id must be a string or an integer, not {kind}"))


class JsonRpcGate:
    """ASGI middleware in front of the SDK's streamable HTTP transport: a POST whose message has an
    id MCP does not allow (:func:`malformed_id`) is answered here with HTTP 400 and the JSON-RPC
    error; every other request goes on untouched (its body replayed as it came). It also keeps
    the MCP sessions the SDK opened and those its client ended with DELETE (:attr:`open_sessions`),
    so that an ended attempt's server can wait for its client to say goodbye."""

    def __init__(self, app, max_body: int = MAX_LINE):
        self.app = app
        self.max_body = max_body
        self._opened: set[str] = set()
        self._ended: set[str] = set()

    @property
    def open_sessions(self) -> int:
        """Sessions opened and not (yet) ended by their client's DELETE."""
        return len(self._opened - self._ended)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        method = scope.get("method")
        if method == "POST":
            chunks, size, more = [], 0, True
            while more and size <= self.max_body:
                message = await receive()
                if message["type"] != "http.request":  # the client went away
                    chunks.append(message)
                    break
                chunks.append(message)
                size += len(message.get("body", b""))
                more = message.get("more_body", False)
            if not more and chunks and chunks[-1]["type"] == "http.request":
                try:
                    obj = pydantic_core.from_json(b"".join(c.get("body", b"") for c in chunks))
                except ValueError:
                    obj = {}  # not JSON: the SDK answers -32700
                error = malformed_id(obj)
                if error is not None:
                    log.warning("malformed MCP message over HTTP: %s", error.error.message)
                    await send({"type": "http.response.start", "status": 400,
                                "headers": [(b"content-type", b"application/json")]})
                    await send({"type": "http.response.body",
                                "body": error.model_dump_json(by_alias=True, exclude_unset=True).encode()})
                    return
            receive = self._replay(chunks, receive)
        session = dict(scope.get("headers") or []).get(b"mcp-session-id", b"").decode("latin-1")

        async def watch(message):
            if message["type"] == "http.response.start" and message["status"] < 300:
                if method == "DELETE" and session:
                    self._ended.add(session)
                for k, v in message.get("headers") or []:
                    if k.lower() == b"mcp-session-id":
                        self._opened.add(v.decode("latin-1"))
            await send(message)

        await self.app(scope, receive, watch)

    @staticmethod
    def _replay(chunks: list, receive):
        pending = list(chunks)

        async def replay():
            return pending.pop(0) if pending else await receive()
        return replay


class BearerGate:
    """ASGI middleware: HTTP requests must carry ``Authorization: Bearer <token>``. Loopback is
    reachable by every local user; the token keeps other users' processes out of the attempt."""

    def __init__(self, app, token: str):
        self.app = app
        self.expected = f"Bearer {token}".encode()

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            got = dict(scope.get("headers") or []).get(b"authorization", b"")
            if not hmac.compare_digest(got, self.expected):
                await send({"type": "http.response.start", "status": 401,
                            "headers": [(b"content-type", b"application/json"), (b"www-authenticate", b"Bearer")]})
                await send({"type": "http.response.body",
                            "body": b'{"error": "missing or wrong bearer token (see mcp_endpoint.json)"}'})
                return
        await self.app(scope, receive, send)


class ServerThread:
    """Runs one transport's event loop in a daemon thread until the client goes or ``stop()``."""

    def __init__(self, server, name: str):
        self.server = server
        self.name = name
        self.error: BaseException | None = None
        self._ready = threading.Event()
        self._finished = threading.Event()
        self._thread = threading.Thread(target=self._main, name=f"cab-mcp-{name}", daemon=True)

    # subclasses implement _serve (async) and _request_stop
    async def _serve(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _request_stop(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _main(self) -> None:
        try:
            anyio.run(self._serve)
        except BaseException as e:  # reported to the owner thread, which ends the attempt
            self.error = e
            log.error("MCP %s transport stopped: %r", self.name, e)
        finally:
            self._ready.set()
            self._finished.set()

    def start(self, ready_timeout: float = 30.0) -> ServerThread:
        self._thread.start()
        if not self._ready.wait(ready_timeout):
            raise SimulatorError(f"the MCP {self.name} transport did not start within {ready_timeout:g} s")
        if self.error is not None:
            raise ConfigError(f"the MCP {self.name} transport failed to start: {self.error!r}")
        return self

    @property
    def finished(self) -> bool:
        return self._finished.is_set()

    def stop(self, timeout: float = 3.0) -> None:
        if not self.finished:
            self._request_stop()
            self._finished.wait(timeout)  # a daemon thread left blocked in a read dies with the process


class StdioServerThread(ServerThread):
    """Serves the client on the claimed stdio channel; ends when the client closes its end."""

    def __init__(self, server, channel: StdioChannel):
        super().__init__(server, "stdio")
        self.channel = channel
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: anyio.Event | None = None

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = anyio.Event()
        rfile = os.fdopen(self.channel.in_fd, "rb", closefd=False)
        wfile = os.fdopen(self.channel.out_fd, "wb", closefd=False)
        write_lock = anyio.Lock()

        async def emit(message) -> None:
            data = (message.model_dump_json(by_alias=True, exclude_unset=True) + "\n").encode("utf-8")
            async with write_lock:  # one frame at a time, whole
                await anyio.to_thread.run_sync(lambda: (wfile.write(data), wfile.flush()))

        read_send, read_recv = anyio.create_memory_object_stream(0)
        write_send, write_recv = anyio.create_memory_object_stream(0)

        async def reader() -> None:
            async with read_send:
                while True:
                    raw = await anyio.to_thread.run_sync(rfile.readline, MAX_LINE + 1, abandon_on_cancel=True)
                    if not raw:
                        return  # the client closed its end
                    line = raw.decode("utf-8", errors="replace").strip()
                    if not line:
                        continue
                    if len(raw) > MAX_LINE:
                        await emit(framing_error("", ValueError("line too long")))
                        continue
                    try:
                        bad_id = malformed_id(pydantic_core.from_json(line))
                    except ValueError:
                        bad_id = None  # not JSON: answered -32700 below
                    if bad_id is not None:
                        log.warning("malformed MCP frame: %s", bad_id.error.message)
                        await emit(bad_id)
                        continue
                    try:
                        message = types.jsonrpc_message_adapter.validate_json(line, by_name=False)
                    except Exception as e:  # answered, never fatal
                        log.warning("malformed MCP frame: %s", str(e)[:200])
                        await emit(framing_error(line, e))
                        continue
                    await read_send.send(SessionMessage(message))

        async def writer() -> None:
            async with write_recv:
                async for session_message in write_recv:
                    await emit(session_message.message)

        async with anyio.create_task_group() as tg:
            async def stopper():
                await self._stop.wait()
                tg.cancel_scope.cancel()

            tg.start_soon(reader)
            tg.start_soon(writer)
            tg.start_soon(stopper)
            self._ready.set()
            await self.server.run(read_recv, write_send, self.server.create_initialization_options())
            tg.cancel_scope.cancel()

    def _request_stop(self) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)


class HttpServerThread(ServerThread):
    """Streamable HTTP on a loopback port, behind a bearer token unless ``auth`` is off."""

    def __init__(self, server, host: str, port: int, auth: bool, session_idle_timeout: float | None):
        super().__init__(server, "http")
        if host not in LOOPBACK:
            raise ConfigError(f"harness.host={host!r}: the MCP server listens on loopback only ({', '.join(LOOPBACK)})")
        self.host = host
        self.token = secrets.token_urlsafe(24) if auth else None
        self._sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._sock.bind((host, int(port)))
        except OSError as e:
            self._sock.close()
            raise ConfigError(f"cannot listen on {host}:{port}: {e}") from e
        self.port = self._sock.getsockname()[1]
        self._idle = session_idle_timeout
        self._uvicorn = None
        self.gate: JsonRpcGate | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/mcp"

    async def _serve(self) -> None:
        import uvicorn

        app = self.gate = JsonRpcGate(self.server.streamable_http_app(host=self.host, session_idle_timeout=self._idle))
        if self.token is not None:
            app = BearerGate(app, self.token)
        config = uvicorn.Config(app, log_config=None, access_log=False, lifespan="on", timeout_graceful_shutdown=2)
        self._uvicorn = uvicorn.Server(config)

        async def mark_ready():
            while not self._uvicorn.started and not self._uvicorn.should_exit:
                await anyio.sleep(0.02)
            self._ready.set()

        async with anyio.create_task_group() as tg:
            tg.start_soon(mark_ready)
            await self._uvicorn.serve(sockets=[self._sock])

    @property
    def open_sessions(self) -> int:
        """MCP sessions opened and not ended by their client (DELETE)."""
        return self.gate.open_sessions if self.gate is not None else 0

    def _request_stop(self) -> None:
        if self._uvicorn is not None:
            self._uvicorn.should_exit = True
