"""cab-studio: the groups and progress it reads from records (hand-made folders), the token and the
request guards (a real server, an HTTP client), the human agent refused outside the studio, a play
whose process is killed ending that play only (the studio's plays, without a browser); then, in
headless Chromium, a tiny MuJoCo sweep listed and updated live while an attempt of it runs, a person
playing ``click_bell`` to success through the play page's forms (a pixel filled by clicking an image,
a run_code program, done), the result on its attempt page (images, video) and in the sweep's
report, and the person's records compared with a scripted agent's making the same calls.

Screenshots of the tree, the play page and an attempt page go to ``$CAB_STUDIO_SCREENSHOTS`` when it
is set (docs/studio/ was made so), else to the test's temporary folder."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from browser import chromium

from cab_core.apps.studio import tree
from cab_core.apps.studio.play import Plays
from cab_core.errors import AttemptEnded, ConfigError
from cab_core.kits.harness.prompts import first_user_message, system_prompt
from cab_core.plugins import create, task_info
from cab_core.tools import TOOLS
from cab_core.tools.motion import HARNESS_PARAMETERS

BIN = os.path.dirname(sys.executable)
TASK = "click_bell"


# ---------------------------------------------------------------------------------------------
# the tree, from hand-made records
# ---------------------------------------------------------------------------------------------
def _attempt(d: Path, result: dict | None = None, model: str = "idle") -> None:
    d.mkdir(parents=True)
    start = {"kind": "attempt_start", "task": TASK, "config": {"model": model, "harness": "direct", "sim": "mujoco"}}
    (d / "events.jsonl").write_text(json.dumps(start) + "\n")
    if result is not None:
        (d / "result.json").write_text(json.dumps({"task": TASK, "model": model, "harness": "direct", "sim": "mujoco",
                                                   **result}))


def test_groups_and_progress_from_the_files(tmp_path):
    sweep = tmp_path / "multirun" / "s1"
    folders = [f"{TASK}/idle/mujoco/seed-0/attempt-{i}" for i in (1, 2, 3, 4, 5)]
    sweep.mkdir(parents=True)
    started = time.time() - 100
    (sweep / "sweep.json").write_text(json.dumps({"n_jobs": 5, "folders": folders, "sessions": [{"started": started}]}))
    _attempt(sweep / folders[0], {"verdict": {"success": True}})
    _attempt(sweep / folders[1], {"verdict": {"success": False}})
    _attempt(sweep / folders[2])  # running
    _attempt(sweep / folders[3], {"verdict": {"success": False}, "infrastructure": {"failed": True},
                                  "termination": {"reason": "infrastructure_failure"}})
    _attempt(sweep / f"{TASK}/human/mujoco/seed-0/attempt-1", {"verdict": {"success": True}}, "human")  # not planned
    (sweep / folders[0] / "set_aside" / "01-interrupted").mkdir(parents=True)  # never an attempt of its own
    _attempt(sweep / folders[0] / "set_aside" / "01-interrupted" / "x")
    _attempt(tmp_path / "outputs" / TASK / "oracle" / "mujoco" / "t1", {"verdict": {"success": True}}, "oracle")
    _attempt(tmp_path / "outputs" / TASK / "oracle" / "mujoco" / "t2")
    _attempt(tmp_path / "loose", {"verdict": {"success": False}})
    _attempt(tmp_path / ".hidden" / "a", {"verdict": {"success": True}})
    gs = {g.rel: g for g in tree.groups(tmp_path, now=time.time())}
    assert sorted(gs) == [".", "multirun/s1", "outputs"]
    s = gs["multirun/s1"]
    assert (s.kind, s.planned, s.done, s.success, s.running, s.infra, s.not_started, s.extra) == (
        "sweep", 5, 3, 2, 1, 1, 1, 1)
    # 3 planned jobs finished (2 done, 1 infra) in the 100 s of this session; 2 left (1 running, 1 not started)
    assert s.eta_s == pytest.approx(2 * 100 / 3, rel=0.05)
    states = {a.rel: a.state for a in s.attempts}
    assert states[folders[2]] == "running" and states[folders[3]] == "infra"
    assert [a.config for a in s.attempts if a.rel.startswith(f"{TASK}/human")] == ["human (direct, mujoco)"]
    o = gs["outputs"]
    assert (o.kind, o.planned, o.done, o.success, o.running) == ("folder", None, 1, 1, 1)
    assert (gs["."].done, gs["."].attempts[0].rel) == (1, "loose")
    # a running attempt whose log stopped growing long ago is marked stale
    later = {a.rel: a for a in tree.groups(tmp_path, now=time.time() + tree.STALE_S + 5)[1].attempts}
    assert later[folders[2]].stale


def test_the_human_agent_is_refused_outside_the_studio():
    with pytest.raises(ConfigError, match="cab-studio"):
        create("agents", "human", {"name": "human", "agent": "human", "handle": "ada", "session": None})


# ---------------------------------------------------------------------------------------------
# each play in a process of its own: a crash ends that play only
# ---------------------------------------------------------------------------------------------
def _until(cond, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")


def _ready(play, timeout: float = 300.0) -> None:
    _until(lambda: play.bridge.ready.is_set() or play.state == "failed", timeout, "the attempt to be ready")
    assert play.bridge.ready.is_set(), play.status()


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a process not yet reaped (a zombie is dead)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


@pytest.mark.sim
def test_a_crashed_plays_process_ends_only_that_play(tmp_path):
    """A play's process killed (as a simulator's segfault would end it) after a call: the call it was
    sent and not yet answered, and every later one, are answered that its process ended unexpectedly,
    and the play is failed; the studio's next play runs to done and writes its records; stopping the
    studio ends a play still running as interrupted."""
    plays = Plays(tmp_path)
    first = plays.start(TASK, "mujoco", None, "crash-test")
    try:
        assert first.pid is not None and first.pid != os.getpid() and _alive(first.pid)
        _ready(first)
        head = first.bridge.submit("capture_head", {}).result(120)
        assert not head.ended and "error" not in head.payload and head.images, head.payload
        os.kill(first.pid, signal.SIGSTOP)  # a call sent while the process cannot answer it is waiting when it dies
        waiting = first.bridge.submit("capture_head", {})
        assert not waiting.done()
        os.kill(first.pid, signal.SIGKILL)
        answer = waiting.result(60)
        error = ("the simulator process ended unexpectedly (exit code -9, killed by SIGKILL); the attempt has ended, "
                 "its records stop where the process died")
        assert (answer.tool, answer.payload, answer.ended, answer.images) == (
            "capture_head", {"error": error, "attempt_ended": True}, True, [])
        first.thread.join(60)
        assert not first.thread.is_alive() and first.exit_code == -signal.SIGKILL
        status = first.status()
        assert (status["state"], status["error"], status["ended"], status["calls"]) == ("failed", error, True, 1)
        again = first.bridge.submit("done", {"report": "x", "success_claim": False}).result(5)  # later calls too
        assert again.payload == {"error": error, "attempt_ended": True} and again.ended
        assert not (first.folder / "result.json").exists() and not plays.playing(first.folder)

        second = plays.start(TASK, "mujoco", None, "after-the-crash")
        assert second.pid != first.pid and second.folder.name == "attempt-2"
        _ready(second)
        head = second.bridge.submit("capture_head", {}).result(120)
        assert not head.ended and "error" not in head.payload and [oid for oid, _ in head.images] == [
            head.payload["obs_id"]] and head.images[0][1].startswith(b"\x89PNG"), head.payload
        end = second.bridge.submit("done", {"report": "looked once", "success_claim": False}).result(120)
        assert end.ended and "error" not in end.payload, end.payload
        second.thread.join(60)
        assert (second.state, second.error, second.exit_code) == ("finished", None, 0)
        r = json.loads((second.folder / "result.json").read_text())
        assert (r["model"], r["harness"], r["sim"], r["termination"]["reason"]) == ("human", "direct", "mujoco", "done")
        assert r["agent"]["client"] == {"name": "after-the-crash", "version": "cab-studio", "session": 1}
        assert r["budget"]["tool_calls_used"] == 1 and r["verdict"]["success"] is False  # done is not charged
        with pytest.raises(AttemptEnded):  # the attempt ended normally: no more calls
            second.bridge.submit("capture_head", {})

        third = plays.start(TASK, "mujoco", None, "left-playing")
        _ready(third)
        plays.stop()
        assert not third.thread.is_alive() and third.exit_code == 0 and not _alive(third.pid)
        r = json.loads((third.folder / "result.json").read_text())
        assert (third.state, r["termination"]["reason"]) == ("finished", "interrupted")
    finally:
        plays.stop(5)


# ---------------------------------------------------------------------------------------------
# a real server
# ---------------------------------------------------------------------------------------------
class Server:
    """``cab-studio`` in its own process; ``url`` as it printed it (with the token when there is one)."""

    def __init__(self, root: Path, state: Path, *args: str):
        self.log = state / "studio.log"
        state.mkdir(parents=True, exist_ok=True)
        # started beside the root and given its name, as a person types ``cab-studio runs``: the pages
        # (and the screenshots in the docs) show that name, not the test's temporary folder
        self.proc = subprocess.Popen([os.path.join(BIN, "cab-studio"), root.name, "--port", "0", "--state-dir",
                                      str(state), *args], cwd=root.parent, stdout=subprocess.DEVNULL,
                                     stderr=open(self.log, "w"), start_new_session=True)
        deadline = time.time() + 60
        while time.time() < deadline:
            m = re.search(r"at (http://\S+)", self.log.read_text())
            if m:
                self.url = m.group(1)
                self.base = self.url.split("?")[0].rstrip("/")
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.2)
        self.stop()
        raise AssertionError(f"cab-studio did not start: {self.log.read_text()}")

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def fetch(url: str, headers: dict | None = None, data: bytes | None = None) -> tuple[int, str, dict]:
    req = urllib.request.Request(url, headers=headers or {}, data=data)
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, r.read().decode(), dict(r.headers)
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode(), dict(e.headers)


def test_a_token_is_required_off_loopback(tmp_path):
    _attempt(tmp_path / "root" / "a", {"verdict": {"success": True}})
    s = Server(tmp_path / "root", tmp_path / "state", "--host", "0.0.0.0")
    try:
        log = s.log.read_text()
        token = re.search(r"token=([\w-]+)", s.url).group(1)
        assert log.count(token) == 1, "the token is printed once"
        port = s.base.rsplit(":", 1)[1]
        base = f"http://127.0.0.1:{port}"
        assert fetch(f"{base}/api/tree")[0] == 401
        assert fetch(f"{base}/api/tree?token=wrong")[0] == 401
        assert fetch(f"{base}/api/tree", {"Authorization": "Bearer wrong"})[0] == 401
        status, body, headers = fetch(f"{base}/api/tree?token={token}")
        assert status == 200 and json.loads(body)["groups"][0]["rel"] == "."
        cookie = headers["set-cookie"].split(";")[0]
        assert "HttpOnly" in headers["set-cookie"]
        assert fetch(f"{base}/api/tree", {"Cookie": cookie})[0] == 200
        assert fetch(f"{base}/", {"Authorization": f"Bearer {token}"})[0] == 200
        assert fetch(f"{base}/attempt/a/", {"Authorization": f"Bearer {token}"})[0] == 200
    finally:
        s.stop()


def test_loopback_needs_no_token_but_refuses_other_hosts_and_sites(tmp_path):
    _attempt(tmp_path / "root" / "a", {"verdict": {"success": True}})
    s = Server(tmp_path / "root", tmp_path / "state")
    try:
        assert "token" not in s.url and s.base.startswith("http://127.0.0.1:")
        assert fetch(f"{s.base}/api/tree")[0] == 200
        assert fetch(f"{s.base}/api/tree", {"Host": "attacker.example"})[0] == 403  # DNS rebinding
        status, _, _ = fetch(f"{s.base}/play", {"Origin": "http://attacker.example"}, b"task=click_bell")
        assert status == 403  # a form posted by another site
        assert fetch(f"{s.base}/attempt/../../etc/passwd")[0] == 404
        assert fetch(f"{s.base}/attempt/a/result.json")[0] == 404  # only what the page shows is served
        status, body, _ = fetch(f"{s.base}/play", {"Origin": s.base}, b"task=click_bell&sim=mujoco&handle=&into=played")
        assert status == 400 and "handle" in body
    finally:
        s.stop()


# ---------------------------------------------------------------------------------------------
# in a browser: a tiny MuJoCo sweep, a person playing click_bell
# ---------------------------------------------------------------------------------------------
def sweep_cmd(root: Path) -> list[str]:
    return [os.path.join(BIN, "cab"), "-m", f"task={TASK}", "model=idle,oracle", "sim=mujoco", "attempt=1,2",
            f"hydra.sweep.dir={root}"]


def shot(driver, name: str, tmp: Path) -> Path:
    folder = Path(os.environ.get("CAB_STUDIO_SCREENSHOTS") or tmp)
    folder.mkdir(parents=True, exist_ok=True)
    driver.execute_script("window.scrollTo(0, 0)")
    path = folder / f"{name}.png"
    driver.save_screenshot(str(path))
    return path


def wait(driver, cond, timeout: float = 60, what: str = ""):
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.support.ui import WebDriverWait

    # a live page reloads itself when its records change: an element found just before is then stale
    return WebDriverWait(driver, timeout, poll_frequency=0.25,
                         ignored_exceptions=(StaleElementReferenceException,)).until(cond, what)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """A sweep of idle and oracle x 2 attempts on MuJoCo with one idle attempt removed (planned, not
    started), cab-studio over its parent folder, and a browser."""
    base = tmp_path_factory.mktemp("studio")
    root = base / "records"
    sweep = root / "sweep"
    r = subprocess.run(sweep_cmd(sweep), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    shutil.rmtree(sweep / TASK / "idle" / "mujoco" / "seed-0" / "attempt-2")
    server = Server(root, base / "state")
    driver = chromium(base, "1400,1100", "--autoplay-policy=no-user-gesture-required")
    try:
        yield {"base": base, "root": root, "sweep": sweep, "server": server, "driver": driver}
    finally:
        driver.quit()
        server.stop()


def cells(driver, rel: str) -> dict[str, str]:
    return driver.execute_script(
        "const r = document.querySelector(`#groups tr[data-rel='${arguments[0]}']`); if (!r) return null;"
        "return Object.fromEntries([...r.children].map(c => [c.className || 'name', c.innerText.trim()]));", rel)


@pytest.mark.sim
def test_the_tree_lists_the_sweep_and_follows_a_running_attempt(site, tmp_path):
    driver, sweep = site["driver"], site["sweep"]
    driver.get(site["server"].url)
    wait(driver, lambda d: cells(d, "sweep") is not None, 30, "the sweep's row")
    row = cells(driver, "sweep")
    assert (row["kind"], row["done"], row["success"], row["running"], row["not_started"], row["planned"]) == (
        "sweep", "3", "2", "0", "1", "4")
    # the sweep is run again: it resumes with the one attempt left, while the page is open
    proc = subprocess.Popen(sweep_cmd(sweep), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait(driver, lambda d: (cells(d, "sweep") or {}).get("done") == "4", 300, "the count to reach 4")
    finally:
        _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-3000:]
    row = cells(driver, "sweep")
    assert (row["not_started"], row["running"], row["eta"]) == ("0", "0", "–")
    shot(driver, "tree", tmp_path)
    # the group's page lists the attempts, linked to their pages
    driver.find_element("css selector", "#groups tr[data-rel='sweep'] a.group-link").click()
    wait(driver, lambda d: len(d.find_elements("css selector", "#attempts tbody tr")) == 4, 30, "4 attempts")


@pytest.mark.sim
def test_a_running_attempts_page_grows_with_its_records(site):
    """An attempt's records written as a running attempt writes them (the oracle's, copied line by
    line): its open page shows each new call, then the verdict once result.json appears."""
    driver = site["driver"]
    src = site["sweep"] / TASK / "oracle" / "mujoco" / "seed-0" / "attempt-1"
    d = site["root"] / "live" / "oracle-copy"
    (d / "observations").mkdir(parents=True)
    lines = (src / "events.jsonl").read_text().splitlines(keepends=True)
    (d / "events.jsonl").write_text("".join(lines[:2]))  # attempt_start, capture_head
    shutil.copy(src / "observations" / "obs_0001.png", d / "observations")
    driver.get(f"{site['server'].base}/attempt/live/oracle-copy/")
    calls_so_far = ("return [...document.querySelectorAll('th')].find(t => t.textContent === 'tool calls so far')"
                    "?.nextElementSibling.textContent")
    assert driver.execute_script(calls_so_far) == "1"
    with open(d / "events.jsonl", "a") as f:
        f.write("".join(lines[2:4]))  # set_gripper, reach_tcp
    wait(driver, lambda d: d.execute_script(calls_so_far) == "3", 30, "the page to show 3 calls")
    assert "reach_tcp" in driver.find_element("tag name", "body").text
    with open(d / "events.jsonl", "a") as f:
        f.write("".join(lines[4:]))
    for name in ("video.mp4", "result.json"):  # result.json last, as an attempt writes it
        shutil.copy(src / name, d / name)
    wait(driver, lambda d: "verdict" in [t.text for t in d.find_elements("tag name", "th")], 30, "the finished page")
    assert "success" in driver.find_element("tag name", "body").text
    assert driver.find_element("tag name", "video")


def oracle_calls(sweep: Path) -> list[dict]:
    d = sweep / TASK / "oracle" / "mujoco" / "seed-0" / "attempt-1"
    return [e for e in map(json.loads, (d / "events.jsonl").read_text().splitlines()) if e.get("kind") == "call"]


def choose(driver, tool: str) -> None:
    from selenium.webdriver.support.ui import Select

    Select(driver.find_element("id", "tool")).select_by_value(tool)
    wait(driver, lambda d: d.find_element("id", "tool-description").text.strip() != "", 10)


def fill(driver, name: str, value: str) -> None:
    from selenium.webdriver.support.ui import Select

    f = driver.find_element("id", f"arg-{name}")
    if f.tag_name == "select":
        Select(f).select_by_value(value)
    else:
        f.clear()
        f.send_keys(value)


def call(driver, expect_results: int) -> dict:
    driver.find_element("id", "call").click()
    wait(driver, lambda d: len(d.find_elements("css selector", "#results .result")) == expect_results, 180,
         f"result {expect_results}")
    card = driver.find_element("css selector", "#results .result")  # the newest is on top
    return json.loads(card.find_element("css selector", "pre.payload").text)


@pytest.fixture(scope="module")
def played(site):
    """A person plays click_bell through the forms, knowing from the oracle's record which calls
    succeed: captures the head image, clicks a pixel of it for ``ray``, closes the gripper, presses
    the knob with a run_code program, calls done."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.ui import Select

    driver, base = site["driver"], site["server"].base
    calls = {e["tool"]: e["arguments"] for e in oracle_calls(site["sweep"])}
    reach = calls["reach_tcp"]
    arm = reach["arm"]
    driver.get(f"{base}/play")
    Select(driver.find_element("id", "task")).select_by_value(TASK)
    Select(driver.find_element("id", "sim")).select_by_value("mujoco")
    driver.find_element("id", "handle").send_keys("test-person")
    Select(driver.find_element("id", "into")).select_by_value("sweep")
    driver.find_element("id", "start").click()
    wait(driver, lambda d: d.find_elements("css selector", "#tool option"), 180, "the attempt to be ready")
    out = {"prompt": driver.find_element("id", "system-prompt").text,
           "instruction": driver.find_element("id", "instruction").text,
           "budget0": driver.find_element("id", "calls-left").text, "tools": len(driver.find_elements("css selector", "#tool option"))}
    choose(driver, "capture_head")
    head = call(driver, 1)
    img = wait(driver, lambda d: d.find_element("css selector", "#results img.obs"), 30)
    wait(driver, lambda d: d.execute_script("return arguments[0].naturalWidth", img) > 0, 30, "the image to load")
    out["budget1"] = driver.find_element("id", "calls-left").text
    folder = f"{site['server'].base}/attempt/sweep/{TASK}/human/mujoco/seed-0/attempt-1/"
    out["while_played"] = (fetch(folder)[1], fetch(folder + "observations/obs_0001.png")[0])
    # ray from a clicked pixel: the form's obs_id and px are filled by the click
    choose(driver, "ray")
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", img)  # all of it in view
    ActionChains(driver).move_to_element_with_offset(img, 0, 0).click().perform()  # the image's centre
    out["clicked"] = {"obs_id": driver.find_element("id", "arg-obs_id").get_attribute("value"),
                      "px": driver.find_element("id", "arg-px").get_attribute("value")}
    out["ray"] = call(driver, 2)
    out["screenshot"] = shot(driver, "play", site["base"])  # the prompt, the forms, the image clicked
    choose(driver, "set_gripper")
    fill(driver, "arm", arm)
    fill(driver, "pos", "0")
    out["grip"] = call(driver, 3)
    choose(driver, "run_code")
    program = (f"r = reach_tcp(arm={arm!r}, target_xyz={reach['target_xyz']!r}, target_quat={reach['target_quat']!r})\n"
               f"m = move_delta(arm={arm!r}, dz=-0.065)\n"
               f"u = move_delta(arm={arm!r}, dz=0.06)\n"
               "result = [r['status'], m['status'], u['status']]\n")
    fill(driver, "code", program)
    out["program"] = program
    out["run_code"] = call(driver, 4)
    out["budget4"] = driver.find_element("id", "calls-left").text
    choose(driver, "done")
    fill(driver, "report", "pressed the knob with the closed gripper")
    fill(driver, "success_claim", "true")
    driver.find_element("id", "call").click()
    wait(driver, lambda d: "/attempt/sweep/" in d.current_url, 180, "the result page")
    out["result_url"] = driver.current_url
    out["head"] = head
    out["dir"] = site["sweep"] / TASK / "human" / "mujoco" / "seed-0" / "attempt-1"
    return out


@pytest.mark.sim
def test_a_person_plays_click_bell_to_success(site, played):
    d = played["dir"]
    r = json.loads((d / "result.json").read_text())
    # what the page showed: the prompt every harness gives, the budgets, every tool
    limit = r["budget"]["tool_calls_limit"]
    budget = {"tool_calls_limit": limit, "sim_seconds_limit": r["budget"]["sim_seconds_limit"]}
    assert played["prompt"] == system_prompt(budget, HARNESS_PARAMETERS).strip()
    assert played["instruction"] == first_user_message(task_info(TASK).instruction)
    assert played["tools"] == len(TOOLS)
    assert played["budget0"] == f"tool calls left: {limit} / {limit}"
    assert played["budget1"] == f"tool calls left: {limit - 1} / {limit}"
    assert played["budget4"] == f"tool calls left: {limit - 4} / {limit}"
    assert played["clicked"]["obs_id"] == played["head"]["obs_id"]  # the image's centre, in its own pixels
    u, v = (int(x) for x in played["clicked"]["px"].split(","))
    assert abs(u - 320) <= 2 and abs(v - 240) <= 2
    assert played["ray"]["valid"] is True
    page, image = played["while_played"]  # nothing of the attempt is shown beside the play page while it runs
    assert "being played" in page and "obs_0001" not in page and image == 404
    assert played["run_code"]["ok"] and played["run_code"]["value"] == ["SUCCESS", "SUCCESS", "SUCCESS"]
    # the record: the human agent, the person's handle, the verifier's success
    assert (r["model"], r["harness"], r["sim"]) == ("human", "direct", "mujoco")
    assert r["agent"] == {"kind": "human", "named_by": "config", "client": {"name": "test-person",
                          "version": "cab-studio", "session": 1},
                          "clients": [{"name": "test-person", "version": "cab-studio", "session": 1}]}
    assert r["verdict"]["success"] is True and r["claim"]["success_claim"] is True
    assert r["termination"]["reason"] == "done" and r["budget"]["tool_calls_used"] == 4
    # the result page the person was taken to
    driver = site["driver"]
    assert played["result_url"].endswith(f"/attempt/sweep/{TASK}/human/mujoco/seed-0/attempt-1/")
    assert "human (direct, mujoco)" in driver.find_element("tag name", "body").text


@pytest.mark.sim
def test_the_attempt_page_shows_images_and_video(site, played, tmp_path):
    driver = site["driver"]
    driver.get(played["result_url"])
    imgs = driver.find_elements("css selector", "img.obs")
    assert imgs, "no observation image on the page"
    wait(driver, lambda d: all(d.execute_script("return arguments[0].naturalWidth", i) > 0 for i in imgs), 30,
         "the images to load")
    video = driver.find_element("tag name", "video")
    fetched = driver.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        "fetch(arguments[0].src).then(r => r.blob().then(b => done([r.status, r.headers.get('content-type'), b.size])));",
        video)
    assert fetched[0] == 200 and fetched[1] == "video/mp4" and fetched[2] > 1000
    if driver.execute_script("return arguments[0].canPlayType('video/mp4')", video):  # H.264 in this chromium
        wait(driver, lambda d: d.execute_script("return arguments[0].readyState", video) >= 1, 30, "video metadata")
        assert driver.execute_script("return arguments[0].duration", video) > 0
    shot(driver, "attempt", tmp_path)


@pytest.mark.sim
def test_the_result_is_in_the_sweeps_report(site, played, tmp_path):
    driver = site["driver"]
    driver.get(f"{site['server'].base}/report?rel=sweep")
    rows = driver.execute_script(
        "const h = [...document.querySelectorAll('h2')].find(e => e.textContent === 'Attempts');"
        "return [...h.nextElementSibling.querySelectorAll('tr')].slice(1).map(r => [...r.children].map(c => c.innerText.trim()));")
    human = [r for r in rows if r[1] == "human (direct, mujoco)"]
    assert len(human) == 1 and human[0][0] == f"{TASK}/human/mujoco/seed-0/attempt-1" and human[0][2] == "yes"
    assert len(rows) == 5  # the sweep's 4 attempts and the played one
    shot(driver, "report", tmp_path)
    link = driver.find_element("xpath", f"//a[text()='{TASK}/human/mujoco/seed-0/attempt-1']")
    link.click()
    assert driver.current_url == played["result_url"]
    # the tree counts the played attempt as one beside the sweep's plan, and lists the play
    driver.get(site["server"].url)
    wait(driver, lambda d: (cells(d, "sweep") or {}).get("extra") == "1", 30, "the played attempt counted")
    assert cells(driver, "sweep")["done"] == "5" and cells(driver, "sweep")["not_started"] == "0"
    wait(driver, lambda d: "test-person" in d.find_element("id", "plays").text, 10)
    shot(driver, "tree", tmp_path)


def _shape(x):
    """The structure of a JSON value: its keys, recursively, with the types of its leaves."""
    if isinstance(x, dict):
        return {k: _shape(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_shape(v) for v in x[:1]]
    return type(x).__name__


@pytest.mark.sim
def test_a_persons_records_have_the_shape_of_any_agents(site, played, tmp_path):
    """The scripted agent makes the person's calls: the same event kinds in the same order, the same
    calls and verdict; the records differ only in who played."""
    from attempt_records import run_one

    d = played["dir"]
    events = [json.loads(x) for x in (d / "events.jsonl").read_text().splitlines()]
    script = [{"tool": e["tool"], "args": e.get("arguments") or {}} for e in events if e["kind"] == "call"]
    (tmp_path / "script.json").write_text(json.dumps(script))
    out = tmp_path / "scripted"
    run_one(out, TASK, "scripted", 1, "sim=mujoco", f"model.script={tmp_path / 'script.json'}")
    theirs = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    assert [e["kind"] for e in events] == [e["kind"] for e in theirs]
    assert [(e.get("tool"), e.get("arguments")) for e in events] == [(e.get("tool"), e.get("arguments")) for e in theirs]
    mine, other = json.loads((d / "result.json").read_text()), json.loads((out / "result.json").read_text())
    assert set(mine) - set(other) == {"agent"} and set(other) <= set(mine)
    assert _shape(mine["verdict"]) == _shape(other["verdict"])
    assert mine["verdict"]["success"] == other["verdict"]["success"] is True
    assert _shape(mine["checkpoints"]) == _shape(other["checkpoints"])
    assert (mine["model"], other["model"]) == ("human", "scripted")
    assert sorted(p.name for p in (d / "observations").iterdir()) == sorted(p.name for p in (out / "observations").iterdir())
