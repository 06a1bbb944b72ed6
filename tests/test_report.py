"""cab-report on a real sweep (oracle, idle, scripted over two tasks): every number the report shows
is recomputed here from result.json and events.jsonl directly, never through cab_core.analysis."""
import functools
import json
import re
import shutil
import xml.etree.ElementTree as ET
from collections import defaultdict
from statistics import median

import pytest
from attempt_records import PLAN, TASKS, attempt_dir, events, results

from cab_core.analysis import report as rep
from cab_core.analysis.measures import wilson
from cab_core.apps.report_cli import main as report_main
from cab_core.sweep.attempt_state import annotate_result, set_aside, write_infrastructure_result

pytestmark = pytest.mark.sim

CONFIG = "{} (direct, sapien)"


@pytest.fixture(scope="module")
def built(sweep, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    r = rep.write(sweep, out)
    return r, out


def by_model(sweep) -> dict[str, list[dict]]:
    out = defaultdict(list)
    for r in results(sweep):
        out[r["model"]].append(r)
    return out


def cfg(r: dict, model: str) -> dict:
    return next(c for c in r["configs"] if c["config"] == CONFIG.format(model))


def test_wilson_matches_reference_values():
    # Wilson score intervals at 95% (z = 1.96), as tabulated by R's binom.confint(method="wilson")
    for (k, n), (lo, hi) in {(4, 4): (0.5101, 1.0), (0, 4): (0.0, 0.4899), (0, 2): (0.0, 0.6576),
                             (1, 3): (0.0615, 0.7923), (0, 0): (0.0, 0.0)}.items():
        got = wilson(k, n)
        assert got == pytest.approx((lo, hi), abs=1e-4), (k, n)


def test_every_attempt_is_counted_once(built, sweep):
    r, _ = built
    n = sum(len(a) for _, a in PLAN) * len(TASKS)
    assert len(results(sweep)) == n
    assert r["attempts"] == n and r["in_flight"] == [] and r["problems"] == []
    assert sum(c["attempts"] for c in r["configs"]) == n


def test_success_coverage_and_consistency(built, sweep):
    r, _ = built
    for model, rs in by_model(sweep).items():
        c = cfg(r, model)
        k = sum(x["verdict"]["success"] for x in rs)
        assert (c["attempts"], c["successes"]) == (len(rs), k)
        assert c["success_rate"] == pytest.approx(k / len(rs))
        per_task = defaultdict(list)
        for x in rs:
            per_task[x["task"]].append(x["verdict"]["success"])
        assert c["tasks"] == len(per_task)
        assert c["coverage"] == sum(any(v) for v in per_task.values())
        expected = defaultdict(int)
        for v in per_task.values():
            expected[f"{sum(v)}/{len(v)}"] += 1
        assert c["consistency"] == dict(expected)
    # the acceptance figures: oracle 100% with coverage 2/2, idle 0% with 0/2
    assert (cfg(r, "oracle")["success_rate"], cfg(r, "oracle")["coverage"], cfg(r, "oracle")["tasks"]) == (1.0, 2, 2)
    assert (cfg(r, "idle")["success_rate"], cfg(r, "idle")["coverage"]) == (0.0, 0)
    assert cfg(r, "oracle")["wilson95"] == pytest.approx((0.5101, 1.0), abs=1e-4)


def test_stopping_and_claims(built, sweep):
    r, _ = built
    for model, rs in by_model(sweep).items():
        c = cfg(r, model)
        stop = defaultdict(int)
        claims = defaultdict(int)
        for x in rs:
            reason = x["termination"]["reason"]
            stop[{"done": "done", "tool_budget": "tool", "sim_budget": "phys"}.get(reason, "other")] += 1
            claim, ok = x["claim"]["success_claim"], x["verdict"]["success"]
            claims["absent" if claim is None else "correct" if claim == ok else "over" if claim else "under"] += 1
        assert c["stopping"] == {k: stop[k] for k in ("done", "tool", "phys", "other")}
        assert c["claims"] == {k: claims[k] for k in ("correct", "over", "under", "absent")}
    # the scripted agent over-claims once and once stops without done
    assert cfg(r, "scripted")["claims"]["over"] == 1 and cfg(r, "scripted")["claims"]["absent"] == 1


def test_programs_actions_and_resources(built, sweep):
    r, _ = built
    for model, rs in by_model(sweep).items():
        c = cfg(r, model)
        evs = [events(attempt_dir(sweep, x["task"], x["model"], x["attempt"])) for x in rs]
        charged = sum(x["budget"]["tool_calls_used"] for x in rs)
        programs = [e for ev in evs for e in ev if e["kind"] == "call" and e["tool"] == "run_code"]
        actions = [e for ev in evs for e in ev if e["kind"] in ("call", "internal_call") and "action_id" in (e.get("result") or {})]
        failed = [e for e in actions if e["result"]["status"] == "FAILED"]
        assert c["charged_calls"] == charged and c["program_calls"] == len(programs)
        assert c["program_errors"] == sum(not e["result"]["ok"] for e in programs)
        assert c["actions"] == len(actions) and c["not_completed"]["planner"] == len(failed)
        stopped = [e for e in actions if e["result"]["status"] != "SUCCESS"]
        assert c["not_completed_total"] == len(stopped)
        assert c["not_completed_moved"] == sum(e["physics_steps"] > 0 for e in stopped)
        assert c["calls_mean"] == pytest.approx(charged / len(rs))
        assert c["sim_seconds_median"] == pytest.approx(median(x["budget"]["sim_seconds_used"] for x in rs))
        assert c["wall_seconds_median"] == pytest.approx(median(x["timing"]["wall_seconds"] for x in rs))
        assert c["cost_total"] is None and c["wait_seconds_median"] is None  # model-free agents record no usage
        assert c["infra_retries"] == sum(len(x.get("infrastructure", {}).get("failures", [])) for x in rs)
    s = cfg(r, "scripted")
    # per task: two programs, one raising; one unreachable reach_tcp refused by the planner
    assert (s["program_calls"], s["program_errors"], s["not_completed"]["planner"]) == (4, 2, 2)
    assert s["program_share"] == pytest.approx(4 / 10)  # 6 charged calls on the first task, 4 on the second


def test_checkpoint_coverage_and_curve(built, sweep):
    r, _ = built
    for model, rs in by_model(sweep).items():
        c = cfg(r, model)
        per_task = defaultdict(list)
        for x in rs:
            per_task[x["task"]].append(x["checkpoints"]["spatial_coverage"])
        want = sum(sum(v) / len(v) for v in per_task.values()) / len(per_task)
        assert c["spatial_coverage"] == pytest.approx(want)
        curve = c["spatial_curve"]
        assert curve[0] == 0.0 and curve[-1] == pytest.approx(want)
        assert all(a <= b for a, b in zip(curve, curve[1:]))
    # the oracle's first spatial match on beat_block_hammer comes at its 4th charged call
    first = min(s["first"]["calls"] for x in by_model(sweep)["oracle"] if x["task"] == "beat_block_hammer"
                for s in x["checkpoints"]["spatial"])
    curve = cfg(r, "oracle")["spatial_curve"]
    assert curve[first - 1] == 0.0 < curve[first]


def test_failure_stages_and_matrix(built, sweep):
    r, _ = built
    assert cfg(r, "idle")["failure_stages"] == {"arrival": 4}  # never near any region
    # the scripted agent reaches the hammer and leaves without grasping it; it never nears a block
    assert cfg(r, "scripted")["failure_stages"] == {"object_control": 1, "arrival": 1}
    assert cfg(r, "scripted")["progress"] == {"success": 0, "subgoal": 0, "spatial_only": 1, "none": 1}
    assert cfg(r, "oracle")["failure_stages"] == {}
    for task in TASKS:
        assert r["matrix"][task][CONFIG.format("oracle")] == [2, 2]
        assert r["matrix"][task][CONFIG.format("idle")] == [0, 2]
    rows = {m["rel"]: m for m in r["attempt_rows"]}
    assert all(m["failure_stage"] is None for m in rows.values() if m["success"])
    assert all(m["failure_stage"] and m["failure_detail"] for m in rows.values() if not m["success"])


def test_markdown_and_html(built, sweep):
    r, out = built
    md = (out / "report.md").read_text()
    assert "| oracle (direct, sapien) | 4/4 | 100.0% | 51.0%–100.0% | 2/2 |" in md
    assert "| idle (direct, sapien) | 0/4 | 0.0% | 0.0%–49.0% | 0/2 |" in md
    assert json.loads((out / "report.json").read_text()) == json.loads(json.dumps(r))
    page = (out / "report.html").read_text()
    svgs = re.findall(r"<svg.*?</svg>", page, re.S)
    assert len(svgs) >= 4
    for fig in svgs:  # each figure is well-formed SVG with marks drawn
        root = ET.fromstring(fig)
        assert root.tag.endswith("svg") and len(root) > 3
    namespaces = ('xmlns="http://www.w3.org/2000/svg"', 'xmlns:xlink="http://www.w3.org/1999/xlink"')
    assert "http://" not in functools.reduce(lambda p, ns: p.replace(ns, ""), namespaces, page) and "https://" not in page
    for m in r["attempt_rows"]:  # every attempt's page exists
        assert (sweep / m["rel"] / "view.html").is_file()
    links = [a.split('"')[0] for a in page.split('<a href="')[1:]]
    assert len(links) == r["attempts"] and all((out / a).resolve().is_file() for a in links)


def test_cli_prints_the_summary_table(sweep, tmp_path, capsys):
    report_main([str(sweep), "--out", str(tmp_path), "--no-views"])
    printed = capsys.readouterr().out
    assert printed.splitlines()[0].startswith("| Configuration | Success | Rate | Wilson 95% | Coverage |")
    assert "| oracle (direct, sapien) | 4/4 | 100.0%" in printed
    assert (tmp_path / "report.html").is_file()


def test_partial_and_corrupt_records_are_reported_not_fatal(sweep, tmp_path):
    d = tmp_path / "sweep"
    shutil.copytree(sweep, d, ignore=shutil.ignore_patterns("*.mp4", "observations", "view.html", "replay*"))
    (attempt_dir(d, TASKS[0], "oracle", 1) / "result.json").unlink()  # killed mid-attempt
    (attempt_dir(d, TASKS[0], "oracle", 2) / "result.json").write_text('{"task": "beat_bl')  # torn write
    bad = attempt_dir(d, TASKS[1], "idle", 1) / "result.json"
    bad.write_text(json.dumps({k: v for k, v in json.loads(bad.read_text()).items() if k != "verdict"}))
    log = attempt_dir(d, TASKS[1], "scripted", 1) / "events.jsonl"
    lines = log.read_text().splitlines()
    log.write_text("\n".join(lines[:2] + ["{not json"] + lines[2:]) + "\n")
    odd = attempt_dir(d, TASKS[0], "idle", 2) / "result.json"
    res = json.loads(odd.read_text())
    res["checkpoints"]["spatial"] = [{"index": 1}]  # a checkpoint without its outcome
    odd.write_text(json.dumps(res))
    # the sweep gave up on one attempt (infrastructure failures), after setting its records aside
    gave_up = attempt_dir(d, TASKS[1], "oracle", 2)
    identity = {k: json.loads((gave_up / "result.json").read_text())[k] for k in ("task", "seed", "attempt", "sim", "model")}
    set_aside(gave_up, "simulator-crash")
    write_infrastructure_result(gave_up, identity, [{"kind": "crash", "detail": "simulator died"}])
    # and redid another after two infrastructure failures: recorded, not counted against the model
    annotate_result(attempt_dir(d, TASKS[1], "oracle", 1), [{"kind": "hang"}, {"kind": "provider outage"}])
    # the sweep planned two attempts more than there are directories
    (d / "sweep.json").write_text(json.dumps({"fingerprint": "sha256:0f", "n_jobs": len(results(sweep)) + 2}))
    r = rep.write(d, views=False)
    assert r["sweep"] == {"fingerprint": "sha256:0f", "jobs": len(results(sweep)) + 2, "not_started": 2}
    assert cfg(r, "oracle")["infra_retries"] == 2 and cfg(r, "oracle")["successes"] == 1
    assert r["in_flight"] == [f"{TASKS[0]}/oracle/seed-0/attempt-1"]
    assert [e["dir"] for e in r["excluded"]] == [f"{TASKS[1]}/oracle/seed-0/attempt-2"]
    assert "simulator died" in r["excluded"][0]["why"]
    problems = {p["dir"]: p["problem"] for p in r["problems"]}
    assert problems[f"{TASKS[0]}/oracle/seed-0/attempt-2"].startswith("result.json is not valid JSON")
    assert problems[f"{TASKS[1]}/idle/seed-0/attempt-1"] == "result.json lacks 'verdict'"
    assert problems[f"{TASKS[1]}/scripted/seed-0/attempt-1"].startswith("events.jsonl line 3 is not valid JSON")
    # refused when read: the record's model (cab_core.attempt.records.result_format) names what the checkpoint lacks
    assert problems[f"{TASKS[0]}/idle/seed-0/attempt-2"].startswith("result.json lacks 'checkpoints.spatial[0].name'")
    assert "result.json lacks 'checkpoints.spatial[0].attained'" in problems[f"{TASKS[0]}/idle/seed-0/attempt-2"]
    assert r["attempts"] == len(results(sweep)) - 6
    assert cfg(r, "oracle")["attempts"] == 1 and cfg(r, "oracle")["tasks"] == 1
    md = (d / "report.md").read_text()
    assert "Unfinished attempts (no result.json): 1" in md and "result.json lacks 'verdict'" in md
    assert "Excluded, not scored (infrastructure failures, interrupted attempts; not the model's): 1" in md
    assert "(2 not started), configuration fingerprint sha256:0f" in md


def test_provider_usage_gives_cost_and_wait(sweep, tmp_path):
    """Usage events as the reference harness writes them (one model_turn per response) give the
    cost total, median and IQR and the provider wait."""
    for i, usd in enumerate((1.0, 2.0, 4.0)):
        src = attempt_dir(sweep, TASKS[0], "idle", 1)
        d = tmp_path / f"a{i}"
        shutil.copytree(src, d, ignore=shutil.ignore_patterns("*.mp4", "view.html"))
        with open(d / "events.jsonl", "a") as f:
            for turn in (1, 2):
                f.write(json.dumps({"seq": 100 + turn, "kind": "model_turn", "turn": turn, "usage": {},
                                    "cost": {"usd": usd / 2}, "latency_s": 1.5 * (i + 1), "waited_s": 0.5}) + "\n")
    c = rep.build(tmp_path)["configs"][0]
    assert c["cost_total"] == pytest.approx(7.0) and c["cost_median"] == pytest.approx(2.0)
    assert c["cost_iqr"] == pytest.approx((1.5, 3.0))
    assert c["wait_seconds_median"] == pytest.approx(2 * (3.0 + 0.5))


def snap(tcp, obj, contacts=(), grip=0.0):
    """A privileged snapshot with the left arm's TCP and one object, both given as xyz."""
    return {"arms": {"left": {"tcp_pose": [*tcp, 1, 0, 0, 0], "gripper_cmd": grip}},
            "objects": {"can": {"pose": [*obj, 1, 0, 0, 0]}}, "contacts": [list(c) for c in contacts]}


FINGERS = {"left": ("fl_link7", "fl_link8")}
BOTH = (("can", "robot/fl_link7", 0.1), ("can", "robot/fl_link8", 0.1))


@pytest.mark.parametrize("after, contacts, carried", [
    (snap((0.0, 0.05, 1.0), (0.0, 0.05, 0.9), BOTH), BOTH, True),              # carried 5 cm together
    (snap((0.0, 0.05, 1.0), (0.0, 0.05, 0.9), BOTH[:1]), BOTH[:1], False),     # one finger only
    (snap((0.0, 0.05, 1.0), (0.0, 0.0, 0.9), BOTH), BOTH, False),              # TCP moved, object stayed
    (snap((0.0, 0.05, 1.0), (0.0, 0.10, 0.9), BOTH), BOTH, False),             # object slid 10 cm: 5 cm drift
    (snap((0.0, 0.02, 1.0), (0.0, 0.02, 0.9), BOTH), BOTH, False),             # 2 cm: below the 3 cm bound
])
def test_common_motion_follows_the_papers_criterion(after, contacts, carried):
    from cab_core.analysis.failure import Grip, common_motions

    before = snap((0.0, 0.0, 1.0), (0.0, 0.0, 0.9), BOTH)
    assert common_motions([before, after], FINGERS) == ([Grip(1, "left", "can")] if carried else [])


def test_transport_loss_needs_release_and_drift():
    from cab_core.analysis.failure import Grip, transport_lost

    held = snap((0.0, 0.05, 1.0), (0.0, 0.05, 0.9), BOTH)
    grip = Grip(0, "left", "can")
    assert transport_lost([held, snap((0.0, 0.2, 1.0), (0.0, 0.05, 0.75), grip=1.0)], grip)  # opened, fell
    assert not transport_lost([held, snap((0.0, 0.2, 1.0), (0.0, 0.2, 0.9), BOTH, grip=0.0)], grip)  # still held
    assert not transport_lost([held, snap((0.0, 0.05, 1.0), (0.0, 0.05, 0.9), grip=1.0)], grip)  # opened in place


def test_attempts_served_over_mcp_group_by_their_configuration_name(sweep, tmp_path):
    """Attempts served over MCP are configurations by the name they were served under (given, or
    mcp:<client> from the handshake), each showing its clients; records from before clients were
    recorded (model mcp_client, no agent block) still load; a malformed agent block is a problem."""
    def client(name, version, session=1):
        return {"name": name, "version": version, "session": session}

    def served(d: str, model: str, agent: dict | None):
        shutil.copytree(attempt_dir(sweep, TASKS[0], "idle", 1), tmp_path / d,
                        ignore=shutil.ignore_patterns("*.mp4", "view.html", "observations"))
        res = json.loads((tmp_path / d / "result.json").read_text())
        res.update(model=model, harness="mcp")
        if agent is not None:
            res["agent"] = agent
        (tmp_path / d / "result.json").write_text(json.dumps(res))

    a, b, c = client("agent-a", "1.0"), client("agent-b", "2.5"), client("agent-c", "0.1", 2)
    served("a1", "mcp:agent-a", {"kind": "mcp_client", "named_by": "client", "client": a, "clients": [a]})
    served("a2", "mcp:agent-a", {"kind": "mcp_client", "named_by": "client", "client": a, "clients": [a, a | {"session": 2}]})
    served("b1", "my-agent", {"kind": "mcp_client", "named_by": "config", "client": b, "clients": [b, c]})
    served("old", "mcp_client", None)
    served("bad", "mcp:agent-d", {"kind": "mcp_client", "named_by": "client", "client": {"name": "agent-d", "version": 3},
                                  "clients": []})
    r = rep.write(tmp_path, views=False)
    by = {x["config"]: x for x in r["configs"]}
    assert sorted(by) == ["mcp:agent-a (mcp, sapien)", "mcp_client (mcp, sapien)", "my-agent (mcp, sapien)"]
    assert {k: (v["attempts"], v["clients"]) for k, v in by.items()} == {
        "mcp:agent-a (mcp, sapien)": (2, ["agent-a/1.0"]),
        "my-agent (mcp, sapien)": (1, ["agent-b/2.5", "agent-c/0.1"]),
        "mcp_client (mcp, sapien)": (1, [])}
    assert {m["rel"]: m["clients"] for m in r["attempt_rows"]} == {
        "a1": ["agent-a/1.0"], "a2": ["agent-a/1.0"], "b1": ["agent-b/2.5", "agent-c/0.1"], "old": []}
    assert r["problems"] == [{"dir": "bad", "problem": "result.json agent.client.version should be a string, got 3"}]
    title, header, rows = rep.tables(r)[0]
    assert header[:3] == ["Configuration", "MCP client", "Success"]
    assert sorted(row[:3] for row in rows) == [["mcp:agent-a (mcp, sapien)", "agent-a/1.0", "0/2"],
                                               ["mcp_client (mcp, sapien)", "–", "0/1"],
                                               ["my-agent (mcp, sapien)", "agent-b/2.5, agent-c/0.1", "0/1"]]
    assert "| mcp:agent-a (mcp, sapien) | agent-a/1.0 | 0/2 |" in (tmp_path / "report.md").read_text()


def test_verdict_margins_and_borderline_flags(sweep, tmp_path):
    """Every real record carries its deciding margin; the report counts borderline verdicts per
    configuration from them, names the attempts, and shows each attempt's margin. One oracle record
    is edited to a deciding margin of 4 % (what another machine could flip)."""
    for r in results(sweep):
        d = r["verdict"]["margin"]
        if r["model"] == "oracle":
            assert r["verdict"]["success"] and d["fraction"] > rep.BORDERLINE_FRACTION and not d["borderline"]
            assert d["predicate"] in r["verdict"]["margins"]
    src = attempt_dir(sweep, TASKS[1], "oracle", 1)
    d = tmp_path / "tight"
    shutil.copytree(src, d, ignore=shutil.ignore_patterns("*.mp4", "view.html"))
    shutil.copytree(attempt_dir(sweep, TASKS[1], "oracle", 2), tmp_path / "wide",
                    ignore=shutil.ignore_patterns("*.mp4", "view.html"))
    res = json.loads((d / "result.json").read_text())
    res["verdict"]["margin"] = {"predicate": "green_on_red", "fraction": 0.04, "borderline": True, "threshold": 0.1}
    (d / "result.json").write_text(json.dumps(res))
    old = tmp_path / "old"  # a record written before margins existed
    shutil.copytree(src, old, ignore=shutil.ignore_patterns("*.mp4", "view.html"))
    res = json.loads((old / "result.json").read_text())
    del res["verdict"]["margin"], res["verdict"]["margins"]
    (old / "result.json").write_text(json.dumps(res))
    r = rep.write(tmp_path, tmp_path / "out")
    b = cfg(r, "oracle")["borderline"]
    assert b["successes"] == 1 and b["failures"] == 0 and b["unrecorded"] == 1 and b["attempts"] == ["tight"]
    assert b["min_success_margin"] == pytest.approx(0.04)
    md = (tmp_path / "out" / "report.md").read_text()
    assert "| oracle (direct, sapien) | 1/3 | 0/0 | 4.0% | 1 |" in md
    assert "Borderline verdicts (deciding margin under 10% of its tolerance): tight (oracle (direct, sapien))" in md
    page = (tmp_path / "out" / "report.html").read_text()
    assert "borderline 4.0% (green_on_red)" in page
    view = (tmp_path / "tight" / "view.html").read_text()
    assert "BORDERLINE: 4.0% of its tolerance (green_on_red" in view and "margins measured at the final" in view


def test_pass_k_per_configuration(built, sweep):
    from scipy.special import comb

    r, out = built
    for model, rs in by_model(sweep).items():
        per_task = defaultdict(list)
        for x in rs:
            per_task[x["task"]].append(x["verdict"]["success"])
        n = min(len(v) for v in per_task.values())
        curve = cfg(r, model)["pass_k"]
        assert curve["k"] == list(range(1, n + 1))
        for k in curve["k"]:  # scipy's exact binomial coefficients, averaged over tasks by hand
            at = [1 - comb(len(v) - sum(v), k, exact=True) / comb(len(v), k, exact=True) for v in per_task.values()]
            hat = [comb(sum(v), k, exact=True) / comb(len(v), k, exact=True) for v in per_task.values()]
            assert curve["pass_at_k"][k - 1] == pytest.approx(sum(at) / len(at))
            assert curve["pass_hat_k"][k - 1] == pytest.approx(sum(hat) / len(hat))
    md = (out / "report.md").read_text()
    assert "## pass@k and pass^k" in md and "| oracle (direct, sapien) | 100.0% | 100.0% | 100.0% |" in md
    assert "pass@k and pass^k" in (out / "report.html").read_text()


def test_compare_and_plan_from_the_command_line(sweep, tmp_path, capsys):
    from scipy.stats import binomtest

    report_main([str(sweep), "--out", str(tmp_path), "--no-views", "--compare", "oracle", "scripted",
              "--resamples", "500", "--plan-difference", "0.1"])
    printed = capsys.readouterr().out
    r = json.loads((tmp_path / "report.json").read_text())
    c = r["comparison"]
    assert (c["a"], c["b"]) == (CONFIG.format("oracle"), CONFIG.format("scripted"))
    # from result.json directly: attempt i of oracle paired with attempt i of scripted on each instance
    verdict = {(x["model"], x["task"], x["seed"], x["attempt"]): x["verdict"]["success"] for x in results(sweep)}
    pairs = [(v, verdict[("scripted", t, s, i)]) for (m, t, s, i), v in verdict.items()
             if m == "oracle" and ("scripted", t, s, i) in verdict]
    b, cc = sum(x and not y for x, y in pairs), sum(y and not x for x, y in pairs)
    assert (c["pairs"], c["only_a"], c["only_b"]) == (len(pairs), b, cc) == (2, 2, 0)
    assert c["mcnemar_p"] == pytest.approx(binomtest(b, b + cc, 0.5).pvalue)
    assert c["instances"] == {"shared": 2, "only_a": 0, "only_b": 0}
    assert c["bootstrap"]["difference"] == 1.0 and c["bootstrap"]["ci"] == [1.0, 1.0]
    assert r["plan"]["tasks"] == 2 and r["plan"]["attempts_per_config"] == 392
    assert "Exact McNemar p-value (two-sided) | 0.5 |" in printed and "| Attempts per configuration | 392 |" in printed
    assert "## Paired comparison: A = oracle (direct, sapien), B = scripted (direct, sapien)" in (
        tmp_path / "report.md").read_text()


def test_compare_names_an_unknown_configuration(sweep, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        report_main([str(sweep), "--out", str(tmp_path), "--no-views", "--compare", "oracle", "nobody"])
    assert e.value.code == 2 and "no configuration 'nobody'" in capsys.readouterr().err
    assert not (tmp_path / "report.json").exists()


def test_plan_without_a_directory(capsys):
    report_main(["--plan-difference", "0.2", "--plan-baseline", "0.3", "--plan-tasks", "25"])
    printed = capsys.readouterr().out
    assert "| Success rates | 20.0% vs 40.0% |" in printed
    assert "| Attempts per configuration | 82 |" in printed and "| Attempts per task over 25 tasks | 4 (100 per" in printed
