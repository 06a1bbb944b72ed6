"""Local stand-ins for two model APIs, speaking their streaming wire formats, so that real clients
(the vendor CLIs Claude Code and Codex) can be driven offline by a scripted model.

- :class:`FakeAnthropic`: ``POST /v1/messages`` answered as server-sent events in the order the
  Messages API sends them (``message_start``, ``ping``, ``content_block_start`` / ``_delta`` /
  ``_stop`` per block, ``message_delta`` with the stop reason and output usage, ``message_stop``);
  ``POST /v1/messages/count_tokens`` and the client's ``HEAD /`` reachability probe are answered too.
- :class:`FakeResponses`: ``POST /v1/responses`` answered as Responses API events
  (``response.created``, ``response.in_progress``, ``response.output_item.added`` / ``.done`` per
  item, ``response.completed`` with usage). A WebSocket upgrade on the same path is refused with
  426 Upgrade Required, which tells a client to use HTTP streaming instead.

Each server records every request it receives and answers the model requests from a script: one
:class:`Turn` per request, in order. A turn may be a callable taking the request body, for replies
that depend on what the client sent (the id of the call being answered, say). When the script is
spent, a model request gets an HTTP 500 in the provider's error format, so a client that asks for
more than the test planned fails loudly instead of looping."""
from __future__ import annotations

import json
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


@dataclass
class Turn:
    """One scripted model reply: output blocks (Anthropic content blocks or Responses output
    items), the stop reason, and the usage the provider reports for it."""
    output: list[dict]
    usage: dict
    stop_reason: str = "end_turn"


@dataclass
class Request:
    """One request as received: the header names lower-cased, the JSON body parsed."""
    method: str
    path: str
    headers: dict[str, str]
    body: dict | None


@dataclass
class _Reply:
    """What to send back: a JSON body, or server-sent events (``(event name, data)`` pairs)."""
    status: int
    headers: dict[str, str] = field(default_factory=dict)
    json_body: dict | None = None
    events: list[tuple[str, dict]] | None = None


class FakeModelApi:
    """A scripted HTTP server thread on 127.0.0.1 (port chosen by the system)."""

    model_path = ""

    def __init__(self, script: list[Turn | Callable[[dict], Turn]]):
        self.script = list(script)
        self.requests: list[Request] = []
        self._lock = threading.Lock()
        fake = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):
                pass

            def _handle(self):
                n = int(self.headers.get("content-length") or 0)
                raw = self.rfile.read(n) if n else b""
                req = Request(self.command, self.path, {k.lower(): v for k, v in self.headers.items()},
                              json.loads(raw) if raw else None)
                with fake._lock:
                    fake.requests.append(req)
                    reply = fake.route(req)
                fake._send(self, reply)

            do_GET = do_POST = do_HEAD = _handle

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self._server.server_address[1]}"
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- what the client sent ------------------------------------------------------------------
    @property
    def model_requests(self) -> list[Request]:
        """The requests the scripted model answered (or refused, once the script was spent)."""
        return [r for r in self.requests if r.method == "POST" and r.path.split("?")[0] == self.model_path]

    # -- routing ---------------------------------------------------------------------------------
    def route(self, req: Request) -> _Reply:  # pragma: no cover - per provider
        raise NotImplementedError

    def next_turn(self, body: dict) -> Turn | None:
        if not self.script:
            return None
        turn = self.script.pop(0)
        return turn(body) if callable(turn) else turn

    @staticmethod
    def _send(h: BaseHTTPRequestHandler, reply: _Reply) -> None:
        if reply.events is not None:
            h.send_response(reply.status)
            h.send_header("content-type", "text/event-stream; charset=utf-8")
            h.send_header("cache-control", "no-cache")
            h.send_header("connection", "close")
            for k, v in reply.headers.items():
                h.send_header(k, v)
            h.end_headers()
            for name, data in reply.events:
                h.wfile.write(f"event: {name}\ndata: {json.dumps(data)}\n\n".encode())
                h.wfile.flush()
            h.close_connection = True
            return
        data = b"" if reply.json_body is None else json.dumps(reply.json_body).encode()
        h.send_response(reply.status)
        if reply.json_body is not None:
            h.send_header("content-type", "application/json")
        for k, v in reply.headers.items():
            h.send_header(k, v)
        h.send_header("content-length", str(len(data)))
        h.end_headers()
        if h.command != "HEAD":
            h.wfile.write(data)


# -- Anthropic Messages API ---------------------------------------------------------------------

class FakeAnthropic(FakeModelApi):
    """``ANTHROPIC_BASE_URL`` target: the Messages API, streamed."""

    model_path = "/v1/messages"

    def route(self, req: Request) -> _Reply:
        path = req.path.split("?")[0]
        if req.method == "HEAD" and path == "/":
            return _Reply(200)
        if req.method == "POST" and path == "/v1/messages/count_tokens":
            return _Reply(200, json_body={"input_tokens": len(json.dumps(req.body)) // 4})
        if req.method == "POST" and path == self.model_path:
            turn = self.next_turn(req.body or {})
            if turn is None:
                return _Reply(500, json_body={"type": "error", "error": {
                    "type": "api_error", "message": "the fake model's script is spent"}})
            n = len(self.model_requests)
            return _Reply(200, {"request-id": f"req_{n}"}, events=messages_events(turn, req.body or {}, n))
        return _Reply(404, json_body={"type": "error", "error": {"type": "not_found_error", "message": req.path}})


def messages_events(turn: Turn, body: dict, n: int) -> list[tuple[str, dict]]:
    """The Messages API's event stream for one reply: input and cache usage in ``message_start``,
    each block opened, filled by deltas and closed, the output usage in ``message_delta``."""
    u = turn.usage
    start_usage = {"input_tokens": u.get("input_tokens", 0),
                   "cache_creation_input_tokens": u.get("cache_creation_input_tokens", 0),
                   "cache_read_input_tokens": u.get("cache_read_input_tokens", 0), "output_tokens": 1}
    message = {"id": f"msg_{n:04d}", "type": "message", "role": "assistant", "model": body.get("model", "claude"),
               "content": [], "stop_reason": None, "stop_sequence": None, "usage": start_usage}
    events = [("message_start", {"type": "message_start", "message": message}), ("ping", {"type": "ping"})]
    for i, block in enumerate(turn.output):
        if block["type"] == "text":
            opened, delta = {"type": "text", "text": ""}, {"type": "text_delta", "text": block["text"]}
        elif block["type"] == "tool_use":
            opened = {"type": "tool_use", "id": block["id"], "name": block["name"], "input": {}}
            delta = {"type": "input_json_delta", "partial_json": json.dumps(block["input"])}
        else:
            raise ValueError(f"unsupported block type {block['type']!r}")
        events += [("content_block_start", {"type": "content_block_start", "index": i, "content_block": opened}),
                   ("content_block_delta", {"type": "content_block_delta", "index": i, "delta": delta}),
                   ("content_block_stop", {"type": "content_block_stop", "index": i})]
    events += [("message_delta", {"type": "message_delta",
                                  "delta": {"stop_reason": turn.stop_reason, "stop_sequence": None},
                                  "usage": {"output_tokens": u.get("output_tokens", 0)}}),
               ("message_stop", {"type": "message_stop"})]
    return events


# -- OpenAI Responses API -----------------------------------------------------------------------

class FakeResponses(FakeModelApi):
    """``openai_base_url`` target: the Responses API, streamed over HTTP."""

    model_path = "/v1/responses"

    def route(self, req: Request) -> _Reply:
        path = req.path.split("?")[0]
        if req.method == "GET" and path == self.model_path and req.headers.get("upgrade", "").lower() == "websocket":
            return _Reply(426, json_body={"error": {"type": "invalid_request_error",
                                                    "message": "use HTTP streaming", "code": None}})
        if req.method == "POST" and path == self.model_path:
            turn = self.next_turn(req.body or {})
            if turn is None:
                return _Reply(500, json_body={"error": {"type": "server_error", "code": None,
                                                        "message": "the fake model's script is spent"}})
            n = len(self.model_requests)
            return _Reply(200, {"x-request-id": f"req_{n}"}, events=responses_events(turn, req.body or {}, n))
        return _Reply(404, json_body={"error": {"type": "invalid_request_error", "message": req.path, "code": None}})


def responses_events(turn: Turn, body: dict, n: int) -> list[tuple[str, dict]]:
    """The Responses API's event stream for one reply: the response created and in progress, each
    output item added then done, the completed response with every item and the usage."""
    response = {"id": f"resp_{n:04d}", "object": "response", "created_at": 1795000000 + n, "status": "in_progress",
                "model": body.get("model", "gpt"), "output": [], "usage": None, "error": None,
                "incomplete_details": None}
    events = [("response.created", {"type": "response.created", "response": response}),
              ("response.in_progress", {"type": "response.in_progress", "response": response})]
    for i, item in enumerate(turn.output):
        events += [("response.output_item.added", {"type": "response.output_item.added", "output_index": i,
                                                   "item": {**item, "status": "in_progress"}}),
                   ("response.output_item.done", {"type": "response.output_item.done", "output_index": i,
                                                  "item": {**item, "status": "completed"}})]
    done = {**response, "status": "completed", "output": [{**it, "status": "completed"} for it in turn.output],
            "usage": turn.usage}
    events.append(("response.completed", {"type": "response.completed", "response": done}))
    for seq, (_, data) in enumerate(events):
        data["sequence_number"] = seq
    return events
