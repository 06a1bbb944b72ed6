"""The comparison contract (cab_core.analysis.contract): the digest's canonical form, the same digest
for the same set-up on another machine, one part named per difference, the record and manifest
fields, and cab-report's refusal (or exploratory table) for attempts whose contracts differ."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_module

from cab_core.analysis.contract import (
    PARTS,
    ContractsDiffer,
    canonical_json,
    combined,
    differing,
    digest,
    of_result,
    report_check,
)
from cab_core.analysis.report import build
from cab_core.apps.cli import normalise_overrides
from cab_core.apps.report_cli import main as report_main
from cab_core.attempt.engine.contract import attempt_contract
from cab_core.attempt.records.result_format import MalformedRecord, parse_record
from cab_core.attempt.runner import attempt_spec
from cab_core.errors import RecordError

# the spec of one attempt, in a fresh interpreter with the given overrides; prints its contract
SPEC_SCRIPT = """
import json, sys
from hydra import compose, initialize_config_module
from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.engine.contract import attempt_contract
from cab_core.attempt.runner import attempt_spec
from cab_core.attempt.engine.contract import attempt_contract
with initialize_config_module(version_base=None, config_module="cab_core.conf"):
    cfg = compose(config_name="config", overrides=normalise_overrides(sys.argv[2:]))
print(json.dumps(attempt_contract(attempt_spec(cfg, sys.argv[1]))))
"""
BASE = ["task=click_bell", "sim=mujoco", "model=idle", "seed=3"]


def contract_elsewhere(tmp_path: Path, name: str, overrides: list[str], env: dict[str, str]) -> dict:
    """The contract of ``overrides`` computed by another process, in another working and output
    folder, under another environment (what a second machine changes)."""
    where = tmp_path / name
    where.mkdir()
    p = subprocess.run([sys.executable, "-c", SPEC_SCRIPT, str(where / "out"), *overrides], cwd=where,
                       env={**os.environ, **env}, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def spec_here(out: Path, *overrides: str):
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(list(overrides)))
    return attempt_spec(cfg, out)


def test_the_same_set_up_elsewhere_has_the_same_digest_and_one_budget_changes_one_part(tmp_path):
    a = contract_elsewhere(tmp_path, "a", BASE, {"HOSTNAME": "machine-a", "CAB_NUMERICS": "native"})
    b = contract_elsewhere(tmp_path, "b", [*BASE, "sweep.hang_timeout_s=77", "record.video=false"],
                           {"HOSTNAME": "machine-b", "CAB_NUMERICS": "pinned", "TMPDIR": str(tmp_path)})
    assert a == b
    assert set(a["parts"]) == set(PARTS) - {"serving"}  # no serving engine known for a model-free agent
    c = attempt_contract(spec_here(tmp_path / "c", *BASE, "budget.tool_calls=7"))
    assert attempt_contract(spec_here(tmp_path / "d", *BASE)) == a  # and in this process too
    assert differing(a, c) == ["budget"]
    assert c["digest"] != a["digest"]


def test_canonical_form_is_independent_of_numpy_and_key_order():
    plain = {"b": 60, "a": [0.5, 2, None, "x"]}
    with_numpy = {"a": [np.float64(0.5), np.int64(2), None, "x"], "b": 60.0}
    assert canonical_json(plain) == canonical_json(with_numpy) == '{"a":[0.5,2,null,"x"],"b":60}'
    # fixed values: a change of the canonical form would change every recorded digest
    assert digest(plain) == "a6e6597a90ac3643d616fc0d97d4572df62f5483988445b1f94d6c75cbbfe5c9"
    assert digest(0.1) == "14be4b45f18e0d8c67b4f719b5144eee88497e413709d11d85b096d8e2346310"  # the shortest repr of a float, as every Python since 3.1 writes it
    with pytest.raises(RecordError, match="non-finite"):
        digest({"x": float("nan")})


def _c(**parts: str) -> dict:
    full = {p: digest(p) for p in PARTS if p != "serving"}
    full.update({k: digest(v) for k, v in parts.items()})
    return {"digest": digest(full), "parts": full}


def test_differing_names_parts_in_order_and_a_part_only_one_side_has():
    a, b = _c(), _c(simulator="other", budget="other")
    assert differing(a, a) == []
    assert differing(a, b) == ["budget", "simulator"]
    assert differing(a, _c(serving="vllm 0.11")) == ["serving"]


def test_of_result_reads_checks_and_tolerates_older_records():
    c = _c()
    assert of_result({"contract": c}) == c
    assert of_result({}) is None
    with pytest.raises(RecordError, match="part 'budget' should be a SHA-256"):
        of_result({"contract": {"digest": c["digest"], "parts": {**c["parts"], "budget": 3}}})
    with pytest.raises(RecordError, match="contract should be"):
        of_result({"contract": "abc"})


def test_report_check_allows_what_the_configurations_name_and_nothing_else():
    def row(config, on="t1", sim="mujoco", **parts):
        return {"config": config, "task": on, "sim": sim, "harness": "direct", "contract": _c(**parts)}

    # two simulators are two configurations; each task has its own definition and budgets; instances differ
    same = [row("a", simulator="m"), row("b", sim="sapien", simulator="s"),
            row("a", on="t2", simulator="m", task="t2 task", budget="t2 budget"),
            row("b", on="t2", sim="sapien", simulator="s", task="t2 task", budget="t2 budget", seeds="seed 2")]
    assert report_check(same) == []
    assert report_check([row("a"), row("b", budget="7 calls")]) == ["budget"]
    assert report_check([row("a"), row("a", on="t2", task="changed verifier"),
                         row("b", on="t2", task="the old one")]) == ["task"]
    assert report_check([row("a"), row("a", simulator="other physics")]) == ["simulator"]
    assert report_check([row("a"), row("b", tools="other tools", planner="mplib")]) == ["tools", "planner"]
    assert report_check([row("a", serving="vllm"), row("a")]) == ["serving"]
    assert report_check([row("a", serving="vllm"), row("b", serving="ollama")]) == []
    assert report_check([row("a"), {**row("b", budget="x"), "contract": None}]) == []  # an older record


def test_combined_is_over_the_set_of_each_parts_digests():
    a, b = _c(seeds="1"), _c(seeds="2")
    assert combined([a, b]) == combined([b, a, b])
    assert differing(combined([a, b]), combined([a])) == ["seeds"]


def test_the_record_model_takes_the_contract_and_checks_its_types():
    rec = {"record_version": "cab-record/1", "task": "t", "seed": 0, "attempt": 1, "sim": "mujoco", "model": "m",
           "harness": "direct", "verdict": {"success": True}, "termination": {"reason": "done"}, "claim": {},
           "budget": {}, "timing": {}, "versions": {}}
    c = _c()
    assert parse_record({**rec, "contract": c}).dump()["contract"] == c
    assert "contract" not in parse_record(rec).dump()
    with pytest.raises(MalformedRecord, match="contract.parts.budget should be a string"):
        parse_record({**rec, "contract": {"digest": "x", "parts": {"budget": 1}}})


@pytest.fixture(scope="module")
def two_sweeps(tmp_path_factory) -> Path:
    """Two real sweeps of click_bell on MuJoCo into one folder: oracle and idle with the task's budget,
    then idle again with budget.tool_calls=7 (named apart: model.name)."""
    root = tmp_path_factory.mktemp("contracts")
    cab = Path(sys.executable).with_name("cab")
    for name, extra in (("first", ["model=oracle,idle"]), ("second", ["model=idle", "model.name=idle7",
                                                                        "budget.tool_calls=7"])):
        p = subprocess.run([str(cab), "-m", "task=click_bell", "sim=mujoco", "seed=1", "record.video=false",
                            *extra, f"hydra.sweep.dir={root / name}"], cwd=root, capture_output=True, text=True,
                           timeout=300)
        assert p.returncode == 0, p.stderr[-3000:]
    return root


def test_results_and_manifest_carry_the_contract(two_sweeps):
    results = [json.loads(p.read_text()) for p in sorted((two_sweeps / "first").rglob("result.json"))]
    assert len(results) == 2
    manifest = json.loads((two_sweeps / "first" / "sweep.json").read_text())
    assert sorted(manifest["contracts"]) == ["idle (direct, mujoco)", "oracle (direct, mujoco)"]
    for r in results:
        c = of_result(r)
        assert c is not None and set(c["parts"]) == set(PARTS) - {"serving"}
        assert manifest["contracts"][f"{r['model']} (direct, mujoco)"] == combined([c])
    oracle, idle = (of_result(r) for r in sorted(results, key=lambda r: r["model"] != "oracle"))
    assert oracle == idle  # the model is what is compared, not part of the benchmark
    second = [json.loads(p.read_text()) for p in (two_sweeps / "second").rglob("result.json")]
    assert differing(idle, of_result(second[0])) == ["budget"]


def test_report_refuses_mixed_contracts_in_one_line_naming_the_part(two_sweeps, tmp_path, capsys):
    with pytest.raises(ContractsDiffer) as e:
        build(two_sweeps)
    assert e.value.parts == ["budget"]
    with pytest.raises(SystemExit) as ex:
        report_main([str(two_sweeps), "--out", str(tmp_path / "r"), "--no-views", "--no-figure-files"])
    assert ex.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"cab-report: the attempts under {two_sweeps} ran under different comparison contracts (they "
                   "differ in: budget); not put in one table: report them apart, or pass --mix-contracts for an "
                   "exploratory table"]
    assert not (tmp_path / "r").exists()
    build(two_sweeps / "first")  # one sweep alone: one contract, no refusal


def test_report_mixes_contracts_when_asked_and_marks_the_tables(two_sweeps, tmp_path, capsys):
    out = tmp_path / "r"
    report_main([str(two_sweeps), "--out", str(out), "--no-views", "--no-figure-files", "--mix-contracts",
                 "--compare", "oracle", "idle7"])
    captured = capsys.readouterr()
    r = json.loads((out / "report.json").read_text())
    assert r["contracts"]["exploratory"] is True and r["contracts"]["differing"] == ["budget"]
    assert set(r["contracts"]["by_config"]) == {"oracle (direct, mujoco)", "idle (direct, mujoco)",
                                                "idle7 (direct, mujoco)"}
    assert r["comparison"]["contracts_differ"] == ["budget"]
    md = (out / "report.md").read_text()
    assert "## Success and task coverage (EXPLORATORY: comparison contracts differ in budget)" in md
    assert "Paired comparison: A = oracle (direct, mujoco), B = idle7 (direct, mujoco) (EXPLORATORY" in md
    assert "cab-report: EXPLORATORY: comparison contracts differ in budget" in captured.err
    assert "Success and task coverage (EXPLORATORY: comparison contracts differ in budget)" in captured.out
    # two configurations of the same contract compared: not marked
    same = build(two_sweeps, compare=("oracle", "idle ("), mix_contracts=True)
    assert same["comparison"]["contracts_differ"] == []



@pytest.mark.parametrize("overrides", [[], ["budget.tool_calls=7", "seed=5", "attempt=2"], ["budget.sim_seconds=12.5"]])
def test_the_manifests_spec_per_task_is_the_attempts(tmp_path, overrides):
    """sweep_contracts validates one spec per composition and takes each task's budgets and seed as
    attempt_spec does: the same spec, task by task."""
    from cab_core.apps.sweep_contracts import _with_task

    first = spec_here(tmp_path, "task=click_bell", "sim=mujoco", "model=idle", *overrides)
    for task in ("beat_block_hammer", "stack_blocks_three", "open_microwave"):
        own = spec_here(tmp_path, f"task={task}", "sim=mujoco", "model=idle", *overrides)
        plain = {"task": {"name": task}, "budget": {k.split(".")[1]: float(v) if "." in v else int(v)
                                                    for k, v in (o.split("=") for o in overrides)
                                                    if k.startswith("budget.")}}
        plain.update({k: int(v) for k, v in (o.split("=") for o in overrides) if k in ("seed", "attempt")})
        assert _with_task(first, plain) == own
