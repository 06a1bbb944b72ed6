"""Scripted plain-JSON HTTP APIs on 127.0.0.1, for driving a provider's real SDK offline:
:class:`JsonServer`, the server thread every such fake is built on (the ``anthropic`` and
``google`` provider tests script their own on it), and :class:`FakeServer`, the one the ``openai``
and ``openai_compatible`` provider tests share, plus the small fixtures those tests share.

Unlike the streaming fakes of :mod:`fake_model_apis`, a reply here is one JSON body with a status,
so a test can script errors (429, 500, 400) and retries as easily as answers."""
from __future__ import annotations

import base64
import json
import random
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

# a 1x1 PNG, the smallest real image a provider can be sent
PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR4nGNgYGD4DwABBAEAwS2OUAAAAABJRU5ErkJggg==")


class TopOfRange(random.Random):
    """Jitter that always draws the top of its range, so backoff delays are predictable."""

    def uniform(self, a, b):
        return b


class JsonServer:
    """A JSON HTTP server thread on 127.0.0.1 (port chosen by the system), the scaffolding of the
    scripted model APIs the provider tests talk to: each POST's parsed JSON body (``{}`` when empty)
    goes to :meth:`answer` with its path and headers, which returns ``(status, payload, headers)``
    to send back as JSON with those extra headers, or None to send nothing (the client waits in vain).
    ``url`` is the server's address followed by :attr:`base_path`; use it as a context manager (or
    :meth:`start` and :meth:`close`)."""

    base_path = ""

    def __init__(self):
        outer = self

        class H(BaseHTTPRequestHandler):
            def log_message(self, *a):  # quiet
                pass

            def do_POST(self):  # noqa: N802
                n = int(self.headers.get("content-length") or 0)
                body = json.loads(self.rfile.read(n) or b"{}")
                reply = outer.answer(self.path, body, dict(self.headers))
                if reply is None:
                    return
                status, payload, headers = reply
                data = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("content-type", "application/json")
                for name, value in headers.items():
                    self.send_header(name, value)
                self.send_header("content-length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), H)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}{self.base_path}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def answer(self, path: str, body: dict, headers: dict):
        raise NotImplementedError

    def start(self):
        self.thread.start()
        return self

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()


class FakeServer(JsonServer):
    """A scripted HTTP server: each POST pops the next (status, body) reply (the last one answers
    every request after it) and records the request path, JSON body and headers. Each answer
    carries an ``x-request-id`` header ``req_<n>``, n counting requests from 1."""

    base_path = "/v1"

    def __init__(self, replies):
        super().__init__()
        self.replies = list(replies)
        self.requests: list[tuple[str, dict, dict]] = []

    def answer(self, path, body, headers):
        self.requests.append((path, body, headers))
        status, payload = self.replies.pop(0) if len(self.replies) > 1 else self.replies[0]
        return status, payload, {"x-request-id": f"req_{len(self.requests)}"}


def offline_provider(cls, config: dict, overrides: dict, sleeps: list | None = None):
    """A ``cls`` provider built from ``config`` updated with ``overrides``, whose backoff waits are
    appended to ``sleeps`` instead of slept, with jitter at the top of its range (:class:`TopOfRange`)."""
    rec = sleeps if sleeps is not None else []
    return cls(dict(config, **overrides), sleep=rec.append, rng=TopOfRange())
