"""``cab-studio <dir>``: a local web application over any tree of attempt records.

Pages: the tree (every sweep and folder of attempts below ``<dir>``, with live progress), a
group's attempts, a group's report (the page ``cab-report`` writes, generated on demand into the
studio's state folder and served with links to the studio's attempt pages), an attempt's page (the
page ``cab-view`` writes, re-rendered as a running attempt grows), and the play page, where a person
plays an attempt through the same tools, prompt and budgets a model gets (:mod:`.play`,
:mod:`cab_core.attempt.human`); each played attempt runs in a child process of its own, so a
simulator's crash ends that play only, never the studio or its other plays. Docs: docs/studio.md.

It listens on loopback by default. Bound to any other address it requires a token, generated at
start and printed once: ``?token=`` on the first request (then a cookie), or the header
``Authorization: Bearer <token>``. A request whose ``Origin`` is another site is refused, and on
loopback so is a ``Host`` that is not a loopback name (DNS rebinding).
"""
from __future__ import annotations

import asyncio
import contextlib
import hashlib
import ipaddress
import json
import os
import secrets
import subprocess
import sys
import threading
from html import escape
from pathlib import Path
from urllib.parse import quote, urlsplit

from jinja2 import FileSystemLoader
from markupsafe import Markup
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import (FileResponse, HTMLResponse, JSONResponse, PlainTextResponse, RedirectResponse,
                                 Response)
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.templating import Jinja2Templates

from cab_core.analysis import pages, viewer
from cab_core.analysis.records import Attempt
from cab_core.apps.studio import tree
from cab_core.apps.studio.play import PLAYED, Plays, installed
from cab_core.errors import AttemptEnded, CabError

HERE = Path(__file__).resolve().parent  # the real folder (an editable install links each file)
COOKIE = "cab_studio_token"
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
#: images of only the most recent image-bearing results stay visible, as under the reference
#: harness's context policy (``max_image_rounds``); older ones are named by id
MAX_IMAGE_ROUNDS = 2
#: files of an attempt folder the studio serves (what its page shows): nothing privileged
SERVED = ("observations/", "video.mp4")


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
        if given is not None and secrets.compare_digest(given, self.token):
            return True, True
        auth = request.headers.get("authorization", "")
        if auth.lower().startswith("bearer ") and secrets.compare_digest(auth[7:].strip(), self.token):
            return True, False
        cookie = request.cookies.get(COOKIE)
        return cookie is not None and secrets.compare_digest(cookie, self.token), False

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
                r = subprocess.run([sys.executable, "-c", "from cab_core.analysis.report import main; main()",
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
        items = [("cab-studio", "/")] + ([(group, f"/group?rel={quote(group)}")] if group is not None else []) + trail
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
                page = viewer.render(Attempt.load(d, d.parent))
            except CabError as e:
                note = f"<p class='bad'>{escape(str(e))}</p>"
                page = viewer.render_unfinished(d)
        else:
            page = viewer.render_unfinished(d)
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
    studio = Studio(root, state_dir)
    T = studio.templates

    def page(request: Request, name: str, **ctx) -> Response:
        return T.TemplateResponse(request, name, {"root": studio.shown, **ctx})

    def home(request: Request):
        return page(request, "tree.html")

    def api_tree(request: Request):
        gs = tree.groups(studio.root)
        plays = [p.status() for p in studio.plays.plays.values()]
        return JSONResponse({"root": studio.shown, "groups": [g.as_dict(attempts=False) for g in gs],
                             "plays": plays})

    def group_page(request: Request):
        rel = request.query_params.get("rel", ".")
        return page(request, "group.html", rel=rel)

    def api_group(request: Request):
        rel = request.query_params.get("rel", ".")
        g = tree.group(studio.root, rel)
        if g is None:
            return JSONResponse({"error": f"no sweep or folder of attempts at {rel!r}"}, 404)
        return JSONResponse(g.as_dict())

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
        if studio.plays.playing(d) or not any(rest == s or (s.endswith("/") and rest.startswith(s)) for s in SERVED):
            return PlainTextResponse("not served", 404)
        f = (d / rest).resolve()
        if not f.is_relative_to(d) or not f.is_file():
            return PlainTextResponse("not found", 404)
        return FileResponse(f)

    def api_stamp(request: Request):
        found = studio.attempt_of(request.query_params.get("rel", ""))
        if found is None:
            return JSONResponse({"error": "no attempt"}, 404)
        d = found[0]
        playing = studio.plays.playing(d)
        return JSONResponse({"finished": (d / "result.json").exists() and not playing, "playing": playing,
                             "stamp": studio.stamp(d)})

    def play_form(request: Request, error: str | None = None, form: dict | None = None, status: int = 200):
        choices = installed()
        targets = [PLAYED] + [g.rel for g in tree.groups(studio.root) if g.rel != PLAYED]
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

    routes = [
        Route("/", home), Route("/api/tree", api_tree), Route("/group", group_page), Route("/api/group", api_group),
        Route("/report", report_page), Route("/attempt/{path:path}", attempt), Route("/api/stamp", api_stamp),
        Route("/play", play_form, methods=["GET"]), Route("/play", play_start, methods=["POST"]),
        Route("/play/{pid}", play_page), Route("/api/play/{pid}", api_play),
        Route("/api/play/{pid}/call", api_call, methods=["POST"]),
        Route("/play/{pid}/image/{obs}.png", play_image),
        Mount("/static", StaticFiles(directory=str(HERE / "static")), name="static"),
    ]
    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        await asyncio.to_thread(studio.plays.stop)  # a play still running is recorded as interrupted

    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.studio = studio
    return Guard(app, token, loopback)  # type: ignore[return-value]


def main(argv: list[str] | None = None) -> None:
    import argparse
    import logging

    ap = argparse.ArgumentParser(prog="cab-studio", description="A local web application over a tree of attempt "
                                 "records: live progress of sweeps, their reports, each attempt's page, and "
                                 "attempts played by a person (docs/studio.md).")
    ap.add_argument("dir", help="a folder of records: a sweep, outputs/, multirun/, any tree of attempt folders")
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; any other "
                                                         "address requires the token printed at start)")
    ap.add_argument("--port", type=int, default=8765, help="port (default 8765; 0: any free port)")
    ap.add_argument("--state-dir", help="where the studio keeps its reports (default ~/.cache/cab-studio/<root hash>)")
    a = ap.parse_args(argv)
    root = Path(a.dir)
    if not root.is_dir():
        print(f"cab-studio: {root} is not a directory", file=sys.stderr)
        sys.exit(2)
    loopback = is_loopback(a.host)
    token = None if loopback else secrets.token_urlsafe(24)
    import uvicorn

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    app = build_app(root, Path(a.state_dir) if a.state_dir else None, token, loopback)
    config = uvicorn.Config(app, host=a.host, port=a.port, log_level="warning", lifespan="on")
    server = uvicorn.Server(config)

    def announce():  # once the socket is bound (port 0: the port it got)
        import time

        while not server.started:
            if server.should_exit:
                return
            time.sleep(0.05)
        port = server.servers[0].sockets[0].getsockname()[1] if server.servers else a.port
        shown = f"[{a.host}]" if ":" in a.host else a.host
        url = f"http://{shown}:{port}/" + (f"?token={token}" if token else "")
        print(f"cab-studio: serving {root.resolve()} at {url}", file=sys.stderr, flush=True)
        if token:
            print("cab-studio: the token above is printed only once; every request needs it (then a cookie)",
                  file=sys.stderr, flush=True)

    threading.Thread(target=announce, daemon=True).start()
    try:
        server.run()
    except KeyboardInterrupt:  # pragma: no cover
        pass


if __name__ == "__main__":  # pragma: no cover
    main()
