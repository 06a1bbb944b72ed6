"""A scripted plain-JSON HTTP API on 127.0.0.1, for driving a provider's real SDK offline (the
``openai`` and ``openai_compatible`` provider tests), plus the small fixtures those tests share.

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


class FakeServer:
    """A scripted HTTP server: each POST pops the next (status, body) reply (the last one answers
    every request after it) and records the request path, JSON body and headers. Each answer
    carries an ``x-request-id`` header ``req_<n>``, n counting requests from 1."""

    def __init__(self, replies):
        self.replies = list(replies)
        self.requests: list[tuple[str, dict, dict]] = []
        outer = self

        class H(BaseHTTPRequestHandler):
            def log_message(self, *a):  # quiet
                pass

            def do_POST(self):
                n = int(self.headers.get("content-length") or 0)
                body = json.loads(self.rfile.read(n) or b"{}")
                outer.requests.append((self.path, body, dict(self.headers)))
                status, payload = outer.replies.pop(0) if len(outer.replies) > 1 else outer.replies[0]
                data = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("content-type", "application/json")
                self.send_header("x-request-id", f"req_{len(outer.requests)}")
                self.send_header("content-length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), H)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()


def offline_provider(cls, config: dict, overrides: dict, sleeps: list | None = None):
    """A ``cls`` provider built from ``config`` updated with ``overrides``, whose backoff waits are
    appended to ``sleeps`` instead of slept, with jitter at the top of its range (:class:`TopOfRange`)."""
    rec = sleeps if sleeps is not None else []
    return cls(dict(config, **overrides), sleep=rec.append, rng=TopOfRange())
