"""``cab-export eee`` (plugin cab-export-eee, docs/export.md): the shared sweep as Every Eval Ever
records, validated with the every-eval-ever package's own validator (schema and its repository
checks: datastore paths, the aggregate/instance companion, model identity, score bounds), and
compared with the sweep's result.json and events.jsonl. every-eval-ever needs Python >= 3.12:
elsewhere this module is skipped (scripts/check-pythons.sh runs it on 3.12 and 3.13)."""
import json
from collections import defaultdict
from pathlib import Path

import pytest

pytest.importorskip("every_eval_ever")

from attempt_records import events, results  # noqa: E402
from every_eval_ever.validator.validate import main as eee_validate  # noqa: E402

from cab_core.analysis.contract import combined  # noqa: E402
from cab_core.analysis.measures import wilson  # noqa: E402
from cab_core.analysis.report import build  # noqa: E402
from cab_core.analysis.summary import sweep_data  # noqa: E402
from cab_core.apps import export as ex  # noqa: E402

#: published figures in the hook's shape: the oracle labelled as a paper configuration (filed beside
#: cab's record of it), and a paper configuration that is not in the sweep
FIGURES = {
    "source": {"title": "A paper", "attempts_per_configuration": 75, "tasks": 25},
    "tables": {"consistency": {"label": "tab:consistency", "caption": "Attempt success and task coverage"}},
    "configurations": [
        {"name": "Oracle (Direct)", "cab": {"model": "oracle", "harness": "direct"},
         "consistency": {"success": 70, "coverage": 24, "tasks_by_successes": {"0/3": 1, "3/3": 22}}},
        {"name": "Claude Opus 5 (Reference)", "cab": {"model": "opus5", "harness": "reference"},
         "model_id": "claude-opus-5", "consistency": {"success": 41, "coverage": 19}},
    ],
}


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    from attempt_records import shared_sweep

    return shared_sweep(tmp_path_factory)


@pytest.fixture(scope="module")
def exported(sweep, tmp_path_factory):
    from cab_export_eee.convert import export_sweep

    out = tmp_path_factory.mktemp("eee")
    return out, export_sweep(sweep_data(sweep, build(sweep), FIGURES), out, now=1795843230.5)


def _records(out: Path) -> list[tuple[Path, dict]]:
    return [(p, json.loads(p.read_text())) for p in sorted(out.glob("data/*/*/*/*.json"))]


@pytest.mark.sim
def test_the_export_validates_against_the_schema(exported):
    out, written = exported
    assert written and all(p.is_file() for p in written)
    assert sorted(written) == sorted(p for p in out.rglob("*") if p.is_file())
    # the package's validator (every_eval_ever validate): 0 = every file valid, no warnings
    assert eee_validate([str(p) for p in written] + ["--format", "json"]) == 0


@pytest.mark.sim
def test_aggregates_carry_the_counts_and_wilson_intervals(sweep, exported):
    out, _ = exported
    by = defaultdict(list)
    for r in results(sweep):
        by[r["model"]].append(r)
    runs = {rec["model_info"]["id"]: rec for _, rec in _records(out)
            if rec["source_metadata"]["source_type"] == "evaluation_run"}
    assert set(runs) == {f"cab/{m}" for m in by}
    for model, rs in by.items():
        rec = runs[f"cab/{model}"]
        k, n = sum(r["verdict"]["success"] for r in rs), len(rs)
        res = {e["evaluation_result_id"]: e for e in rec["evaluation_results"]}
        s = res["attempt_success"]["score_details"]
        lo, hi = wilson(k, n)
        assert s["score"] == k / n and s["details"] == {"successes": str(k), "attempts": str(n)}
        assert s["uncertainty"]["confidence_interval"] == {"lower": lo, "upper": hi, "confidence_level": 0.95,
                                                           "method": "wilson"}
        assert s["uncertainty"]["num_samples"] == n
        tasks = defaultdict(list)
        for r in rs:
            tasks[r["task"]].append(r["verdict"]["success"])
        cov = res["task_coverage"]["score_details"]
        assert cov["score"] == sum(any(v) for v in tasks.values()) / len(tasks)
        for task, v in tasks.items():
            t = res[f"attempt_success/{task}"]["score_details"]
            assert t["score"] == sum(v) / len(v)
            assert [t["uncertainty"]["confidence_interval"][b] for b in ("lower", "upper")] == list(wilson(sum(v), len(v)))
        gen = res["attempt_success"]["generation_config"]["additional_details"]
        assert gen["simulator"] == rs[0]["sim"] and gen["harness"] == "direct" and gen["cab_version"] == rs[0]["versions"]["cab"]
        whole = None if any(r.get("contract") is None for r in rs) else combined([r["contract"] for r in rs])
        assert gen.get("contract_digest") == (whole["digest"] if whole else None)
        assert rec["detailed_evaluation_results"]["total_rows"] == n


@pytest.mark.sim
def test_instances_are_the_agentic_interactions(sweep, exported):
    out, _ = exported
    samples = [json.loads(line) for p in sorted(out.glob("data/*/*/*/*_samples.jsonl"))
               for line in p.read_text().splitlines()]
    assert len(samples) == len(results(sweep)) == 10
    for s in samples:
        d = sweep / s["metadata"]["attempt_key"]
        r = json.loads((d / "result.json").read_text())
        calls = [e for e in events(d) if e["kind"] in ("call", "call_refused")]
        assert s["interaction_type"] == "agentic" and s["input"]["raw"] == r["instruction"]
        assert s["evaluation"]["is_correct"] is r["verdict"]["success"]
        assert s["evaluation"]["score"] == (1.0 if r["verdict"]["success"] else 0.0)
        msgs = s["messages"]
        assert msgs[0] == {"turn_idx": 0, "role": "user", "content": r["instruction"]}
        assert [m["turn_idx"] for m in msgs] == list(range(len(msgs)))
        asked = [c for m in msgs if m["role"] == "assistant" for c in m.get("tool_calls") or []]
        assert [c["name"] for c in asked] == [e["tool"] for e in calls]  # model-free agents: one turn a call
        assert s["evaluation"]["tool_calls_count"] == len(calls)
        answered = [m["tool_call_id"][0] for m in msgs if m["role"] == "tool"]
        assert answered == [c["id"] for c in asked]
        done = [c for c in asked if c["name"] == "done"]
        if r["claim"].get("success_claim") is None:
            assert s["answer_attribution"] == [] and not done
        else:
            (a,) = s["answer_attribution"]
            assert json.loads(a["extracted_value"]) == {"success_claim": r["claim"]["success_claim"],
                                                        "report": r["claim"]["report"]}
            assert msgs[a["turn_idx"]]["tool_calls"][0]["name"] == "done" and a["is_terminal"]
        assert s["sample_id"] == f"{r['task']}/seed-{r['seed']}/attempt-{r['attempt']}"


@pytest.mark.sim
def test_the_papers_figures_are_documentation_beside_the_run(exported):
    out, _ = exported
    docs = [(p, rec) for p, rec in _records(out) if rec["source_metadata"]["source_type"] == "documentation"]
    assert len(docs) == 2
    by_name = {rec["source_metadata"]["additional_details"]["name_in_paper"]: (p, rec) for p, rec in docs}
    p, rec = by_name["Oracle (Direct)"]
    run = next(q for q, r in _records(out) if r["source_metadata"]["source_type"] == "evaluation_run"
               and r["model_info"]["id"] == "cab/oracle")
    assert p.parent == run.parent  # filed beside cab's record of the same model
    res = {e["evaluation_result_id"]: e["score_details"] for e in rec["evaluation_results"]}
    assert res["attempt_success"]["score"] == 70 / 75
    assert [res["attempt_success"]["uncertainty"]["confidence_interval"][b] for b in ("lower", "upper")] == \
        list(wilson(70, 75))
    assert res["task_coverage"]["score"] == 24 / 25 and "detailed_evaluation_results" not in rec
    assert rec["source_metadata"]["additional_details"]["reported_table"].startswith("tab:consistency")
    p, rec = by_name["Claude Opus 5 (Reference)"]
    assert p.parent.relative_to(out).as_posix() == "data/cab/anthropic/claude-opus-5"
    assert rec["model_info"]["id"] == "anthropic/claude-opus-5"


@pytest.mark.sim
def test_a_labelled_configuration_has_the_papers_record_beside_it(sweep, tmp_path):
    """``--as idle=...``: the paper's row is filed beside the labelled configuration's record."""
    from cab_export_eee.convert import export_sweep

    export_sweep(sweep_data(sweep, build(sweep), FIGURES, {"idle": "Claude Opus 5 (Reference)"}), tmp_path)
    docs = {rec["source_metadata"]["additional_details"]["name_in_paper"]: p for p, rec in _records(tmp_path)
            if rec["source_metadata"]["source_type"] == "documentation"}
    assert docs["Claude Opus 5 (Reference)"].parent.relative_to(tmp_path).as_posix() == "data/cab/cab/idle"
    assert docs["Oracle (Direct)"].parent.relative_to(tmp_path).as_posix() == "data/cab/cab/oracle"
    assert eee_validate([str(p) for p in tmp_path.rglob("*.json*")] + ["--format", "json"]) == 0


@pytest.mark.sim
def test_cab_export_eee_writes_and_lists(sweep, tmp_path, capsys):
    assert "eee" in ex.sweep_exporters()
    ex.main(["eee", str(sweep), "--out", str(tmp_path)])
    lines = capsys.readouterr().out.strip().splitlines()
    files = sorted(tmp_path.rglob("*.json*"))
    assert lines[-1] == f"eee: {len(files)} files" and len(lines) == len(files) + 1
    assert eee_validate([str(p) for p in files] + ["--format", "json"]) == 0
    ex.main(["--list"])
    assert "eee" in capsys.readouterr().out.split()
