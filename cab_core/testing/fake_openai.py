"""A scripted OpenAI-compatible model server for benchmarks and tests: real HTTP on 127.0.0.1, the
Chat Completions wire format, each answer after a set latency (what a model keeps an attempt waiting).

``POST /v1/chat/completions`` answers turn ``k`` of a conversation (``k``: the assistant messages the
request already carries) with the script's ``k``-th tool call, after ``latency_s``; ``GET /v1/models``
lists the one model. The default script (:data:`CLICK_BELL_SCRIPT`) is an attempt at a table-top task
with the standard tools: it reads the robot's state, looks, moves the right arm a few times and ends
with ``done``: 16 turns, 15 charged calls. It stands in for a model in ``cab-bench-sweep
--fake-model-latency``; a test support, never a provider of a real run.
"""
from __future__ import annotations

import json
import re
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

MODEL_ID = "cab-fake-model"
CODE_WORD = re.compile(r"code word:\s*(\S+?)\.?\s")  # what a context probe asks to be given back

#: (tool, arguments) per turn: 15 charged calls (reads, captures, motions), then done
CLICK_BELL_SCRIPT: tuple[tuple[str, dict[str, Any]], ...] = (
    ("get_robot_state", {}),
    ("capture_head", {}),
    ("get_arm_pose", {"arm": "right"}),
    ("set_gripper", {"arm": "right", "pos": 0.0}),
    ("move_delta", {"arm": "right", "dz": 0.05}),
    ("move_delta", {"arm": "right", "dx": -0.05}),
    ("capture_head", {}),
    ("move_delta", {"arm": "right", "dz": -0.03}),
    ("get_grasp_contact", {"arm": "right"}),
    ("move_delta", {"arm": "right", "dz": 0.03}),
    ("move_delta", {"arm": "right", "dy": 0.03}),
    ("capture_head", {}),
    ("move_delta", {"arm": "right", "dy": -0.03}),
    ("get_gripper_state", {"arm": "right"}),
    ("capture_head", {}),
    ("done", {"report": "a scripted benchmark attempt (no model)", "success_claim": False}),
)


class FakeOpenAIServer:
    """The server in a thread of this process (one handler thread per request, so answers to
    attempts in flight wait side by side); ``base_url`` is what ``model.base_url`` takes."""

    def __init__(self, latency_s: float = 0.0, script: tuple[tuple[str, dict[str, Any]], ...] = CLICK_BELL_SCRIPT,
                 model_id: str = MODEL_ID):
        self.latency_s, self.script, self.model_id = float(latency_s), script, model_id
        self.requests = 0  # chat completions answered
        self.in_flight = 0  # requests being answered now
        self.max_in_flight = 0  # most requests answered at the same time
        self._lock = threading.Lock()
        outer = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:  # quiet
                pass

            def _send(self, status: int, body: dict) -> None:
                data = json.dumps(body).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def do_GET(self) -> None:
                if self.path.rstrip("/").endswith("/models"):
                    self._send(200, {"object": "list", "data": [{"id": outer.model_id, "object": "model",
                                                                 "created": 0, "owned_by": "cab-bench"}]})
                else:
                    self._send(404, {"error": {"message": f"no route {self.path}", "type": "invalid_request_error"}})

            def do_POST(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                try:
                    body = json.loads(self.rfile.read(length) or b"{}")
                except ValueError:
                    self._send(400, {"error": {"message": "the body is not JSON", "type": "invalid_request_error"}})
                    return
                if not self.path.rstrip("/").endswith("/chat/completions"):
                    self._send(404, {"error": {"message": f"no route {self.path}", "type": "invalid_request_error"}})
                    return
                if body.get("stream"):
                    self._send(400, {"error": {"message": "streaming is not served here",
                                               "type": "invalid_request_error"}})
                    return
                self._send(200, outer.answer(body))

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(target=self.httpd.serve_forever, name="fake-openai", daemon=True)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def answer(self, body: dict) -> dict:
        """The completion for one request (after the latency)."""
        with self._lock:
            self.requests += 1
            self.in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self.in_flight)
        try:
            time.sleep(self.latency_s)
        finally:
            with self._lock:
                self.in_flight -= 1
        messages = body.get("messages") or []
        turn = sum(1 for m in messages if isinstance(m, dict) and m.get("role") == "assistant")
        name, args = self.script[min(turn, len(self.script) - 1)]
        offered = {t.get("function", {}).get("name") for t in body.get("tools") or [] if isinstance(t, dict)}
        message: dict[str, Any] = {"role": "assistant", "content": None}
        if body.get("tools") and name in offered:
            message["tool_calls"] = [{"id": f"call_{turn}", "type": "function",
                                      "function": {"name": name, "arguments": json.dumps(args)}}]
            finish = "tool_calls"
        else:  # no tools offered (a server probe, say): a plain answer, a code word it was asked to remember
            last = messages[-1].get("content") if messages and isinstance(messages[-1], dict) else None
            word = CODE_WORD.search(last) if isinstance(last, str) else None
            message["content"] = word.group(1) if word else "ok"
            finish = "stop"
        prompt = sum(len(json.dumps(m)) for m in messages) // 4
        return {"id": f"chatcmpl-{self.requests}", "object": "chat.completion", "created": int(time.time()),
                "model": body.get("model", self.model_id),
                "choices": [{"index": 0, "message": message, "finish_reason": finish}],
                "usage": {"prompt_tokens": prompt, "completion_tokens": 20, "total_tokens": prompt + 20}}

    def __enter__(self) -> FakeOpenAIServer:
        self.thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
