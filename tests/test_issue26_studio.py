"""Issue 26, the studio's and the pages' part: cab-studio serves from an attempt folder only what its
page shows (decided on the resolved path: ``..`` however encoded, symbolic links pointing out), and
so does cab-view link; a bad ``--port``, a port in use and a host it cannot listen on are one line
each with exit status 2; a token with non-ASCII characters is refused (401), not an error (500); a
studio started on one sweep names its group, not ``.``; the attempt page says at which call a
latched subgoal was attained and where the margins were measured, in full; the report opens with its
summary table; the labels of a scatter figure do not overlap."""
from __future__ import annotations

import http.client
import json
import os
import re
import shutil
import socket
import subprocess
import sys
from html import unescape
from pathlib import Path
from urllib.parse import urljoin

import pytest
from test_studio import Server, fetch

from cab_core.analysis import figures as fg
from cab_core.analysis import report, viewer
from cab_core.analysis.attempts import Attempt
from cab_core.analysis.viewer import _margins
from cab_core.apps.studio.app import Studio
from cab_core.testing.task_conformance import _predicate_line

BIN = os.path.dirname(sys.executable)
TASK = "click_bell"


# ---------------------------------------------------------------------------------------------
# a hand-made tree: one sweep whose one attempt has observations, a video, records and privileged files
# ---------------------------------------------------------------------------------------------
def _attempt_folder(a: Path) -> None:
    (a / "observations").mkdir(parents=True)
    (a / "privileged").mkdir()
    start = {"kind": "attempt_start", "task": TASK, "config": {"model": "idle", "harness": "direct", "sim": "mujoco"}}
    (a / "events.jsonl").write_text(json.dumps(start) + "\n")
    (a / "result.json").write_text(json.dumps({"task": TASK, "model": "idle", "harness": "direct", "sim": "mujoco",
                                               "verdict": {"success": False}}))
    (a / "privileged" / "snapshots.jsonl").write_text('{"objects": {"bell": {"pose": [0.18, -0.04, 0.74]}}}\n')
    (a / "privileged" / "scene_info.json").write_text('{"info": {"secret": 1}}')
    (a / "cli.log").write_text("log\n")
    (a / "observations" / "obs_0001.png").write_bytes(b"\x89PNG observation")
    (a / "video.mp4").write_bytes(b"video")
    # symbolic links that point out of observations/: a file, a folder
    (a / "observations" / "obs_0002.png").symlink_to("../result.json")
    (a / "observations" / "more").symlink_to("../privileged", target_is_directory=True)


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    base = tmp_path_factory.mktemp("issue26-studio")
    root = base / "sweep-7"  # the studio is started on one sweep
    a = root / "a"
    _attempt_folder(a)
    (root / "sweep.json").write_text(json.dumps({"n_jobs": 1, "folders": ["a"]}))
    b = root / "b"  # an attempt whose observations/ itself is a link to another attempt's privileged files
    _attempt_folder(b)
    shutil.rmtree(b / "observations")
    (b / "observations").symlink_to("../a/privileged", target_is_directory=True)
    return root


@pytest.fixture(scope="module")
def studio(tree, tmp_path_factory):
    s = Server(tree, tmp_path_factory.mktemp("issue26-state"))
    try:
        yield s
    finally:
        s.stop()


def raw_get(base: str, path: str, headers: dict | None = None) -> int:
    """The status of GET ``path`` sent exactly as written (as ``curl --path-as-is``: no client
    normalises ``..`` away)."""
    host, port = base.split("//")[1].rsplit(":", 1)
    c = http.client.HTTPConnection(host, int(port), timeout=30)
    try:
        c.request("GET", path, headers=headers or {})
        r = c.getresponse()
        r.read()
        return r.status
    finally:
        c.close()


# the four URLs of the issue, and the other ways round the rule
TRAVERSALS = [
    "/attempt/a/observations/../result.json",
    "/attempt/a/observations/%2e%2e/privileged/snapshots.jsonl",
    "/attempt/a/observations/..%2fprivileged%2fscene_info.json",
    "/attempt/a/observations/%252e%252e%252fresult.json",  # double encoding
    "/attempt/a/observations/%2E%2E/cli.log",
    "/attempt/a/observations/%2e%2e%2f%2e%2e%2fsweep.json",
    "/attempt/a/observations/../observations/../events.jsonl",
    "/attempt/a/observations/obs_0002.png",  # a link in observations/ to result.json
    "/attempt/a/observations/more/snapshots.jsonl",  # a linked folder
    "/attempt/b/observations/snapshots.jsonl",  # observations/ itself a link
    "/attempt/a/%2e%2e/b/result.json",
    "/attempt/a/result.json",
    "/attempt/a/privileged/snapshots.jsonl",
]


@pytest.mark.parametrize("path", TRAVERSALS)
def test_an_attempts_records_and_privileged_files_are_never_served(studio, path):
    assert raw_get(studio.base, path) in (403, 404), path


def test_what_the_page_shows_is_served(studio):
    assert raw_get(studio.base, "/attempt/a/observations/obs_0001.png") == 200
    assert raw_get(studio.base, "/attempt/a/observations/../observations/obs_0001.png") == 200  # resolves inside
    assert raw_get(studio.base, "/attempt/a/video.mp4") == 200
    assert raw_get(studio.base, "/attempt/a/") == 200


def test_cab_view_links_only_files_its_page_may_show(tree):
    a = tree / "a"
    assert viewer.shown_file(a, "observations/obs_0001.png") == (a / "observations" / "obs_0001.png").resolve()
    assert viewer.shown_file(a, "video.mp4") == (a / "video.mp4").resolve()
    for rel in ("observations/../result.json", "observations/obs_0002.png", "observations/more/snapshots.jsonl",
                "privileged/scene_info.json", "observations/../../b/result.json", "observations/missing.png"):
        assert viewer.shown_file(a, rel) is None, rel
    assert viewer.shown_file(tree / "b", "observations/snapshots.jsonl") is None
    # an observation id in the records never makes the page link another file
    (a / "privileged" / "x.png").write_bytes(b"\x89PNG privileged")
    assert viewer._images(a, ["obs_0001", "../privileged/x", "obs_0002"]) == ["obs_0001"]


def test_a_studio_started_on_one_sweep_names_its_group(studio):
    status, body, _ = fetch(f"{studio.base}/api/tree")
    groups = json.loads(body)["groups"]
    assert status == 200 and [(g["rel"], g["name"]) for g in groups] == [(".", "sweep-7")]
    status, body, _ = fetch(f"{studio.base}/api/group?rel=.")
    assert status == 200 and json.loads(body)["name"] == "sweep-7"
    status, page, _ = fetch(f"{studio.base}/group?rel=.")
    assert status == 200 and re.search(r'<h1 id="title" data-rel=".">sweep-7</h1>', page), page
    assert "<title>sweep-7 · cab-studio</title>" in page
    status, page, _ = fetch(f"{studio.base}/play")
    assert status == 200 and '<option value=".">sweep-7</option>' in page


def test_the_root_group_of_cab_studio_dot_has_the_folders_name(tree, monkeypatch):
    monkeypatch.chdir(tree)
    s = Studio(Path("."), tree.parent / "state-dot")
    assert (s.group_name("."), s.group_name("a/b")) == ("sweep-7", "a/b")


# ---------------------------------------------------------------------------------------------
# the command line: one line, exit status 2
# ---------------------------------------------------------------------------------------------
def _studio_cmd(tree: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([os.path.join(BIN, "cab-studio"), str(tree), *args], capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("port", ["99999", "-1", "http"])
def test_a_port_out_of_range_is_one_line(tree, port):
    r = _studio_cmd(tree, "--port", port)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == f"cab-studio: --port must be an integer from 0 to 65535 (0: any free port), got {port!r}\n"


def test_a_port_in_use_is_one_line_with_a_hint(tree):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = _studio_cmd(tree, "--port", str(port))
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == (f"cab-studio: port {port} on 127.0.0.1 is in use (another cab-studio?): stop what listens "
                        "there, or choose another port with --port (--port 0: any free port)\n")


def test_a_host_it_cannot_listen_on_is_one_line(tree):
    r = _studio_cmd(tree, "--host", "no-such-host.invalid")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith(
        "cab-studio: --host 'no-such-host.invalid' is not an address or a name that resolves"), r.stderr


def test_a_non_ascii_token_is_refused_not_an_error(tree, tmp_path):
    s = Server(tree, tmp_path / "state", "--host", "0.0.0.0")
    try:
        token = re.search(r"token=([\w-]+)", s.url).group(1)
        base = "http://127.0.0.1:" + s.base.rsplit(":", 1)[1]
        assert raw_get(base, "/api/tree?token=%C3%A9t%C3%A9") == 401
        assert raw_get(base, "/api/tree", {"Authorization": "Bearer \u00e9t\u00e9"}) == 401
        assert raw_get(base, "/api/tree", {"Cookie": "cab_studio_token=%C3%A9"}) == 401
        assert raw_get(base, "/api/tree", {"Cookie": "cab_studio_token=\u00e9t\u00e9"}) == 401
        assert raw_get(base, f"/api/tree?token={token}") == 200
        # the traversals need the token first, and are refused with it too
        assert raw_get(base, "/attempt/a/observations/../result.json") == 401
        assert raw_get(base, "/attempt/a/observations/../result.json", {"Authorization": f"Bearer {token}"}) == 404
    finally:
        s.stop()


# ---------------------------------------------------------------------------------------------
# the pages of a real latched attempt (click_bell's oracle on MuJoCo)
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def latched(tmp_path_factory):
    out = tmp_path_factory.mktemp("issue26-latched") / "click"
    r = subprocess.run([os.path.join(BIN, "cab"), f"task={TASK}", "model=oracle", "sim=mujoco", f"hydra.run.dir={out}"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return out


def _cells(page: str, th: str) -> list[list[str]]:
    """The rows (cell texts) of the table whose header row has ``th``."""
    table = next(t for t in re.findall(r"<table>.*?</table>", page, re.S) if f"<th>{th}</th>" in t)
    return [[unescape(re.sub(r"<[^>]+>", "", c)) for c in re.findall(r"<td[^>]*>(.*?)</td>", row, re.S)]
            for row in re.findall(r"<tr>(.*?)</tr>", table, re.S)[1:]]


@pytest.mark.sim
def test_a_latched_subgoal_says_at_which_call(latched):
    r = json.loads((latched / "result.json").read_text())
    v = r["verdict"]
    assert v["scoring"] == "latch" and v["latch"]["latched"] and v["margins_at"] == "latch"
    sub = r["checkpoints"]["subgoals"][0]
    assert sub["attained"] and sub["first"]["calls"] is None  # credited to the latch event itself
    snaps = [json.loads(x) for x in (latched / "privileged" / "snapshots.jsonl").read_text().splitlines()]
    k = next(s["calls"] for s in snaps if s.get("latched"))
    page = viewer.render(Attempt.load(latched))
    rows = _cells(page, "first at call")
    assert rows[0][0] == "subgoal 1" and rows[0][3] == f"{k} (the event latched, physics step {v['latch']['at_step']})"
    assert all(row[3] != "None" and "None" not in row[3] for row in rows)
    # the timeline marks it after the charged call it was attained in
    mark = page.index('<div class="mark">✓ checkpoint subgoal 1: ')
    assert re.findall(r"charged call (\d+)", page[:mark])[-1] == str(k)
    step = v["margins_at_step"]
    assert (f"<p>margins measured at the latch: physics step {step}, where the latched event held widest "
            f"(it latched at step {v['latch']['at_step']})</p>") in page


@pytest.mark.sim
def test_margins_measured_at_the_final_state_say_so(latched, tmp_path):
    d = tmp_path / "final"
    shutil.copytree(latched, d, symlinks=True)
    r = json.loads((d / "result.json").read_text())
    r["verdict"].update(margins_at="final", margins_at_step=None)
    (d / "result.json").write_text(json.dumps(r))
    page = viewer.render(Attempt.load(d))
    assert "<p>margins measured at the final state (when the attempt ended)</p>" in page


@pytest.mark.sim
def test_the_report_opens_with_its_summary_table(latched, tmp_path):
    report.write(latched.parent, tmp_path, views=False)
    page = (tmp_path / "report.html").read_text()
    body = page[page.index("<body>"):]
    first_table, figures = body.index("<table>"), body.index("<h2>Figures</h2>")
    assert first_table < figures and "<svg" not in body[:first_table]
    assert re.search(r"<h1>cab report</h1>\s*<h2>Success and task coverage</h2><table>", body)
    md = (tmp_path / "report.md").read_text()
    assert md.startswith("# cab report\n\n## Success and task coverage\n") and md.index("## Figures") > md.index(
        "## Success and task coverage")
    # in a browser: the summary table is on the first screen, above every figure
    from browser import chromium

    driver = chromium(tmp_path, "1300,1000")
    try:
        driver.get((tmp_path / "report.html").as_uri())
        top, fig_top = driver.execute_script(
            "return [document.querySelector('table').getBoundingClientRect().top,"
            " document.querySelector('figure').getBoundingClientRect().top]")
    finally:
        driver.quit()
    assert top < 200 < fig_top, (top, fig_top)


# ---------------------------------------------------------------------------------------------
# the scatter figures: no label over another
# ---------------------------------------------------------------------------------------------
def _boxes(fig):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    ax = fig.axes[0]
    return ([fg.label_box(t, renderer) for t in ax.texts if t.get_text() != fg.NO_DATA],
            [line.get_window_extent(renderer) for line in ax.lines])


@pytest.mark.parametrize("points", [
    # two configurations at the same success rate and nearly the same median wall time (the case)
    [("oracle (direct, mujoco)", 3.1, 1.0), ("scripted (direct, mujoco)", 3.3, 1.0), ("idle (direct, mujoco)", 0.4, 0.0)],
    [("oracle (codeaction, sapien)", 12.0, 0.5), ("oracle (direct, sapien)", 12.0, 0.5)],  # the same point
    [(f"model-{i} (direct, mujoco)", 5.0 + 0.1 * i, 0.8 + 0.01 * i) for i in range(5)],
])
def test_scatter_labels_do_not_overlap(points):
    fig = fg.scatter("success_wall", "Success rate against median wall time", points, "median wall time (s)",
                     "success rate", xfmt=lambda x: f"{x:.1f} s")
    svg = fg.inline_svg(fig)  # laid out and saved as the report saves it
    labels, dots = _boxes(fig)
    assert len(labels) == len(points) == len(dots)
    frame = fig.axes[0].get_window_extent()
    for i, a in enumerate(labels):
        for j, b in enumerate(labels[i + 1:], i + 1):
            assert not a.overlaps(b), (points[i][0], points[j][0])
        for j, d in enumerate(dots):
            assert j == i or not a.overlaps(d), (points[i][0], "point", points[j][0])
        assert frame.x0 <= a.x0 and a.x1 <= frame.x1 + 1 and frame.y0 <= a.y0 and a.y1 <= frame.y1 + 1, points[i][0]
    again = fg.scatter("success_wall", "Success rate against median wall time", points, "median wall time (s)",
                       "success rate", xfmt=lambda x: f"{x:.1f} s")
    assert fg.inline_svg(again) == svg  # the same points, the same places, the same bytes


def test_a_margin_written_as_null_is_shown_not_measured():
    """A measurement that was not a finite number is null in a strict-JSON record
    (``non_finite_as_null``); the attempt page and the conformance message say so instead of failing."""
    m = {"slack": None, "scale": 0.04, "fraction": None, "unit": "m", "measured": None, "threshold": 0.04}
    rows = _margins({"margins": {"on_pad": m}})["rows"]
    assert rows == [{"name": "on_pad", "cls": "bad", "slack": "not measured", "fraction": "",
                     "measured": "", "threshold": "0.04"}]
    assert _predicate_line("on_pad", m) == "on_pad false: threshold 0.04 m, margin not measured"


def test_a_forks_links_lead_to_pages_each_serves(tree, tmp_path):
    """An attempt page links the attempt it was forked from: cab-view to that folder's view.html
    (a file it writes there), cab-studio to its own page of that attempt (it serves no view.html)."""
    c = tree / "c"
    c.mkdir()
    start = {"kind": "attempt_start", "task": TASK,
             "config": {"model": "idle", "harness": "direct", "sim": "mujoco", "fork": {"parent": "../a", "at": 1}}}
    (c / "events.jsonl").write_text(json.dumps(start) + "\n")
    try:
        assert 'class="fork-parent" href="../a/view.html"' in viewer.render_unfinished(c)
        s = Server(tree, tmp_path / "state")
        try:
            status, page, _ = fetch(s.base + "/attempt/c/")
            assert status == 200
            [href] = re.findall(r'class="fork-parent" href="([^"]+)"', page)
            assert href == "../a/"
            assert fetch(urljoin(s.base + "/attempt/c/", href))[0] == 200  # as a browser resolves it
        finally:
            s.stop()
    finally:
        shutil.rmtree(c)
