"""``cab-export leaderboard`` (cab_core.analysis.leaderboard, docs/export.md): one JSON row per
configuration with its provenance, read back with ``leaderboard.read``; every count survives the
round trip and equals cab-report's. Expected values come from the sweep's result.json files directly
(attempt_records.results) and from cab-report's build. Also: ``cab-export eee`` where its plugin is
not installed (Python 3.11: every-eval-ever needs 3.12) is one line naming the Python it needs."""
import json
from collections import defaultdict

import pytest
from attempt_records import results

from cab_core.analysis import contract, leaderboard, report, summary
from cab_core.analysis.measures import wilson
from cab_core.apps import export as ex
from cab_core.errors import RecordError

#: published figures in the hook's shape (cab_published_figures): the oracle labelled as a paper
#: configuration, as a suite would ship a paper's row; the idle agent has no paper row
FIGURES = {
    "source": {"title": "A paper", "attempts_per_configuration": 75, "tasks": 25},
    "tables": {"consistency": {"label": "tab:consistency", "caption": "Attempt success and task coverage"}},
    "configurations": [{"name": "Oracle (Direct)", "cab": {"model": "oracle", "harness": "direct"},
                        "consistency": {"success": 70, "coverage": 24}}],
}


def _truth(sweep):
    """Per configuration label, from result.json: attempts, successes, tasks, tasks covered, seeds,
    cab versions, contracts."""
    by = defaultdict(list)
    for r in results(sweep):
        by[f"{r['model']} ({r['harness']}, {r['sim']})"].append(r)
    out = {}
    for label, rs in by.items():
        tasks = defaultdict(list)
        for r in rs:
            tasks[r["task"]].append(r["verdict"]["success"])
        out[label] = {"attempts": len(rs), "successes": sum(r["verdict"]["success"] for r in rs),
                      "tasks": len(tasks), "tasks_covered": sum(any(v) for v in tasks.values()),
                      "seeds": sorted({r["seed"] for r in rs}), "sim": {r["sim"] for r in rs},
                      "cab_versions": sorted({r["versions"]["cab"] for r in rs}),
                      "contracts": [r.get("contract") for r in rs]}
    return out


@pytest.fixture(scope="module")
def exported(sweep, tmp_path_factory):
    out = tmp_path_factory.mktemp("leaderboard")
    ex.main(["leaderboard", str(sweep), "--out", str(out)])
    return out / leaderboard.FILE


@pytest.mark.sim
def test_a_round_trip_through_the_leaderboard_keeps_every_count(sweep, exported):
    rows = leaderboard.read(exported)
    lines = [json.loads(line) for line in exported.read_text().splitlines()]
    assert rows == lines and all(list(r) == list(leaderboard.KEYS) for r in rows)
    truth = _truth(sweep)
    shown = report.build(sweep)["configs"]  # cab-report's figures, in its order
    assert [r["config"] for r in rows] == [c["config"] for c in shown] and set(truth) == {r["config"] for r in rows}
    for row, c in zip(rows, shown):
        t = truth[row["config"]]
        assert (row["attempts"], row["successes"], row["tasks"], row["tasks_covered"]) == \
            (t["attempts"], t["successes"], t["tasks"], t["tasks_covered"]) == \
            (c["attempts"], c["successes"], c["tasks"], c["coverage"])
        assert row["wilson95"] == list(c["wilson95"]) == list(wilson(t["successes"], t["attempts"]))
        assert row["success_rate"] == c["success_rate"]
        assert row["seeds"] == t["seeds"] and {row["simulator"]} == t["sim"]
        assert row["cab_versions"] == t["cab_versions"] and row["cab_version"] == t["cab_versions"][0]
        # the configuration's contract: each part the digest of the sorted set of its attempts' digests
        # of that part (contract.combined, as sweep.json keeps it); a sweep of records without
        # contracts has none
        if None in t["contracts"]:
            assert row["contract_digest"] is None and row["contract_parts"] == {}
        else:
            names = sorted({p for c in t["contracts"] for p in c["parts"]})
            parts = {p: contract.digest(sorted({c["parts"].get(p) or "" for c in t["contracts"]})) for p in names}
            assert row["contract_parts"] == parts and parts
            assert row["contract_digest"] == contract.combined(t["contracts"])["digest"]
            assert len({c["digest"] for c in t["contracts"]}) > 1  # the tasks differ: one contract each
        assert row["model"] in row["config"] and row["harness"] == "direct"
    assert sum(r["attempts"] for r in rows) == len(results(sweep)) == 10


@pytest.mark.sim
def test_a_configuration_that_reproduces_a_papers_names_it(sweep, tmp_path):
    rows = {r["config"]: r for r in leaderboard.rows(sweep, report.build(sweep), FIGURES)}
    oracle = next(r for c, r in rows.items() if c.startswith("oracle "))
    assert oracle["name_in_paper"] == "Oracle (Direct)"
    assert oracle["reported_table"] == "tab:consistency Attempt success and task coverage"
    assert (oracle["paper_successes"], oracle["paper_attempts"], oracle["paper_tasks_covered"],
            oracle["paper_tasks"]) == (70, 75, 24, 25)
    idle = next(r for c, r in rows.items() if c.startswith("idle "))
    assert idle["name_in_paper"] is None and idle["reported_table"] is None and idle["paper_successes"] is None
    path = leaderboard.write(list(rows.values()), tmp_path / "lb.jsonl")
    assert leaderboard.read(path) == list(rows.values())


@pytest.mark.sim
def test_a_configuration_labelled_as_the_papers(sweep, tmp_path, capsys):
    """``--as CONFIG=NAME`` (as cab-report --against paper takes it) with the installed suites' own
    published figures: the oracle labelled as a paper configuration carries that row's counts."""
    figures = summary.published()
    if figures is None:
        pytest.skip("no installed task suite ships published figures")
    paper = figures["configurations"][1]
    ex.main(["leaderboard", str(sweep), "--out", str(tmp_path), "--as", f"oracle={paper['name']}"])
    rows = {r["config"]: r for r in leaderboard.read(tmp_path / leaderboard.FILE)}
    assert "1 with a paper configuration" in capsys.readouterr().out
    oracle = next(r for c, r in rows.items() if c.startswith("oracle "))
    table = figures["tables"]["consistency"]
    assert oracle["name_in_paper"] == paper["name"] and oracle["reported_table"] == f"{table['label']} {table['caption']}"
    assert (oracle["paper_successes"], oracle["paper_tasks_covered"]) == \
        (paper["consistency"]["success"], paper["consistency"]["coverage"])
    assert (oracle["paper_attempts"], oracle["paper_tasks"]) == \
        (figures["source"]["attempts_per_configuration"], figures["source"]["tasks"])
    assert all(r["name_in_paper"] is None for c, r in rows.items() if r is not oracle)
    for label, says in [(f"nosuch={paper['name']}", "no configuration of the sweep 'nosuch'"),
                        ("oracle=No Such Model (Harness)", "no such configuration in the published figures")]:
        with pytest.raises(SystemExit) as e:
            ex.main(["leaderboard", str(sweep), "--out", str(tmp_path), "--as", label])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1 and says in err[0]


@pytest.mark.sim
def test_a_row_whose_counts_do_not_fit_is_refused_in_one_line(exported, tmp_path):
    row = json.loads(exported.read_text().splitlines()[0])
    cases = [({"successes": row["attempts"] + 1}, "more than possible"),
             ({"successes": row["successes"] - 1 if row["successes"] else 1}, "is not the interval of"),
             ({"attempts": -1}, "attempts should be a count"),
             ({"tasks_covered": 1.5}, "tasks_covered should be a count")]
    for change, says in cases:
        bad = tmp_path / "bad.jsonl"
        bad.write_text(json.dumps({**row, **change}) + "\n")
        with pytest.raises(RecordError, match=says) as e:
            leaderboard.read(bad)
        assert "\n" not in str(e.value) and str(bad) in str(e.value)
    bad.write_text(json.dumps({k: v for k, v in row.items() if k != "seeds"}) + "\n")
    with pytest.raises(RecordError, match="missing seeds"):
        leaderboard.read(bad)
    bad.write_text("{not json\n")
    with pytest.raises(RecordError, match=r"bad.jsonl:1: not JSON"):
        leaderboard.read(bad)


def test_the_eee_exporter_on_an_older_python_is_one_line(capsys, monkeypatch, tmp_path):
    """Where the eee plugin is not installed, the line says which Python its plugin needs (read
    from plugins/export_eee/pyproject.toml) on 3.11, and how to install it on 3.12."""
    monkeypatch.setattr(ex, "sweep_exporters", lambda: {})
    monkeypatch.setattr(ex.platform, "python_version", lambda: "3.11.7")
    with pytest.raises(SystemExit) as e:
        ex.main(["eee", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1
    assert err[0].startswith("cab-export: no exporter 'eee' is installed: its plugin (export_eee) needs "
                             "Python >=3.12 and this is Python 3.11.7")
    assert "bash scripts/install.sh" in err[0]
    monkeypatch.setattr(ex.platform, "python_version", lambda: "3.12.1")
    with pytest.raises(SystemExit):
        ex.main(["eee", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"install it with: pip install -e {ex.Path(ex.__file__).resolve().parents[2] / 'plugins' / 'export_eee'}")


def test_the_docs_list_every_leaderboard_key():
    doc = (ex.Path(ex.__file__).resolve().parents[2] / "docs" / "export.md").read_text()
    for name, kind, _ in leaderboard.COLUMNS:
        assert f"| `{name}` | {kind} |" in doc, name
