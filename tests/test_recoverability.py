"""cab-report --recoverability: the fork points and figures on hand-made records (shares computed by
hand), then a tiny MuJoCo sweep of a scripted agent that fails (and the idle agent) forked for real,
the figures recomputed from the forks' own records, the page checked in headless Chromium."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from browser import chromium

from cab_core.analysis import recoverability as rc
from cab_core.analysis import report as analysis_report  # report() below runs cab-report
from cab_core.analysis.attempts import scan
from cab_core.analysis.figures import inline_svg

TASK = "grab_roller_dual_contact"  # cheap on MuJoCo: the oracle needs 7 calls
BIN = os.path.dirname(sys.executable)


# ---------------------------------------------------------------------------------------------
# the computation on hand-made records
# ---------------------------------------------------------------------------------------------
def result(subgoals, used=12, error=False) -> dict:
    """A result.json as far as the fork points read it: subgoals as (attained, first call or None)."""
    ck = {"error": "boom"} if error else {"subgoals": [
        {"index": i + 1, "text": f"stage {'ABCDE'[i]}", "attained": a, "first": None if k is None else {"calls": k}}
        for i, (a, k) in enumerate(subgoals)]}
    return {"budget": {"tool_calls_used": used}, "checkpoints": ck}


def test_failure_point_is_where_the_stages_before_the_first_unattained_one_were_all_reached():
    # stages A (call 3) and B (call 7) reached, C never: C should have followed call 7
    assert rc.fork_points(result([(True, 3), (True, 7), (False, None), (True, 2)])) == {
        "failure_point": 7, "last_call": 12, "failed_stage": "subgoal 3: stage C"}
    # out of order: A only at call 9, C already at 4, B never: B should have followed A (call 9)
    assert rc.fork_points(result([(True, 9), (False, None), (True, 4)]))["failure_point"] == 9
    # the first stage never reached: the scene's start
    assert rc.fork_points(result([(False, None), (True, 5)])) == {
        "failure_point": 0, "last_call": 12, "failed_stage": "subgoal 1: stage A"}
    # every stage reached at some time (then lost): after the last first hit, named by the failure stage
    assert rc.fork_points(result([(True, 2), (True, 5)]), "state_loss") == {
        "failure_point": 5, "last_call": 12, "failed_stage": "Subgoal state lost"}
    # no usable checkpoint record: only the last call
    assert rc.fork_points(result([], error=True), "unresolved") == {
        "failure_point": None, "last_call": 12, "failed_stage": "Unresolved"}
    assert rc.fork_points({"budget": {"tool_calls_used": 4}, "checkpoints": None})["failure_point"] is None
    # an idle attempt: no call, nothing reached
    assert rc.fork_points(result([(False, None)], used=0)) == {
        "failure_point": 0, "last_call": 0, "failed_stage": "subgoal 1: stage A"}


def test_where_a_fork_fails():
    assert rc.fork_fails_at(result([(True, 3), (False, None)])) == "subgoal 2: stage B"
    assert rc.fork_fails_at(result([(True, 3)]), "final_condition") == "Final condition unmet"
    assert rc.fork_fails_at(result([], error=True)) == "Unresolved"


def fork(outcome, kind=None, at=0, fails_at=None) -> dict:
    return {"dir": f"f{at}", "at": at, "outcome": outcome, "kind": kind, "reason": None, "fails_at": fails_at}


REC, NR, UNEX, ERR = "recovered", "not_recoverable", "unexplained", "error"


def path_x(d: str) -> tuple[float, float]:
    """The horizontal extent of an SVG path made of straight segments (matplotlib's bars)."""
    xs = [float(v) for v in re.findall(r"[ML]\s*(-?[\d.]+)\s", d)]
    return min(xs), max(xs)


def cases() -> list[dict]:
    """Config A: 4 failures; config B: 1 without a failure point; config C: no failure (all succeeded)."""
    a = [  # (failure point fork, last call fork, model retries at fp, at last)
        (fork(REC), fork(REC), [fork(REC), fork(NR, "budget")], [fork(NR, "budget")] * 2),
        (fork(REC), fork(NR, "budget", fails_at="subgoal 2: grasp"), [fork(UNEX)] * 2, [fork(NR, "budget")] * 2),
        (fork(NR, "off_table", fails_at="subgoal 1: reach"), fork(NR, "budget", fails_at="subgoal 2: grasp"),
         [fork(REC)] * 2, [fork(ERR)] * 2),
        (fork(ERR), fork(UNEX, "done", fails_at="subgoal 2: grasp"), [fork(ERR)] * 2, [fork(REC), fork(UNEX)]),
    ]
    out = [{"rel": f"a{i}", "config": "A", "oracle": {"failure_point": fp, "last_call": last},
            "model": {"failure_point": mfp, "last_call": mlast}} for i, (fp, last, mfp, mlast) in enumerate(a)]
    out.append({"rel": "b", "config": "B", "oracle": {"failure_point": None, "last_call": fork(REC)},
                "model": {"failure_point": [], "last_call": [fork(NR, "budget")] * 2}})
    return out


def test_shares_by_hand():
    a, b, c = rc.summarize(cases(), ["A", "B", "C"], repeats=2)
    assert (a["config"], a["failures"], b["failures"], c["failures"]) == ("A", 4, 1, 0)
    fp, last = a["oracle"]["failure_point"], a["oracle"]["last_call"]
    # from the failure point: 2 recovered of the 3 forks made (one could not be made)
    assert (fp["recovered"], fp["n"], fp["errors"], fp["unavailable"]) == (2, 3, 1, 0)
    assert fp["share"] == pytest.approx(2 / 3)
    # Wilson 95 % for 2/3 and 1/4, as R's binom.confint(method = "wilson") gives them
    assert fp["wilson95"] == pytest.approx([0.2077, 0.9385], abs=1e-4)
    assert fp["not_recoverable"] == {"off_table": 1} and fp["unexplained"] == 0
    assert fp["fails_at"] == {"subgoal 1: reach": {"forks": 1, "kinds": {"off_table": 1}}}
    assert (last["recovered"], last["n"], last["share"]) == (1, 4, 0.25)
    assert last["wilson95"] == pytest.approx([0.0456, 0.6994], abs=1e-4)
    assert last["not_recoverable"] == {"budget": 2} and last["unexplained"] == 1
    assert last["fails_at"] == {"subgoal 2: grasp": {"forks": 3, "kinds": {"budget": 2, "unexplained": 1}}}
    # the model: every retry counts, errors apart: 3 of 6 at the failure point, 1 of 6 at the last call
    mfp, mlast = a["model"]["failure_point"], a["model"]["last_call"]
    assert (mfp["recovered"], mfp["n"], mfp["errors"], mfp["share"]) == (3, 6, 2, 0.5)
    assert (mlast["recovered"], mlast["n"], mlast["errors"]) == (1, 6, 2)
    # B: no failure point, so nothing to share there; recovered from its last call
    assert b["oracle"]["failure_point"]["n"] == 0 and b["oracle"]["failure_point"]["unavailable"] == 1
    assert b["oracle"]["failure_point"]["share"] is None and b["oracle"]["failure_point"]["wilson95"] is None
    assert (b["oracle"]["last_call"]["recovered"], b["oracle"]["last_call"]["n"]) == (1, 1)
    assert c["oracle"]["last_call"]["n"] == 0
    assert rc.summarize(cases(), ["A"], repeats=0)[0]["model"] is None


def test_tables_and_figure_from_the_shares():
    rec = {"repeats": 2, "configs": rc.summarize(cases(), ["A", "B", "C"], repeats=2)}
    (title, header, rows), (_, where_header, where) = rc.tables(rec)
    assert "failure point" in title and "retries 2 time(s)" in title
    row = dict(zip(header, rows[0]))
    assert row["Failures"] == "4" and row["Oracle from failure point"] == "2/3 (66.7%)"
    assert row["Oracle from last call"] == "1/4 (25.0%)"
    assert row["Model retry from failure point"] == "3/6 (50.0%)" and row["Model retry from last call"] == "1/6 (16.7%)"
    assert header.count("Wilson 95%") == 2 and "20.8%–93.9%" in rows[0] and "4.6%–69.9%" in rows[0]
    assert row["Not recoverable from failure point"] == "off_table 1"
    assert row["Not recoverable from last call"] == "budget 2, unexplained 1"
    assert row["Not forked"] == "fork not made: 1 from the failure point"
    b = dict(zip(header, rows[1]))
    assert b["Oracle from failure point"] == "–" and b["Not forked"] == "1 without a failure point"
    assert dict(zip(header, rows[2]))["Failures"] == "0"
    assert where == [["A", "failure point", "subgoal 1: reach", "1", "off_table 1"],
                     ["A", "last call", "subgoal 2: grasp", "3", "budget 2, unexplained 1"]]
    svg = ET.fromstring(inline_svg(rc.figure(rec)))
    ns = "{http://www.w3.org/2000/svg}"
    assert svg.get("aria-label") == "Failures recoverable (Wilson 95% interval)"
    bars = [g for g in svg.iter(f"{ns}g") if g.get("id", "").startswith("recoverability-bar-")]
    # A: 4 bars, B: the last-call ones (the failure point has no share), C: no failure, no row
    assert [b.find(f"{ns}title").text for b in bars] == [
        "A, oracle from failure point: 66.7%", "A, oracle from last call: 25.0%",
        "A, model retry from failure point: 50.0%", "A, model retry from last call: 16.7%",
        "B, oracle from last call: 100.0%", "B, model retry from last call: 0.0%"]
    spans = [path_x(b.find(f"{ns}path").get("d")) for b in bars]  # each bar's (left, right) on the page
    assert len({round(x0, 3) for x0, _ in spans}) == 1  # all from the same 0%
    full = spans[4][1] - spans[4][0]
    assert [(x1 - x0) / full for x0, x1 in spans] == pytest.approx([2 / 3, 1 / 4, 1 / 2, 1 / 6, 1, 0], abs=1e-3)
    rec0 = {"repeats": 0, "configs": rc.summarize(cases(), ["A"], repeats=0)}
    assert "Model retry from failure point" not in rc.tables(rec0)[0][1]


# ---------------------------------------------------------------------------------------------
# a real sweep, forked
# ---------------------------------------------------------------------------------------------
def first_calls_up_to_subgoal_1(oracle_dir: Path) -> tuple[list[dict], int]:
    """The oracle's charged calls up to the one that attained the task's first subgoal."""
    r = json.loads((oracle_dir / "result.json").read_text())
    k = r["checkpoints"]["subgoals"][0]["first"]["calls"]
    calls = [e for e in map(json.loads, (oracle_dir / "events.jsonl").read_text().splitlines())
             if e.get("kind") == "call" and e.get("charged", True)]
    return [{"tool": e["tool"], "args": e.get("arguments") or {}} for e in calls[:k]], k


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The scripted agent plays the oracle's calls up to the first subgoal (the left gripper on the
    roller), lifts that hand and then only reads its pose until the tool budget is spent; the idle
    agent calls done at once. Both fail; ``cab-report --recoverability`` with one model retry."""
    from attempt_records import run_one

    base = tmp_path_factory.mktemp("recov")
    run_one(base / "oracle", TASK, "oracle", 1, "sim=mujoco", "record.video=false")
    calls, k = first_calls_up_to_subgoal_1(base / "oracle")
    budget = json.loads((base / "oracle" / "result.json").read_text())["budget"]["tool_calls_limit"]
    script = calls + [{"tool": "move_delta", "args": {"arm": "left", "dx": 0.0, "dy": 0.0, "dz": 0.1}}]
    script += [{"tool": "get_arm_pose", "args": {"arm": "left"}}] * (budget - len(script) + 2)
    (base / "script.json").write_text(json.dumps(script))
    root = base / "sweep"
    for model, extra in (("scripted", [f"model.script={base / 'script.json'}"]), ("idle", [])):
        run_one(root / TASK / model / "mujoco" / "seed-0" / "attempt-1", TASK, model, 1, "sim=mujoco",
                "record.video=false", *extra)
    r = report(root)
    return {"root": root, "k": k, "budget": budget, "run": r, "report": json.loads((root / "report.json").read_text())}


def report(root: Path) -> subprocess.CompletedProcess:
    r = subprocess.run([os.path.join(BIN, "cab-report"), str(root), "--recoverability",
                        "--recoverability-model-repeats", "1", "--recoverability-jobs", "2"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


def fork_dirs(root: Path) -> dict[tuple[str, int, str], Path]:
    """(agent of the parent, K, oracle or model-1) -> fork folder, found on disk."""
    out = {}
    for res in sorted((root / "recoverability").rglob("result.json")):
        d = res.parent
        out[(d.parents[4].name, int(d.parent.name.removeprefix("at-")), d.name)] = d
    return out


def success(d: Path) -> bool:
    return bool(json.loads((d / "result.json").read_text())["verdict"]["success"])


@pytest.mark.sim
def test_forks_made_at_the_failure_point_and_the_last_call(sweep):
    root, k, budget = sweep["root"], sweep["k"], sweep["budget"]
    rec = sweep["report"]["recoverability"]
    cases = {x["rel"].split("/")[1]: x for x in rec["cases"]}
    assert set(cases) == {"scripted", "idle"} and rec["repeats"] == 1 and rec["dir"] == "recoverability"
    assert cases["scripted"]["points"] == {"failure_point": k, "last_call": budget}
    assert cases["scripted"]["failed_stage"].startswith("subgoal 2: ")
    assert cases["idle"]["points"] == {"failure_point": 0, "last_call": 0}
    forks = fork_dirs(root)
    # one fork serves both points of the idle attempt
    assert sorted(forks) == sorted([("scripted", k, "oracle"), ("scripted", k, "model-1"), ("scripted", budget, "oracle"),
                                    ("scripted", budget, "model-1"), ("idle", 0, "oracle"), ("idle", 0, "model-1")])
    assert rec["forks"] == 6 and rec["ran"] == 6
    for (agent, at, who), d in forks.items():
        r = json.loads((d / "result.json").read_text())
        assert r["fork"]["at"] == at and r["fork"]["exact"] is True
        assert (d / r["fork"]["parent"]).resolve() == (root / TASK / agent / "mujoco" / "seed-0" / "attempt-1").resolve()
        assert r["model"] == ("oracle" if who == "oracle" else agent)
    # the model retry is the parent's own model as recorded: the scripted agent with its script
    start = next(e for e in map(json.loads, (forks[("scripted", k, "model-1")] / "events.jsonl").read_text().splitlines())
                 if e.get("kind") == "attempt_start")
    parent = root / TASK / "scripted" / "mujoco" / "seed-0" / "attempt-1"
    pstart = next(e for e in map(json.loads, (parent / "events.jsonl").read_text().splitlines())
                  if e.get("kind") == "attempt_start")
    assert start["config"]["model_cfg"] == pstart["config"]["model_cfg"]
    assert start["config"]["model_cfg"]["script"]
    # what the forks did: the reference solution finishes from the failure point (and from the
    # idle attempt's start); from the scripted attempt's last call no call is left
    assert success(forks[("scripted", k, "oracle")]) and success(forks[("idle", 0, "oracle")])
    assert not success(forks[("scripted", budget, "oracle")])
    last = cases["scripted"]["oracle"]["last_call"]
    assert (last["outcome"], last["kind"]) == ("not_recoverable", "budget")
    assert last["fails_at"] == cases["scripted"]["failed_stage"]
    assert not any(success(d) for (_, _, who), d in forks.items() if who == "model-1")


@pytest.mark.sim
def test_table_figures_match_the_forks_records(sweep):
    root = sweep["root"]
    rec = sweep["report"]["recoverability"]
    forks = fork_dirs(root)
    points = {x["rel"].split("/")[1]: x["points"] for x in rec["cases"]}
    md = (root / "report.md").read_text()
    for c in rec["configs"]:
        agent = c["config"].split(" ")[0]
        assert c["failures"] == 1
        for p in rc.POINTS:
            ok = success(forks[(agent, points[agent][p], "oracle")])
            assert (c["oracle"][p]["recovered"], c["oracle"][p]["n"]) == (int(ok), 1)
            m = success(forks[(agent, points[agent][p], "model-1")])
            assert (c["model"][p]["recovered"], c["model"][p]["n"]) == (int(m), 1)
    # the Markdown table, as the report prints it
    assert ("| idle (direct, mujoco) | 1 | 1/1 (100.0%) | 20.7%–100.0% | 1/1 (100.0%) | 20.7%–100.0% | 0/1 (0.0%) "
            "| 0/1 (0.0%) | – | – | – |") in md
    assert ("| scripted (direct, mujoco) | 1 | 1/1 (100.0%) | 20.7%–100.0% | 0/1 (0.0%) | 0.0%–79.3% | 0/1 (0.0%) "
            "| 0/1 (0.0%) | – | budget 1 | – |") in md
    stage = next(x["failed_stage"] for x in rec["cases"] if "/scripted/" in x["rel"])
    assert f"| scripted (direct, mujoco) | last call | {stage} | 1 | budget 1 |" in md
    assert "Recoverability of failures" in sweep["run"].stdout  # printed too
    # the forks are no attempts of the sweep
    assert sweep["report"]["attempts"] == 2 and len(scan(root).attempts) == 2


@pytest.mark.sim
def test_finished_forks_are_not_run_again(sweep, tmp_path):
    root = tmp_path / "sweep"
    shutil.copytree(sweep["root"], root, symlinks=True)
    forks = fork_dirs(root)
    stamps = {key: (d / "result.json").stat().st_mtime_ns for key, d in forks.items()}
    report(root)
    again = json.loads((root / "report.json").read_text())["recoverability"]
    assert again["ran"] == 0 and again["configs"] == sweep["report"]["recoverability"]["configs"]
    assert {key: (d / "result.json").stat().st_mtime_ns for key, d in forks.items()} == stamps
    # an interrupted fork (records, no result.json) is made again, and only that one
    gone = forks[("scripted", sweep["k"], "oracle")]
    (gone / "result.json").unlink()
    report(root)
    again = json.loads((root / "report.json").read_text())["recoverability"]
    assert again["ran"] == 1 and again["configs"] == sweep["report"]["recoverability"]["configs"]


def table_after(driver, heading: str) -> list[list[str]]:
    """The rendered cells of the table that follows the h2 starting with ``heading``."""
    return driver.execute_script(
        "const h = [...document.querySelectorAll('h2')].find(e => e.textContent.startsWith(arguments[0]));"
        "if (!h) return null; let t = h.nextElementSibling;"
        "return [...t.querySelectorAll('tr')].map(r => [...r.children].map(c => c.innerText.trim()));", heading)


@pytest.mark.sim
def test_page_shows_the_table_and_the_figure_in_a_browser(sweep, tmp_path):
    from selenium.webdriver.common.by import By

    root = sweep["root"]
    driver = chromium(tmp_path, "1300,2000")
    try:
        driver.get((root / "report.html").as_uri())
        rows = table_after(driver, "Recoverability of failures")
        assert rows is not None, "no recoverability table on the page"
        header, body = rows[0], {r[0]: dict(zip(rows[0], r)) for r in rows[1:]}
        assert header[:3] == ["Configuration", "Failures", "Oracle from failure point"]
        assert body["scripted (direct, mujoco)"]["Oracle from failure point"] == "1/1 (100.0%)"
        assert body["scripted (direct, mujoco)"]["Oracle from last call"] == "0/1 (0.0%)"
        assert body["scripted (direct, mujoco)"]["Not recoverable from last call"] == "budget 1"
        assert body["idle (direct, mujoco)"]["Oracle from last call"] == "1/1 (100.0%)"
        where = table_after(driver, "Where recovery fails")
        assert where[1][:2] == ["scripted (direct, mujoco)", "last call"] and where[1][3:] == ["1", "budget 1"]
        fig = driver.find_element(By.CSS_SELECTOR, 'svg[aria-label="Failures recoverable (Wilson 95% interval)"]')
        assert fig.is_displayed() and fig.size["width"] > 300 and fig.size["height"] > 100
        bars = dict(driver.execute_script(
            "return [...arguments[0].querySelectorAll('g[id^=\"recoverability-bar-\"] > title')]"
            ".map(t => { const r = t.parentElement.getBoundingClientRect(); return [t.textContent, [r.left, r.right]]; });",
            fig))
        ticks = dict(driver.execute_script(  # the x axis' tick labels, at their centres
            "return [...arguments[0].querySelectorAll('g[id^=\"recoverability-xtick_\"] text')]"
            ".map(t => { const r = t.getBoundingClientRect(); return [t.textContent, (r.left + r.right) / 2]; });", fig))
        zero, full = ticks["0%"], ticks["100%"]
        assert full - zero > 250
        for name in ("scripted (direct, mujoco), oracle from failure point: 100.0%",
                     "idle (direct, mujoco), oracle from failure point: 100.0%"):  # from 0% to 100%
            assert bars[name] == pytest.approx([zero, full], abs=1.5)
        left, right = bars["scripted (direct, mujoco), oracle from last call: 0.0%"]
        assert left == pytest.approx(zero, abs=1.5) and right - left < 1
        # from the forks table to the fork's page, which links back to its parent's page and says where it started
        forks = table_after(driver, "Forks of the failed attempts")
        assert forks[0][:5] == ["Attempt", "Configuration", "First failed stage", "Failure point", "Last call"]
        link = driver.find_element(By.XPATH, "//h2[text()='Forks of the failed attempts']/following-sibling::table[1]"
                                             "//tr[td[2][text()='scripted (direct, mujoco)']]/td[6]/a")
        assert link.text == "recovered"
        link.click()
        assert f"fork at call {sweep['k']}" in driver.find_element(By.TAG_NAME, "body").text
        driver.find_element(By.CSS_SELECTOR, "a.fork-parent").click()
        assert driver.current_url.endswith(f"{TASK}/scripted/mujoco/seed-0/attempt-1/view.html")
        children = [a.get_attribute("href") for a in driver.find_elements(By.CSS_SELECTOR, "a.fork-child")]
        assert len(children) == 4 and all(Path(h.removeprefix("file://")).is_file() for h in children)
    finally:
        driver.quit()


@pytest.mark.sim
def test_an_attempt_that_cannot_be_forked_is_counted_apart(sweep, tmp_path):
    """Records without the resolved configuration cannot be forked: the fork is an error, named in
    the record and the table, and nothing is run."""
    src = sweep["root"] / TASK / "idle" / "mujoco" / "seed-0" / "attempt-1"
    d = tmp_path / "sweep" / TASK / "idle" / "mujoco" / "seed-0" / "attempt-1"
    shutil.copytree(src, d, ignore=shutil.ignore_patterns("forks.jsonl", "view.html"))
    lines = [json.loads(line) for line in (d / "events.jsonl").read_text().splitlines()]
    for e in lines:
        e.pop("config", None)
    (d / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in lines))

    r = analysis_report.write(tmp_path / "sweep", views=False, recover={"repeats": 0, "jobs": 1})
    rec = r["recoverability"]
    assert rec["ran"] == 0 and rec["forks"] == 1
    f = rec["cases"][0]["oracle"]["failure_point"]
    assert f["outcome"] == "error" and "attempt_start.config" in f["reason"]
    c = rec["configs"][0]
    assert (c["failures"], c["oracle"]["failure_point"]["n"], c["oracle"]["failure_point"]["errors"]) == (1, 0, 1)
    _, header, rows = rc.tables(rec)[0]
    row = dict(zip(header, rows[0]))
    assert row["Oracle from failure point"] == "–"
    assert row["Not forked"] == "fork not made: 1 from the failure point, 1 from the last call"
