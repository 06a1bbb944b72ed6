"""``cab-studio <dir>``: a local web application over any tree of attempt records.

Pages: the tree (every sweep and folder of attempts below ``<dir>``, with live progress), a
group's attempts, a group's report (the page ``cab-report`` writes, generated on demand into the
studio's state folder and served with links to the studio's attempt pages), an attempt's page (the
page ``cab-view`` writes, re-rendered as a running attempt grows), and the play page, where a person
plays an attempt through the same tools, prompt and budgets a model gets (:mod:`.play`,
:mod:`cab_core.attempt.engine.human`); each played attempt runs in a child process of its own, so a
simulator's crash ends that play only, never the studio or its other plays. Docs: docs/studio.md.

It listens on loopback by default. Bound to any other address it requires a token, generated at
start and printed once: ``?token=`` on the first request (then a cookie), or the header
``Authorization: Bearer <token>``. A request whose ``Origin`` is another site is refused, and on
loopback so is a ``Host`` that is not a loopback name (DNS rebinding).
"""
from __future__ import annotations

import asyncio
import contextlib
import errno
import hashlib
import ipaddress
import json
import os
import secrets
import socket
import subprocess
import sys
import threading
from html import escape
from pathlib import Path
from typing import NoReturn
from urllib.parse import quote, urlsplit

from jinja2 import FileSystemLoader
from markupsafe import Markup
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, PlainTextResponse, RedirectResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.templating import Jinja2Templates

from cab_core.analysis import pages, viewer
from cab_core.analysis.attempts import Attempt
from cab_core.apps.studio import tree
from cab_core.apps.studio.play import PLAYED, Plays, installed
from cab_core.errors import AttemptEnded, CabError

HERE = Path(__file__).resolve().parent  # the real folder (an editable install links each file)
COOKIE = "cab_studio_token"
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
#: images of only the most recent image-bearing results stay visible, as under the reference
#: harness's context policy (``max_image_rounds``); older ones are named by id
MAX_IMAGE_ROUNDS = 2
def is_loopback(host: str) -> bool:
    if host in ("localhost",):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def default_state_dir(root: Path) -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "cab-studio" / hashlib.sha256(str(Path(root).resolve()).encode()).hexdigest()[:16]


class Guard:
    """ASGI middleware: the token (when one is set), the Origin of state-changing requests, the
    Host on loopback."""

    def __init__(self, app, token: str | None, loopback: bool):
        self.app, self.token, self.loopback = app, token, loopback

    def _authorised(self, request: Request) -> tuple[bool, bool]:
        """(allowed, set the cookie)."""
        if self.token is None:
            return True, False
        given = request.query_params.get("token")
        if given is not None and self._is_token(given):
            return True, True
        auth = request.headers.get("authorization", "")
        if auth.lower().startswith("bearer ") and self._is_token(auth[7:].strip()):
            return True, False
        cookie = request.cookies.get(COOKIE)
        return cookie is not None and self._is_token(cookie), False

    def _is_token(self, given: str) -> bool:
        """Whether ``given`` is the token: compared as UTF-8 bytes in constant time (a text with
        non-ASCII characters is simply not the token; ``compare_digest`` refuses such ``str``)."""
        token = self.token  # set: called only when the studio has a token
        return token is not None and secrets.compare_digest(given.encode("utf-8", "surrogatepass"), token.encode())

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        request = Request(scope)
        host = (request.headers.get("host") or "").rsplit(":", 1)[0].strip("[]")
        if self.loopback and host and host not in LOOPBACK_NAMES and not is_loopback(host):
            return await PlainTextResponse("cab-studio: unexpected Host", 403)(scope, receive, send)
        origin = request.headers.get("origin")
        if request.method not in ("GET", "HEAD") and origin and urlsplit(origin).netloc != request.headers.get("host"):
            return await PlainTextResponse("cab-studio: cross-site request refused", 403)(scope, receive, send)
        ok, set_cookie = self._authorised(request)
        if not ok:
            return await PlainTextResponse(
                "cab-studio: a token is required (printed when the studio started): open the URL it printed, "
                "or send 'Authorization: Bearer <token>'", 401)(scope, receive, send)
        if not set_cookie:
            return await self.app(scope, receive, send)

        async def send_with_cookie(message):
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers.append((b"set-cookie", f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict".encode()))
                message = {**message, "headers": headers}
            await send(message)

        return await self.app(scope, receive, send_with_cookie)


class Studio:
    """The application's state: the root, the state folder (report cache), the plays."""

    def __init__(self, root: Path, state_dir: Path | None = None):
        self.root = Path(root).resolve()
        self.shown = os.path.normpath(str(root))  # the root as the person named it, shown on every page
        self.state_dir = Path(state_dir) if state_dir else default_state_dir(self.root)
        self.plays = Plays(self.root)
        self._report_locks: dict[str, threading.Lock] = {}
        # the studio's templates extend the pages' shared base (cab_core/analysis/templates/base.html.j2)
        self.templates = Jinja2Templates(env=pages.environment(FileSystemLoader(str(HERE / "templates"))))

    # -- paths -------------------------------------------------------------------------------
    def group_name(self, rel: str) -> str:
        """What a group is called on the pages: its path below the root; the root itself (a studio
        started on one sweep, or on a folder of attempts) by the name it was given (``cab-studio
        multirun/s1``: ``multirun/s1``; ``cab-studio .``: the folder's own name), never ``.``."""
        if rel != ".":
            return rel
        return self.shown if self.shown not in (".", "..") else (self.root.name or str(self.root))

    def inside(self, rel: str) -> Path | None:
        """``rel`` below the root (no hidden part, nothing outside), None otherwise."""
        rel = (rel or ".").strip("/") or "."
        if any(p.startswith(".") and p != "." for p in rel.split("/")) or ".." in rel.split("/"):
            return None
        p = (self.root / rel).resolve()
        return p if p == self.root or p.is_relative_to(self.root) else None

    def attempt_of(self, rel: str) -> tuple[Path, str] | None:
        """The attempt folder a path starts with, and the rest of the path (a file in it)."""
        parts = [p for p in rel.split("/") if p]
        for i in range(len(parts), -1, -1):
            d = self.inside("/".join(parts[:i]))
            if d is not None and d.is_dir() and ((d / "result.json").exists() or (d / "events.jsonl").exists()):
                return d, "/".join(parts[i:])
        return None

    # -- the report ----------------------------------------------------------------------------
    def report(self, rel: str) -> tuple[str, int]:
        """The report page of the group at ``rel`` (cab-report's, regenerated when a record changed),
        its attempts linked to the studio's pages."""
        folder = self.inside(rel)
        if folder is None or not folder.is_dir():
            return f"<p>no folder {escape(rel)}</p>", 404
        rel = tree._rel(folder, self.root)
        out = self.state_dir / "reports" / hashlib.sha256(rel.encode()).hexdigest()[:16]
        lock = self._report_locks.setdefault(rel, threading.Lock())
        with lock:
            sig = json.dumps([rel, tree.signature(folder)])
            stamp = out / "signature.json"
            if not (stamp.is_file() and stamp.read_text() == sig and (out / "report.html").is_file()):
                out.mkdir(parents=True, exist_ok=True)
                # cab-report itself, in its own process: the report exactly as it writes it
                r = subprocess.run([sys.executable, "-c", "from cab_core.apps.report_cli import main; main()",
                                    str(folder), "--out", str(out), "--no-views", "--no-figure-files"],
                                   capture_output=True, text=True, timeout=600)
                if r.returncode == 2 or not (out / "report.html").is_file():
                    return f"<p>cab-report wrote no report for {escape(rel)}:</p><pre>{escape(r.stderr)}</pre>", 200
                stamp.write_text(sig)
            page = (out / "report.html").read_text()
            data = json.loads((out / "report.json").read_text())
        base = "" if rel == "." else rel + "/"
        for a in [m["rel"] for m in data.get("attempt_rows", [])] + list(data.get("in_flight", [])):
            link = f'<a class="attempt-link" href="/attempt/{quote(base + a)}/">{Markup.escape(a)}</a>'
            page = page.replace(f"<tr><td>{Markup.escape(a)}</td>", f"<tr><td>{link}</td>")  # escaped as the template does
        nav = self.nav([("report", None)], rel)
        return page.replace("<body>", f"<body>{nav}", 1), 200

    def nav(self, trail: list[tuple[str, str | None]], group: str | None = None) -> str:
        items = [("cab-studio", "/")] + trail
        if group is not None:
            items.insert(1, (self.group_name(group), f"/group?rel={quote(group)}"))
        return self.templates.env.get_template("nav.html").render(items=items)

    # -- an attempt's page ----------------------------------------------------------------------
    def attempt_page(self, d: Path) -> str:
        rel = tree._rel(d, self.root)
        if self.plays.playing(d):
            return self.templates.env.get_template("playing.html").render(
                rel=rel, nav=Markup(self.nav([(rel, None)])), live=Markup(self._live(d, rel, False)))
        finished = (d / "result.json").exists()
        live = self._live(d, rel, finished)  # stamped before the records are read: a change meanwhile shows
        note = ""
        if finished:
            try:
                page = viewer.render(Attempt.load(d, d.parent), page_of="")  # another attempt: its route
            except CabError as e:
                note = f"<p class='bad'>{escape(str(e))}</p>"
                page = viewer.render_unfinished(d, page_of="")
        else:
            page = viewer.render_unfinished(d, page_of="")
        page = page.replace("<body>", f"<body>{self.nav([(rel, None)])}{note}", 1)
        return page.replace("</body>", f"{live}</body>", 1)

    def stamp(self, d: Path) -> str:
        """Changes whenever the attempt's records (or whether it is being played) change."""
        return hashlib.sha256(json.dumps([tree.signature(d), self.plays.playing(d)]).encode()).hexdigest()[:16]

    def _live(self, d: Path, rel: str, finished: bool) -> str:
        """A running attempt's page fetches itself again whenever its records change (the stamp of
        the records it was rendered from is in the page)."""
        if finished:
            return ""
        return (f"<script src='/static/live.js' data-stamp='/api/stamp?rel={quote(rel)}' "
                f"data-rendered='{self.stamp(d)}'></script>")


def build_app(root: Path, state_dir: Path | None = None, token: str | None = None, loopback: bool = True) -> Starlette:
    """The studio's application over ``root``, behind its :class:`Guard` (the token, the loopback rule)."""
    studio = Studio(root, state_dir)
    routes = [*_browse_routes(studio), *_play_routes(studio), *_play_api_routes(studio),
              Mount("/static", StaticFiles(directory=str(HERE / "static")), name="static")]

    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        await asyncio.to_thread(studio.plays.stop)  # a play still running is recorded as interrupted

    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.studio = studio
    return Guard(app, token, loopback)  # type: ignore[return-value]


def _page(studio: Studio, request: Request, name: str, **ctx) -> Response:
    """Template ``name`` rendered with the studio's root and ``ctx``."""
    return studio.templates.TemplateResponse(request, name, {"root": studio.shown, **ctx})


def _browse_routes(studio: Studio) -> list[Route]:
    """The pages and API of the tree of records: the tree, a group, its report, an attempt and its files."""

    def page(request: Request, name: str, **ctx) -> Response:
        return _page(studio, request, name, **ctx)

    def home(request: Request):
        return page(request, "tree.html")

    def api_tree(request: Request):
        gs = tree.groups(studio.root)
        plays = [p.status() for p in studio.plays.plays.values()]
        named = [{**g.as_dict(attempts=False), "name": studio.group_name(g.rel)} for g in gs]
        return JSONResponse({"root": studio.shown, "groups": named,
                             "plays": plays})

    def group_page(request: Request):
        rel = request.query_params.get("rel", ".")
        return page(request, "group.html", rel=rel, group_name=studio.group_name(rel))

    def api_group(request: Request):
        rel = request.query_params.get("rel", ".")
        g = tree.group(studio.root, rel)
        if g is None:
            return JSONResponse({"error": f"no sweep or folder of attempts at {rel!r}"}, 404)
        return JSONResponse({**g.as_dict(), "name": studio.group_name(g.rel)})

    def report_page(request: Request):
        html, status = studio.report(request.query_params.get("rel", "."))
        return HTMLResponse(html, status)

    def attempt(request: Request):
        rel = request.path_params["path"]
        found = studio.attempt_of(rel)
        if found is None:
            return PlainTextResponse(f"no attempt at {rel}", 404)
        d, rest = found
        if not rest:
            if not request.url.path.endswith("/"):  # the page's relative links need the slash
                return RedirectResponse(request.url.path + "/", 308)
            return HTMLResponse(studio.attempt_page(d))
        f = None if studio.plays.playing(d) else viewer.shown_file(d, rest)
        if f is None:  # not served and not there answer alike: the answer tells nothing of the folder
            return PlainTextResponse("not served", 404)
        return FileResponse(f)

    def api_stamp(request: Request):
        found = studio.attempt_of(request.query_params.get("rel", ""))
        if found is None:
            return JSONResponse({"error": "no attempt"}, 404)
        d = found[0]
        playing = studio.plays.playing(d)
        return JSONResponse({"finished": (d / "result.json").exists() and not playing, "playing": playing,
                             "stamp": studio.stamp(d)})

    return [
        Route("/", home), Route("/api/tree", api_tree), Route("/group", group_page), Route("/api/group", api_group),
        Route("/report", report_page), Route("/attempt/{path:path}", attempt), Route("/api/stamp", api_stamp),
    ]


def _play_routes(studio: Studio) -> list[Route]:
    """The pages of attempts played by a person: the form that starts one, the play's page."""
    T = studio.templates

    def page(request: Request, name: str, **ctx) -> Response:
        return _page(studio, request, name, **ctx)

    def play_form(request: Request, error: str | None = None, form: dict | None = None, status: int = 200):
        choices = installed()
        targets = [(PLAYED, PLAYED)] + [(g.rel, studio.group_name(g.rel)) for g in tree.groups(studio.root)
                                        if g.rel != PLAYED]
        return T.TemplateResponse(request, "play_new.html", {
            "root": str(studio.root), "tasks": choices["tasks"], "sims": choices["sims"], "targets": targets,
            "error": error, "form": form or {}}, status_code=status)

    async def play_start(request: Request):
        form = dict(await request.form())
        seed_text = str(form.get("seed", "")).strip()
        try:
            seed = int(seed_text) if seed_text else None
        except ValueError:
            return await asyncio.to_thread(play_form, request, f"seed must be an integer, got {seed_text!r}", form, 400)
        try:
            play = await asyncio.to_thread(studio.plays.start, str(form.get("task", "")), str(form.get("sim", "")),
                                           seed, str(form.get("handle", "")), str(form.get("into", PLAYED)))
        except CabError as e:
            return await asyncio.to_thread(play_form, request, str(e), form, 400)
        return RedirectResponse(f"/play/{play.id}", 303)

    def play_page(request: Request):
        p = studio.plays.get(request.path_params["pid"])
        if p is None:
            return PlainTextResponse("no such play", 404)
        return page(request, "play.html", play=p.status())

    return [
        Route("/play", play_form, methods=["GET"]), Route("/play", play_start, methods=["POST"]),
        Route("/play/{pid}", play_page),
    ]


def _play_api_routes(studio: Studio) -> list[Route]:
    """The API a play's page calls: its status, a tool call made by the person, the images it was shown."""

    def api_play(request: Request):
        p = studio.plays.get(request.path_params["pid"])
        if p is None:
            return JSONResponse({"error": "no such play"}, 404)
        out = p.status()
        if p.bridge.ready.is_set():
            out["info"] = {**p.bridge.info, "max_image_rounds": MAX_IMAGE_ROUNDS}
        return JSONResponse(out)

    async def api_call(request: Request):
        p = studio.plays.get(request.path_params["pid"])
        if p is None:
            return JSONResponse({"error": "no such play"}, 404)
        if not p.bridge.ready.is_set():
            return JSONResponse({"error": "the attempt is not ready yet"}, 409)
        try:
            body = await request.json()
        except ValueError:
            return JSONResponse({"error": "the body must be JSON: {\"tool\": ..., \"args\": {...}}"}, 400)
        if not isinstance(body, dict) or not isinstance(body.get("tool"), str) or not isinstance(body.get("args", {}), dict):
            return JSONResponse({"error": "the body must be JSON: {\"tool\": ..., \"args\": {...}}"}, 400)
        try:
            future = p.bridge.submit(body["tool"], body.get("args") or {})
        except AttemptEnded as e:
            return JSONResponse({"error": str(e), "ended": True}, 409)
        answer = await asyncio.wrap_future(future)
        for oid, png in answer.images:
            p.images[oid] = png
        if answer.ended and p.thread is not None:
            await asyncio.to_thread(p.thread.join, 120)
        out = {"tool": answer.tool, "payload": answer.payload, "budget": answer.budget,
               "images": [{"obs_id": oid, "url": f"/play/{p.id}/image/{quote(oid)}.png"} for oid, _ in answer.images],
               "withheld": answer.withheld, "ended": answer.ended, "status": p.status()}
        return Response(json.dumps(out, default=str), media_type="application/json")

    def play_image(request: Request):
        p = studio.plays.get(request.path_params["pid"])
        png = p.images.get(request.path_params["obs"]) if p is not None else None
        if png is None:
            return PlainTextResponse("not an image this attempt was shown", 404)
        return Response(png, media_type="image/png")

    return [
        Route("/api/play/{pid}", api_play), Route("/api/play/{pid}/call", api_call, methods=["POST"]),
        Route("/play/{pid}/image/{obs}.png", play_image),
    ]


def main(argv: list[str] | None = None) -> None:
    import argparse
    import logging

    ap = argparse.ArgumentParser(prog="cab-studio", description="A local web application over a tree of attempt "
                                 "records: live progress of sweeps, their reports, each attempt's page, and "
                                 "attempts played by a person (docs/studio.md).")
    ap.add_argument("dir", help="a folder of records: a sweep, outputs/, multirun/, any tree of attempt folders")
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; any other "
                                                         "address requires the token printed at start)")
    ap.add_argument("--port", default="8765", help="port (default 8765; 0: any free port)")
    ap.add_argument("--state-dir", help="where the studio keeps its reports (default ~/.cache/cab-studio/<root hash>)")
    a = ap.parse_args(argv)
    root = Path(a.dir)
    if not root.is_dir():
        fail(f"{root} is not a directory")
    port = parse_port(a.port)
    sock = bind(a.host, port)  # before anything else: a port that cannot be had is one line, exit 2
    loopback = is_loopback(a.host)
    token = None if loopback else secrets.token_urlsafe(24)
    import uvicorn

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    app = build_app(root, Path(a.state_dir) if a.state_dir else None, token, loopback)
    config = uvicorn.Config(app, host=a.host, port=port, log_level="warning", lifespan="on")
    server = uvicorn.Server(config)

    def announce():  # once the server listens (port 0: the port the socket got)
        import time

        while not server.started:
            if server.should_exit:
                return
            time.sleep(0.05)
        port = sock.getsockname()[1]
        shown = f"[{a.host}]" if ":" in a.host else a.host
        url = f"http://{shown}:{port}/" + (f"?token={token}" if token else "")
        print(f"cab-studio: serving {root.resolve()} at {url}", file=sys.stderr, flush=True)
        if token:
            print("cab-studio: the token above is printed only once; every request needs it (then a cookie)",
                  file=sys.stderr, flush=True)

    threading.Thread(target=announce, daemon=True).start()
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:  # pragma: no cover
        pass


def fail(message: str) -> NoReturn:
    """``cab-studio: <message>`` on stderr, exit status 2 (a mistake on the command line)."""
    print(f"cab-studio: {message}", file=sys.stderr)
    sys.exit(2)


def parse_port(text: str) -> int:
    """``--port``: an integer from 0 to 65535 (0: any free port), else one line and exit 2."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        fail(f"--port must be an integer from 0 to 65535 (0: any free port), got {text!r}")
    return port


def bind(host: str, port: int) -> socket.socket:
    """A socket bound to ``host``:``port`` (as uvicorn binds one: IPv6 when the host has a colon),
    handed to the server; a port in use, an address not of this machine or one that does not resolve
    is one line naming it and what to do, exit 2."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as e:
        sock.close()
        where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        if e.errno == errno.EADDRINUSE:
            fail(f"port {port} on {host} is in use (another cab-studio?): stop what listens there, or choose "
                 f"another port with --port (--port 0: any free port)")
        if e.errno == errno.EACCES:
            fail(f"not allowed to listen on {where} (ports below 1024 need privileges): choose another with --port")
        if isinstance(e, socket.gaierror):
            fail(f"--host {host!r} is not an address or a name that resolves ({e.strerror})")
        fail(f"cannot listen on {where}: {e.strerror or e} (--host: an address of this machine, e.g. 127.0.0.1)")
    sock.set_inheritable(True)
    return sock


if __name__ == "__main__":  # pragma: no cover
    main()
