"""cab-view: one page per attempt, from its records."""
import html
import json
import re
import shutil

import pytest
from attempt_records import RAISING_PROGRAM, TASKS, attempt_dir, events, shared_sweep

from cab_core.analysis.attempts import Attempt
from cab_core.analysis.report import write
from cab_core.analysis.viewer import render, write_view
from cab_core.apps.view import main
from cab_core.errors import RecordError

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def scripted(tmp_path_factory):
    """A copy of the scripted attempt that over-claims (so the shared sweep stays untouched)."""
    src = attempt_dir(shared_sweep(tmp_path_factory), TASKS[0], "scripted", 1)
    d = tmp_path_factory.mktemp("view") / "attempt"
    shutil.copytree(src, d, ignore=shutil.ignore_patterns("view.html", "replay*"))
    return d


def test_page_shows_timeline_programs_images_verdict_claim_and_checkpoints(scripted):
    page = write_view(scripted).read_text()
    text = html.unescape(page)
    evs = events(scripted)
    calls = [e["tool"] for e in evs if e["kind"] in ("call", "internal_call")]
    # every call, in the order logged
    shown = re.findall(r"<b>(?:↳ )?([a-z_]+)</b>", page)
    assert shown == calls + ["attempt_end"]
    assert RAISING_PROGRAM in text and "ValueError: no block found" in text and "prog_001.py" in text
    obs = [o for e in evs for o in e.get("obs_ids") or []]
    assert obs and all(f'src="observations/{o}.png"' in page for o in obs)
    assert all((scripted / "observations" / f"{o}.png").is_file() for o in obs)
    assert '<video src="video.mp4"' in page
    assert "<th>verdict</th><td>failure</td>" in page and "<th>claim</th><td>success</td>" in page
    assert "Approach hammer" in text and "not attained" in text
    # the checkpoint is marked right after the charged call that first matched it (the move down)
    k = next(c["first"]["calls"] for c in json.loads((scripted / "result.json").read_text())["checkpoints"]["spatial"]
             if c["attained"])
    call = page.index(f"charged call {k} ·")
    assert page.index("✓ checkpoint spatial 1: Approach hammer") > call
    assert f"charged call {k + 1} ·" not in page[call:page.index("✓ checkpoint spatial 1")]
    assert "https://" not in page and "http://" not in page  # nothing fetched from elsewhere


def test_page_shows_model_turns_when_recorded(scripted, tmp_path):
    d = tmp_path / "a"
    shutil.copytree(scripted, d)
    with open(d / "events.jsonl", "a") as f:
        f.write('{"seq": 99, "kind": "model_turn", "turn": 1, "model": "m", "usage": {"input_tokens": 1200, '
                '"output_tokens": 80}, "cost": {"usd": 0.0123}, "latency_s": 2.5, "waited_s": 0, '
                '"text": "I will look first <b>", "thinking": "plan"}\n')
    page = render(Attempt.load(d))
    assert "model turn 1" in page and "1200 in / 80 out tokens" in page and "$0.0123" in page
    assert "I will look first &lt;b&gt;" in page  # model text is escaped


def test_cli_and_bad_input(scripted, tmp_path, capsys):
    main([str(scripted)])
    assert capsys.readouterr().out.strip() == str(scripted / "view.html")
    with pytest.raises(RecordError, match="result.json is missing"):
        write_view(tmp_path)
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path)])
    assert e.value.code == 2 and "result.json is missing" in capsys.readouterr().err


def test_unfinished_attempt_page_and_its_link_in_the_report(scripted, tmp_path):
    d = tmp_path / "sweep" / "a"
    shutil.copytree(scripted, d, ignore=shutil.ignore_patterns("view.html"))
    (d / "result.json").unlink()  # killed after its fourth event, mid-write of the fifth
    lines = (d / "events.jsonl").read_text().splitlines()
    (d / "events.jsonl").write_text("\n".join(lines[:4]) + "\n" + lines[4][:20])
    page = write_view(d).read_text()
    assert "unfinished: no result.json (still running, or interrupted)" in page
    assert "scripted (direct, sapien)" in page
    made = [json.loads(line)["tool"] for line in lines[1:4]]
    assert re.findall(r"<b>(?:↳ )?([a-z_]+)</b>", page) == made
    assert f"<th>tool calls so far</th><td>{len(made)}</td>" in page
    r = write(tmp_path / "sweep")
    assert r["in_flight"] == ["a"] and r["attempts"] == 0
    assert '<li><a href="a/view.html">a</a></li>' in (tmp_path / "sweep" / "report.html").read_text()
