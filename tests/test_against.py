"""``cab-report <sweep> --against paper|<earlier run>`` on the shared sweep of real attempts (oracle,
idle, scripted over two tasks): the side-by-side table, its tests checked against scipy, the
verdicts, the forest plot, per-task success against an earlier run, contracts that differ marked
exploratory, a third party's published figures, and bad input as one line."""
from __future__ import annotations

import json
import re
import shutil
import types
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

from cab_core import hookimpl
from cab_core.analysis import against
from cab_core.apps.report_cli import main as report_main

OPUS, ASTRA = "Claude Opus 5 (Reference)", "GPT-6 Astra (Codex CLI)"


def p_text(p: float) -> str:
    return f"{p:.3g}"


# --- the statistics ------------------------------------------------------------------------------
@pytest.mark.parametrize("k,n,p", [(4, 4, 37 / 75), (0, 4, 55 / 75), (3, 10, 0.3), (7, 20, 0.5), (0, 5, 0.0),
                                   (5, 5, 1.0), (1, 50, 0.02), (30, 75, 0.493)])
def test_the_binomial_test_is_scipys(k, n, p):
    assert against.binomial_test(k, n, p) == pytest.approx(sps.binomtest(k, n, p).pvalue, rel=1e-9)


@pytest.mark.parametrize("table", [(4, 0, 37, 38), (0, 4, 55, 20), (2, 0, 19, 6), (0, 2, 22, 3), (3, 3, 3, 3),
                                   (0, 0, 5, 5), (10, 65, 40, 35), (1, 9, 11, 3)])
def test_fisher_is_scipys(table):
    a, b, c, d = table
    assert against.fisher_exact(a, b, c, d) == pytest.approx(sps.fisher_exact([[a, b], [c, d]]).pvalue, rel=1e-9)


def test_the_bootstrap_interval_is_seeded_and_holds_the_median():
    xs = [float(x) for x in np.random.default_rng(3).gamma(2.0, 3.0, size=75)]
    lo, hi = against.bootstrap(xs, np.median, resamples=4000, seed=1)
    assert (lo, hi) == against.bootstrap(xs, np.median, resamples=4000, seed=1)
    assert lo < float(np.median(xs)) < hi
    res = sps.bootstrap((np.asarray(xs),), np.median, n_resamples=4000, method="percentile", random_state=1)
    assert lo == pytest.approx(res.confidence_interval.low, rel=0.1)
    assert hi == pytest.approx(res.confidence_interval.high, rel=0.1)
    assert against.bootstrap([1.0], np.median) is None


# --- against the paper ---------------------------------------------------------------------------
def test_against_the_paper_prints_the_side_by_side_table(sweep, tmp_path, capsys):
    report_main([str(sweep), "--out", str(tmp_path), "--no-views", "--against", "paper",
                 "--as", f"oracle={OPUS}", "--as", f"idle={ASTRA}"])  # returns: exit status 0
    out = capsys.readouterr().out
    a = json.loads((tmp_path / "against.json").read_text())
    assert a["kind"] == "paper" and [r["other"] for r in a["rows"]] == [OPUS, ASTRA]
    oracle = next(r for r in a["rows"] if r["other"] == OPUS)
    success, coverage = oracle["tested"]
    assert (success["cab"], success["other"]) == ([4, 4], [37, 75])
    assert (coverage["cab"], coverage["other"]) == ([2, 2], [19, 25])
    assert success["binomial_p"] == pytest.approx(sps.binomtest(4, 4, 37 / 75).pvalue)
    assert success["fisher_p"] == pytest.approx(sps.fisher_exact([[4, 0], [37, 38]]).pvalue)
    assert oracle["verdict"] == "consistent with the paper"
    idle = next(r for r in a["rows"] if r["other"] == ASTRA)
    assert idle["tested"][0]["binomial_p"] == pytest.approx(sps.binomtest(0, 4, 55 / 75).pvalue)
    assert idle["verdict"].startswith("differs: success 0/4 vs 55/75 (binomial p=0.00506, Fisher p=0.00707)")
    assert "task coverage 0/2 vs 22/25" in idle["verdict"]
    # the printed table: each configuration's success row with its interval, the paper's value, both tests
    line = next(ln for ln in out.splitlines() if ln.startswith("| oracle") and OPUS in ln)
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1:] == [OPUS, "success", "4/4 (100.0%)", "51.0%–100.0%", "37/75 (49.3%)",
                         p_text(success["binomial_p"]), p_text(success["fisher_p"]), "consistent with the paper"]
    assert "compared on what the paper fixed" in out
    assert "Not compared (no counterpart; name one with --as CONFIG=NAME): scripted" in out
    # the other measures beside cab's intervals: stopping shares (Wilson) and medians (bootstrap)
    side = {m["measure"]: m for m in oracle["measures"]}
    assert side["stop_done"]["other"] == pytest.approx(63 / 75) and side["stop_done"]["cab_count"] == [4, 4]
    assert side["wall_seconds_median"]["other"] == 1193.1 and side["wall_seconds_median"]["other_inside"] is False
    lo, hi = side["sim_seconds_median"]["interval"]
    assert lo <= side["sim_seconds_median"]["cab"] <= hi
    assert side["calls_mean"]["other"] == 36.1
    # the forest plot: one marked point per tested measure
    svg = (tmp_path / "figures" / "against_forest.svg").read_text()
    assert all(f'id="against_forest-point-{i}"' in svg for i in range(4))
    assert (tmp_path / "figures" / "against_forest.pdf").stat().st_size > 0
    assert "| oracle (direct" in (tmp_path / "against.md").read_text()


def test_a_configuration_named_like_the_papers_meets_its_row_unasked(sweep, tmp_path, capsys, process_plugins):
    """Any plugin may ship a paper's figures; a row whose cab model and harness are the sweep's
    configuration's meets it without --as."""
    figures = {"configurations": [{"name": "Oracle (Direct)", "cab": {"model": "oracle", "harness": "direct"},
                                   "consistency": {"success": 3, "coverage": 2, "tasks_by_successes": {"0/2": 0, "1/2": 1, "2/2": 1}},
                                   "termination": {"stopping": {"done": 4, "tool": 0, "phys": 0, "other": 0}},
                                   "resource_use": {"calls_mean": 20.0}}]}
    mod = types.ModuleType("my_paper_plugin")
    mod.cab_published_figures = hookimpl(lambda: {"my_paper": lambda: figures})
    process_plugins(mod, "my_paper_plugin")
    report_main([str(sweep), "--out", str(tmp_path), "--no-views", "--no-figure-files", "--against", "my_paper"])
    a = json.loads((tmp_path / "against.json").read_text())
    assert [(r["config"].split(" ")[0], r["other"]) for r in a["rows"]] == [("oracle", "Oracle (Direct)")]
    assert a["rows"][0]["tested"][0]["other"] == [3, 4] and a["rows"][0]["tested"][1]["other"] == [2, 2]
    assert a["rows"][0]["verdict"] == "consistent with the paper"
    assert not (tmp_path / "figures").exists()


# --- against an earlier run ----------------------------------------------------------------------
def earlier_run(sweep: Path, folder: Path, fail_oracle: bool = False, budget: str | None = None) -> Path:
    """A hand-made earlier run: a copy of the sweep's records, the oracle's successes turned into
    failures (``fail_oracle``), every record's contract set, its budget part ``budget`` if given."""
    shutil.copytree(sweep, folder, ignore=shutil.ignore_patterns("*.mp4", "observations", "view.html"))
    for p in folder.glob("*/*/seed-*/attempt-*/result.json"):
        r = json.loads(p.read_text())
        if fail_oracle and r["model"] == "oracle":
            r["verdict"]["success"] = False
        parts = {"tools": "a" * 64, "task": "b" * 64, "budget": (budget or "c") * 64, "simulator": "d" * 64}
        r["contract"] = {"digest": ("e" if budget else "f") * 64, "parts": parts}
        p.write_text(json.dumps(r))
    return folder


def test_against_an_earlier_run_the_same_records_are_consistent(sweep, tmp_path, capsys):
    mine, earlier = earlier_run(sweep, tmp_path / "mine"), earlier_run(sweep, tmp_path / "earlier")
    report_main([str(mine), "--out", str(tmp_path / "out"), "--no-views", "--against", str(earlier)])
    a = json.loads((tmp_path / "out" / "against.json").read_text())
    assert a["kind"] == "run" and len(a["rows"]) == 3 and a["unmatched"] == []
    for row in a["rows"]:
        assert row["config"] == row["other"] and row["verdict"] == "consistent with the earlier run"
        assert [t["fisher_p"] for t in row["tested"]] == [1.0, 1.0]
        n = row["tested"][0]["cab"][1]
        assert row["contract"] == {"cab": n, "other": n, "differs_in": [], "exploratory": False}
        assert {t["task"] for t in row["per_task"]} == {"beat_block_hammer", "stack_blocks_three"}
    oracle = next(r for r in a["rows"] if r["config"].startswith("oracle"))
    assert oracle["per_task"][0]["cab"] == oracle["per_task"][0]["other"] == [2, 2]
    assert "EXPLORATORY" not in capsys.readouterr().out



def _oracle_differs(a: dict) -> dict:
    """The oracle's row of against.json when the other side's oracle succeeded 0 of 4 times."""
    oracle = next(r for r in a["rows"] if r["config"].startswith("oracle"))
    assert oracle["tested"][0]["cab"] == [4, 4] and oracle["tested"][0]["other"] == [0, 4]
    assert oracle["tested"][0]["fisher_p"] == pytest.approx(sps.fisher_exact([[4, 0], [0, 4]]).pvalue)
    assert oracle["verdict"].startswith("differs: success 4/4 vs 0/4 (")
    return oracle


def test_against_an_earlier_run_a_real_difference_and_a_contract_that_differs(sweep, tmp_path, capsys):
    mine = earlier_run(sweep, tmp_path / "mine")
    earlier = earlier_run(sweep, tmp_path / "earlier", fail_oracle=True, budget="9")
    report_main([str(mine), "--out", str(tmp_path / "out"), "--no-views", "--against", str(earlier)])
    out = capsys.readouterr().out
    a = json.loads((tmp_path / "out" / "against.json").read_text())
    oracle = _oracle_differs(a)
    assert [t["other"] for t in oracle["per_task"]] == [[0, 2], [0, 2]]
    idle = next(r for r in a["rows"] if r["config"].startswith("idle"))
    assert idle["verdict"] == "consistent with the earlier run"
    assert all(r["contract"]["differs_in"] == ["budget"] and r["contract"]["exploratory"] for r in a["rows"])
    assert re.search(r"oracle \(direct, \w+\): EXPLORATORY, the two runs' contracts differ in budget\.", out)


# --- bad input -----------------------------------------------------------------------------------
@pytest.mark.parametrize("args,message", [
    (["--against", "nopaper"], "cab-report: no published figures named 'nopaper' (installed: paper"),
    (["--against", "paper", "--as", "oracle"], "cab-report: --as takes CONFIG=NAME"),
    (["--against", "paper", "--as", "oracle=Nobody (Reference)"],
     "cab-report: --as oracle (direct"),
    (["--against", "paper", "--as", "nobody=" + OPUS], "cab-report: no configuration of the sweep 'nobody'"),
])
def test_bad_input_is_one_line_and_exit_2(sweep, tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as e:
        report_main([str(sweep), "--out", str(tmp_path), "--no-views", "--no-figure-files", *args])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(message) and not (tmp_path / "against.json").exists()


def test_as_without_against_is_refused(sweep, capsys):
    with pytest.raises(SystemExit) as e:
        report_main([str(sweep), "--as", f"oracle={OPUS}"])
    assert e.value.code == 2 and "--as CONFIG=NAME goes with --against" in capsys.readouterr().err


# --- against an exported result (cab-export leaderboard) -----------------------------------------
def _export(sweep: Path, folder: Path) -> Path:
    from cab_core.apps import export as ex

    ex.main(["leaderboard", str(sweep), "--out", str(folder)])
    return folder / "leaderboard.jsonl"


def _edit(path: Path, config_prefix: str, change) -> None:
    """Rewrite the row of ``path`` whose configuration starts with ``config_prefix`` through ``change``."""
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    for row in rows:
        if row["config"].startswith(config_prefix):
            change(row)
    path.write_text("".join(json.dumps(row) + "\n" for row in rows))


def test_against_its_own_export_every_configuration_is_consistent(sweep, tmp_path, capsys):
    lb = _export(sweep, tmp_path / "lb")
    exported = {r["config"]: r for r in map(json.loads, lb.read_text().splitlines())}
    report_main([str(sweep), "--out", str(tmp_path / "out"), "--no-views", "--against", str(lb)])
    out = capsys.readouterr().out
    a = json.loads((tmp_path / "out" / "against.json").read_text())
    assert a["kind"] == "export" and a["unmatched"] == [] and len(a["rows"]) == 3
    for row in a["rows"]:
        e = exported[row["config"]]
        assert row["other"] == row["config"] and row["verdict"] == "consistent with the exported run"
        assert [(t["cab"], t["other"]) for t in row["tested"]] == [
            ([e["successes"], e["attempts"]], [e["successes"], e["attempts"]]),
            ([e["tasks_covered"], e["tasks"]], [e["tasks_covered"], e["tasks"]])]
        assert [t["fisher_p"] for t in row["tested"]] == [1.0, 1.0] and row["per_task"] == []
        assert row["contract"]["cab"] == e["contract_digest"] is not None and not row["contract"]["exploratory"]
        assert f"{row['config']}: the exported row carries no per-task success: per-task success is not compared" in out
    assert "| exported run |" in out and "EXPLORATORY" not in out
    # a folder holding the file (and no attempt records) is read the same way
    report_main([str(sweep), "--out", str(tmp_path / "out2"), "--no-views", "--no-figure-files",
                 "--against", str(tmp_path / "lb")])
    assert json.loads((tmp_path / "out2" / "against.json").read_text())["rows"] == a["rows"]


def test_against_an_edited_export_the_verdict_and_the_contract_change(sweep, tmp_path, capsys):
    from cab_core.analysis.measures import wilson

    lb = _export(sweep, tmp_path / "lb")

    def no_successes(row):  # one count edited (the interval with it, else the file is refused)
        row.update(successes=0, success_rate=0.0, wilson95=list(wilson(0, row["attempts"])), tasks_covered=0,
                   per_task={"beat_block_hammer": {"successes": 0, "attempts": 2}})

    def other_budget(row):
        row["contract_parts"]["budget"] = "9" * 64
        row["contract_digest"] = "0" * 64

    _edit(lb, "oracle", no_successes)
    _edit(lb, "idle", other_budget)
    report_main([str(sweep), "--out", str(tmp_path / "out"), "--no-views", "--no-figure-files", "--against", str(lb)])
    out = capsys.readouterr().out
    a = json.loads((tmp_path / "out" / "against.json").read_text())
    oracle = _oracle_differs(a)
    assert oracle["per_task"] == [{"task": "beat_block_hammer", "cab": [2, 2], "other": [0, 2],
                                   "fisher_p": pytest.approx(sps.fisher_exact([[2, 0], [0, 2]]).pvalue)}]
    assert oracle["contract"]["differs_in"] == []
    idle = next(r for r in a["rows"] if r["config"].startswith("idle"))
    assert idle["verdict"] == "consistent with the exported run"
    assert idle["contract"]["differs_in"] == ["budget"] and idle["contract"]["exploratory"]
    assert re.search(r"idle \(direct, \w+\): EXPLORATORY, its contract and the exported row's differ in budget\.", out)
    assert not re.search(r"oracle \(direct, \w+\): the exported row carries no per-task success", out)


def test_an_exported_row_without_a_contract_is_noted(sweep, tmp_path, capsys):
    lb = _export(sweep, tmp_path / "lb")
    _edit(lb, "scripted", lambda row: row.update(contract_digest=None, contract_parts={}))
    report_main([str(sweep), "--out", str(tmp_path / "out"), "--no-views", "--no-figure-files", "--against", str(lb)])
    assert re.search(r"scripted \([^)]*\): not checked for comparability: the exported row scripted \([^)]*\) carries "
                     r"no comparison contract\.", capsys.readouterr().out)


@pytest.mark.parametrize("content,message", [
    ("not json\n", "leaderboard.jsonl:1: not JSON"),
    ("", "no leaderboard row to compare with"),
    ('{"format": "cab-leaderboard/1"}\n', "leaderboard.jsonl:1: missing config"),
])
def test_a_bad_exported_file_is_one_line_and_exit_2(sweep, tmp_path, capsys, content, message):
    (tmp_path / "leaderboard.jsonl").write_text(content)
    with pytest.raises(SystemExit) as e:
        report_main([str(sweep), "--out", str(tmp_path / "out"), "--no-views", "--no-figure-files",
                     "--against", str(tmp_path / "leaderboard.jsonl")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("cab-report: ") and message in err[-1] and not (tmp_path / "out" / "against.json").exists()


def test_an_exported_row_of_another_name_is_met_through_as(sweep, tmp_path, capsys):
    lb = _export(sweep, tmp_path / "lb")
    _edit(lb, "oracle", lambda row: row.update(config="oracle, last year", model="oracle-0"))
    report_main([str(sweep), "--out", str(tmp_path / "a"), "--no-views", "--no-figure-files", "--against", str(lb)])
    assert [u.split(" ")[0] for u in json.loads((tmp_path / "a" / "against.json").read_text())["unmatched"]] == ["oracle"]
    report_main([str(sweep), "--out", str(tmp_path / "b"), "--no-views", "--no-figure-files", "--against", str(lb),
                 "--as", "oracle=oracle, last"])
    a = json.loads((tmp_path / "b" / "against.json").read_text())
    oracle = next(r for r in a["rows"] if r["config"].startswith("oracle"))
    assert a["unmatched"] == [] and oracle["other"] == "oracle, last year"
    assert oracle["verdict"] == "consistent with the exported run"


def test_an_exported_per_task_count_that_does_not_fit_is_one_line(sweep, tmp_path, capsys):
    lb = _export(sweep, tmp_path / "lb")
    _edit(lb, "oracle", lambda row: row.update(per_task={"beat_block_hammer": {"successes": 3, "attempts": 2}}))
    with pytest.raises(SystemExit) as e:
        report_main([str(sweep), "--out", str(tmp_path / "out"), "--no-views", "--no-figure-files", "--against", str(lb)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert re.match(r"cab-report: .*leaderboard\.jsonl: row 1 \(oracle \(direct, \w+\)\): per_task should map each task", err)
