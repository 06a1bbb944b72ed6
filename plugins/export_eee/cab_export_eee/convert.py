"""A sweep as Every Eval Ever records (``cab-export eee``), built with the format's own pydantic
models (``every_eval_ever.eval_types``, ``every_eval_ever.instance_level_types``), so a record that
does not fit the schema is refused while it is made, not after. The sweep comes as the plain data
cab gives every sweep exporter (``cab_core.analysis.summary.sweep_data``: cab-report's figures and
intervals, the attempts' records, the paper's published figures).

Per configuration of the sweep (as cab-report names them), in the datastore layout
``data/<collection>/<developer>/<model>/<uuid>.json`` (the package's
``datastore_repo_file_path``):

- an aggregate record (``source_type: evaluation_run``): attempt success with its Wilson 95 %
  interval (cab-report's), task coverage, and success per task with its interval; budgets, simulator, embodiment, planner and the comparison contract's
  digest in ``generation_config``;
- its instance-level records (``<uuid>_samples.jsonl``), one per attempt, ``interaction_type:
  agentic``: the instruction, then the agent's turns as the conversation it had
  (:func:`cab_core.kits.harness.conversation.transcript`: a model's turns with the tool calls it
  asked for, or one turn per call for a model-free agent or an MCP client) and each call's result
  as a ``tool`` message; the verdict as the score, the ``done`` claim as the answer attribution.

Per configuration of the paper (a task suite's published figures, hook ``cab_published_figures``),
an aggregate record with ``source_type: documentation``: the paper's success and coverage counts,
with the Wilson interval cab computes from those counts, filed beside cab's record of the same model.
"""
from __future__ import annotations

import hashlib
import json
import re
import time
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from every_eval_ever.eval_types import (
    AgenticEvalConfig,
    AvailableTool,
    ConfidenceInterval,
    DetailedEvaluationResults,
    EvalLibrary,
    EvalLimits,
    EvaluationLog,
    EvaluationResult,
    EvaluatorRelationship,
    Format,
    GenerationArgs,
    GenerationConfig,
    HashAlgorithm,
    MetricConfig,
    ModelInfo,
    ScoreDetails,
    ScoreType,
    SourceDataPrivate,
    SourceMetadata,
    SourceType,
    StandardError,
    Uncertainty,
)
from every_eval_ever.helpers.io import datastore_repo_file_path
from every_eval_ever.instance_level_types import (
    AnswerAttributionItem,
    Evaluation,
    Input,
    InstanceLevelEvaluationLog,
    InteractionType,
    Message,
    Performance,
    TokenUsage,
    ToolCall,
)
from every_eval_ever.schema import get_schema_version

from cab_core.kits.harness.conversation import transcript

COLLECTION = "cab"  # data/<collection>/...: cab's runs and the paper's figures of its tasks, side by side
LIBRARY = "cab"
RESULT_TEXT_LIMIT = 2000  # characters of a call's result kept in its tool message
#: providers that are the model's developer (their API serves only their own models)
FIRST_PARTY = {"anthropic", "openai", "google"}
#: the developer of a model served by another provider, by the model id's first word (HF namespaces)
DEVELOPER_BY_PREFIX = {"claude": "anthropic", "gpt": "openai", "gemini": "google", "grok": "xai",
                       "kimi": "moonshotai", "qwen": "Qwen"}
SUCCESS_ID = "attempt_success"
COVERAGE_ID = "task_coverage"


def _strings(d: Mapping[str, Any]) -> dict[str, str]:
    """``additional_details`` of the schema: string values only (JSON text for the others), no nulls."""
    return {k: v if isinstance(v, str) else json.dumps(v, sort_keys=True) for k, v in d.items() if v is not None}


def _uuid4(*parts: str) -> str:
    """A UUID4-shaped identifier derived from ``parts``: the same sweep exported again writes the
    same files (the datastore requires version-4 file names)."""
    digest = hashlib.sha256("\x1f".join(parts).encode()).digest()
    return str(uuid.UUID(bytes=digest[:16], version=4))


def _model_cfg(a: Mapping[str, Any]) -> dict:
    start = next((e for e in a["events"] if e.get("kind") == "attempt_start"), {})
    cfg = (start.get("config") or {}).get("model_cfg")
    return cfg if isinstance(cfg, dict) else {}


def developer_of(model_id: str) -> str | None:
    """The developer a model id names by its first word (:data:`DEVELOPER_BY_PREFIX`), or None."""
    word = re.match(r"[a-z]*", model_id.lower())
    return DEVELOPER_BY_PREFIX.get(word.group(0)) if word else None


def paper_identity(conf: Mapping[str, Any]) -> ModelInfo | None:
    """The identity of a paper configuration that is not in the sweep, from its model id (None:
    no model id, or one whose developer :func:`developer_of` does not know)."""
    model_id = conf.get("model_id")
    developer = developer_of(str(model_id)) if model_id else None
    if developer is None:
        return None
    ident = str(model_id) if "/" in str(model_id) else f"{developer}/{model_id}"
    return ModelInfo(name=str(conf.get("name")), id=ident, developer=developer,
                     additional_details={"deployment_type": "unknown", "model_availability": "unknown"})


def model_identity(model: str, cfg: Mapping[str, Any], serving: Mapping[str, Any] | None = None) -> ModelInfo:
    """The EEE model identity of cab's model configuration ``model`` (its ``model_cfg``): id
    ``developer/model_id`` (a model-free agent: ``cab/<agent>``), inference platform the provider,
    deployment type from who serves it."""
    provider, model_id = cfg.get("provider"), cfg.get("model_id")
    serving = serving or {}
    if not provider or not model_id:  # a model-free agent (oracle, idle, scripted) or an MCP client
        return ModelInfo(name=model, id=f"cab/{model}", developer="cab",
                         additional_details={"deployment_type": "self_deployed", "model_availability": "unknown",
                                             "cab_model": model})
    model_id = str(model_id)
    developer = provider if provider in FIRST_PARTY else developer_of(model_id)
    ident = model_id if "/" in model_id or developer is None else f"{developer}/{model_id}"
    engine = serving.get("engine")
    details = {"deployment_type": ("externally_managed" if provider in FIRST_PARTY
                                   else "self_deployed" if engine else "unknown"),
               "model_availability": "unknown", "cab_model": model, "provider": str(provider)}
    return ModelInfo(name=model, id=ident, developer=developer or str(provider), inference_platform=str(provider),
                     inference_engine={"name": engine, "version": serving.get("version")} if engine else None,
                     additional_details=details)


def _proportion(description: str, metric_id: str, name: str) -> MetricConfig:
    return MetricConfig(evaluation_description=description, metric_id=metric_id, metric_name=name,
                        metric_kind="pass_rate", metric_unit="proportion", lower_is_better=False,
                        score_type=ScoreType.continuous, min_score=0.0, max_score=1.0)


def _rate(k: int, n: int, interval: list[float], method_note: str = "wilson") -> ScoreDetails:
    """``k`` successes out of ``n`` as a score with its Wilson 95 % ``interval`` (cab's) and the
    binomial standard error."""
    lo, hi = interval
    p = k / n
    return ScoreDetails(
        score=p, details={"successes": str(k), "attempts": str(n)},
        uncertainty=Uncertainty(
            confidence_interval=ConfidenceInterval(lower=lo, upper=hi, confidence_level=0.95, method=method_note),
            standard_error=StandardError(value=(p * (1 - p) / n) ** 0.5, method="analytic (binomial)"),
            num_samples=n))


def _source_data(tasks: list[str], seeds: list[int], extra: Mapping[str, Any] | None = None) -> SourceDataPrivate:
    return SourceDataPrivate(dataset_name="cab tasks", source_type="other",
                             additional_details=_strings({"tasks": ",".join(tasks), "seeds": seeds, **(extra or {})}))


def _generation(attempts: list[Mapping[str, Any]], contract: Mapping[str, Any] | None) -> GenerationConfig:
    """The set-up the configuration's attempts were played under: tools the agent called, budgets,
    simulator, embodiment, planner, the comparison contract (one value, or every value seen)."""
    def seen(get) -> Any:
        vals = sorted({json.dumps(v, sort_keys=True) for v in (get(a["result"]) for a in attempts) if v is not None})
        return json.loads(vals[0]) if len(vals) == 1 else [json.loads(v) for v in vals] or None

    budget = seen(lambda r: {k: (r.get("budget") or {}).get(k)
                             for k in ("tool_calls_limit", "sim_seconds_limit", "wall_seconds_limit")})
    tools = sorted({e.get("tool") for a in attempts for e in a["events"]
                    if e.get("kind") in ("call", "internal_call") and isinstance(e.get("tool"), str)})
    wall = budget.get("wall_seconds_limit") if isinstance(budget, dict) else None
    return GenerationConfig(
        generation_args=GenerationArgs(
            agentic_eval_config=AgenticEvalConfig(
                available_tools=[AvailableTool(name=t) for t in tools],
                additional_details={"tools_listed": "the tools the agent called in these attempts"}),
            eval_limits=EvalLimits(time_limit=int(wall) if isinstance(wall, (int, float)) else None),
            max_attempts=1),
        additional_details=_strings({
            "harness": seen(lambda r: r.get("harness")), "simulator": seen(lambda r: r.get("sim")),
            "embodiment": seen(lambda r: r.get("embodiment")), "planner": seen(lambda r: r.get("planner")),
            "budget": budget, "scoring": seen(lambda r: r.get("scoring")),
            "contract_digest": (contract or {}).get("digest"),
            "cab_version": seen(lambda r: (r.get("versions") or {}).get("cab"))}))


def _args(arguments: Any) -> dict[str, Any] | None:
    if arguments is None:
        return None
    if not isinstance(arguments, dict):
        return {"arguments": json.dumps(arguments, sort_keys=True, default=str)}
    return {k: v if isinstance(v, str) else json.dumps(v, sort_keys=True, default=str) for k, v in arguments.items()}


def messages(a: Mapping[str, Any]) -> tuple[list[Message], list[AnswerAttributionItem], int]:
    """The attempt as the schema's agentic transcript: the instruction (``user``), then per turn the
    agent's message with its tool calls (``assistant``) and each call's result (``tool``); the
    ``done`` call's claim as the terminal answer. Returns the messages, the attribution and the
    number of tool calls."""
    out = [Message(turn_idx=0, role="user", content=a["result"].get("instruction"))]
    attribution: list[AnswerAttributionItem] = []
    n_calls = 0
    for turn in transcript(a["events"]):
        calls = turn.get("calls") or []
        here = len(out)
        out.append(Message(turn_idx=here, role="assistant", content=turn.get("text") or None,
                           tool_calls=[ToolCall(id=c["call_id"], name=c["name"], arguments=_args(c.get("arguments")))
                                       for c in calls] or None))
        n_calls += len(calls)
        for c in calls:
            if c.get("made"):
                body = {k: c.get(k) for k in ("status", "result", "obs_ids") if c.get(k) not in (None, [])}
                text = json.dumps(body, sort_keys=True, default=str)
                text = text if len(text) <= RESULT_TEXT_LIMIT else text[:RESULT_TEXT_LIMIT] + " ...(cut)"
            else:
                text = "cancelled: an earlier action of the same turn aborted"
            out.append(Message(turn_idx=len(out), role="tool", content=text, tool_call_id=[c["call_id"]]))
            if c["name"] == "done" and c.get("made"):
                args = c.get("arguments") or {}
                attribution.append(AnswerAttributionItem(
                    turn_idx=here, source=f"messages[{here}].tool_calls",
                    extracted_value=json.dumps({"success_claim": args.get("success_claim"),
                                                "report": args.get("report")}, sort_keys=True),
                    extraction_method="the done tool call's success_claim and report", is_terminal=True))
    return out, attribution, n_calls


def instance(a: Mapping[str, Any], evaluation_id: str, model_id: str) -> InstanceLevelEvaluationLog:
    """One attempt (``{"rel", "result", "events"}``) as an instance-level record of the
    configuration's attempt-success result."""
    r = a["result"]
    verdict, budget, timing = r.get("verdict") or {}, r.get("budget") or {}, r.get("timing") or {}
    msgs, attribution, n_calls = messages(a)
    usage = next((e for e in a["events"] if e.get("kind") == "model_usage_total"), None)
    tokens = None
    if usage and isinstance(usage.get("input_tokens"), int) and isinstance(usage.get("output_tokens"), int):
        tokens = TokenUsage(input_tokens=usage["input_tokens"], output_tokens=usage["output_tokens"],
                            total_tokens=usage["input_tokens"] + usage["output_tokens"])
    wall = timing.get("wall_seconds")
    success = verdict.get("success") is True
    instruction = r.get("instruction") or ""
    term = r.get("termination") or {}
    return InstanceLevelEvaluationLog(
        schema_version=get_schema_version(), evaluation_id=evaluation_id, model_id=model_id,
        evaluation_name=SUCCESS_ID, evaluation_result_id=SUCCESS_ID,
        sample_id=f"{r.get('task')}/seed-{r.get('seed')}/attempt-{r.get('attempt')}",
        sample_hash=hashlib.sha256(instruction.encode()).hexdigest(),
        interaction_type=InteractionType.agentic,
        input=Input(raw=instruction, reference=[]),
        messages=msgs, answer_attribution=attribution,
        evaluation=Evaluation(score=1.0 if success else 0.0, is_correct=success,
                              num_turns=sum(m.role == "assistant" for m in msgs) or None, tool_calls_count=n_calls),
        token_usage=tokens,
        performance=Performance(latency_ms=wall * 1000 if isinstance(wall, (int, float)) and wall >= 0 else None,
                                additional_details={"sim_seconds": budget.get("sim_seconds_used"),
                                                    "physics_steps": budget.get("physics_steps")}),
        metadata={"attempt_key": a["rel"], "task": r.get("task"), "seed": r.get("seed"), "attempt": r.get("attempt"),
                  "termination": term.get("reason"), "termination_detail": term.get("detail"),
                  "success_claim": (r.get("claim") or {}).get("success_claim"),
                  "charged_calls": budget.get("tool_calls_used"),
                  "deciding_margin": verdict.get("margin"),
                  "contract_digest": (r.get("contract") or {}).get("digest")})


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path


def run_records(config: Mapping[str, Any], retrieved: str, sweep_id: str) -> tuple[EvaluationLog, str, str]:
    """A configuration's aggregate record, its instance records (JSON Lines text) and the aggregate's
    repository path (``data/...``). ``config``: one of the sweep data's ``configs``."""
    attempts = config["records"]
    first = attempts[0]["result"]
    agent = first.get("agent") if isinstance(first.get("agent"), dict) else {}
    info = model_identity(str(first.get("model")), _model_cfg(attempts[0]), (agent or {}).get("serving"))
    file_id = _uuid4(sweep_id, config["config"], "evaluation_run")
    repo_path = datastore_repo_file_path(COLLECTION, info.id, info.developer, f"{file_id}.json")
    evaluation_id = f"{COLLECTION}/{info.id}/{retrieved}"
    per_task = config["per_task"]
    tasks = sorted(per_task)
    seeds = sorted({a["result"].get("seed") for a in attempts if isinstance(a["result"].get("seed"), int)})
    gen = _generation(attempts, config.get("contract"))
    results = [
        EvaluationResult(
            evaluation_result_id=SUCCESS_ID, evaluation_name=SUCCESS_ID,
            source_data=_source_data(tasks, seeds),
            metric_config=_proportion("attempts the hidden verifier scored a success, over all finished attempts; "
                                      "interval: Wilson 95 %", f"{COLLECTION}.{SUCCESS_ID}", "Attempt success"),
            score_details=_rate(config["successes"], config["attempts"], config["wilson95"]), generation_config=gen),
        EvaluationResult(
            evaluation_result_id=COVERAGE_ID, evaluation_name=COVERAGE_ID,
            source_data=_source_data(tasks, seeds),
            metric_config=_proportion("tasks with at least one successful attempt, over the tasks attempted",
                                      f"{COLLECTION}.{COVERAGE_ID}", "Task coverage"),
            score_details=ScoreDetails(
                score=config["coverage"] / config["tasks"],
                details=_strings({"tasks_covered": str(config["coverage"]), "tasks": str(config["tasks"]),
                                  "tasks_by_successes": config.get("consistency")}),
                uncertainty=Uncertainty(num_samples=config["tasks"])),
            generation_config=gen),
    ]
    for task in tasks:
        t = per_task[task]
        results.append(EvaluationResult(
            evaluation_result_id=f"{SUCCESS_ID}/{task}", evaluation_name=f"{SUCCESS_ID}/{task}",
            source_data=_source_data([task], seeds),
            metric_config=_proportion(f"attempts of task {task} the hidden verifier scored a success; "
                                      "interval: Wilson 95 %", f"{COLLECTION}.{SUCCESS_ID}", f"Attempt success: {task}"),
            score_details=_rate(t["successes"], t["attempts"], t["wilson95"]), generation_config=gen))
    samples = [instance(a, evaluation_id, info.id) for a in attempts]
    text = "".join(s.model_dump_json(exclude_none=True) + "\n" for s in samples)
    log = EvaluationLog(
        schema_version=get_schema_version(), evaluation_id=evaluation_id, retrieved_timestamp=retrieved,
        source_metadata=SourceMetadata(source_name="cab", source_type=SourceType.evaluation_run,
                                       source_organization_name="cab (the user who ran this sweep)",
                                       evaluator_relationship=EvaluatorRelationship.third_party,
                                       additional_details=_strings({"configuration": config["config"],
                                                                    "sweep": sweep_id})),
        eval_library=EvalLibrary(name=LIBRARY, version=str((first.get("versions") or {}).get("cab") or "unknown")),
        model_info=info, evaluation_results=results,
        detailed_evaluation_results=DetailedEvaluationResults(
            format=Format.jsonl, file_path=repo_path[:-len(".json")] + "_samples.jsonl",
            hash_algorithm=HashAlgorithm.sha256, checksum=hashlib.sha256(text.encode()).hexdigest(),
            total_rows=len(samples)))
    return log, text, repo_path


def documentation_record(figures: Mapping[str, Any], conf: Mapping[str, Any], info: ModelInfo,
                         retrieved: str) -> tuple[EvaluationLog, str] | None:
    """A paper configuration's published success and coverage (its ``counts``) as a
    ``documentation`` record (None: the paper gives neither count)."""
    counts = conf["counts"]
    title = str((figures.get("source") or {}).get("title") or "published figures")
    extra = {"reported_table": counts["table"], "name_in_paper": conf.get("name")}
    results = []
    if counts["wilson95"] is not None:
        results.append(EvaluationResult(
            evaluation_result_id=SUCCESS_ID, evaluation_name=SUCCESS_ID, source_data=_source_data([], [], extra),
            metric_config=_proportion("attempts scored a success, as the paper reports them; interval: Wilson 95 % "
                                      "computed by cab from the paper's counts", f"{COLLECTION}.{SUCCESS_ID}",
                                      "Attempt success"),
            score_details=_rate(counts["successes"], counts["attempts"], counts["wilson95"])))
    covered, tasks = counts["tasks_covered"], counts["tasks"]
    if isinstance(covered, int) and isinstance(tasks, int) and 0 <= covered <= tasks and tasks > 0:
        results.append(EvaluationResult(
            evaluation_result_id=COVERAGE_ID, evaluation_name=COVERAGE_ID, source_data=_source_data([], [], extra),
            metric_config=_proportion("tasks with at least one successful attempt, as the paper reports them",
                                      f"{COLLECTION}.{COVERAGE_ID}", "Task coverage"),
            score_details=ScoreDetails(
                score=covered / tasks,
                details=_strings({"tasks_covered": str(covered), "tasks": str(tasks),
                                  "tasks_by_successes": (conf.get("consistency") or {}).get("tasks_by_successes")}),
                uncertainty=Uncertainty(num_samples=tasks))))
    if not results:
        return None
    file_id = _uuid4(title, str(conf.get("name")), "documentation")
    repo_path = datastore_repo_file_path(COLLECTION, info.id, info.developer, f"{file_id}.json")
    log = EvaluationLog(
        schema_version=get_schema_version(), evaluation_id=f"{COLLECTION}/{info.id}/{retrieved}/paper",
        retrieved_timestamp=retrieved,
        source_metadata=SourceMetadata(source_name=title, source_type=SourceType.documentation,
                                       source_organization_name=f"the authors of {title}",
                                       evaluator_relationship=EvaluatorRelationship.third_party,
                                       additional_details=_strings(extra)),
        eval_library=EvalLibrary(name=str(conf.get("name") or "unknown"), version="unknown",
                                 additional_details={"note": "the paper's own harness, not cab"}),
        model_info=info, evaluation_results=results)
    return log, repo_path


def export_sweep(sweep: Mapping[str, Any], out: Path, now: float | None = None) -> list[Path]:
    """Every configuration of ``sweep`` (cab's sweep data) as an aggregate record and its instance
    records, and each configuration of its published figures as a documentation record, below
    ``out/data/``. Returns the paths written."""
    out = Path(out)
    retrieved = str(time.time() if now is None else now)
    written: list[Path] = []
    identities: dict[str, ModelInfo] = {}  # a paper configuration's name -> cab's identity of its run
    for c in sweep["configs"]:
        if not c["records"]:
            continue
        log, text, repo_path = run_records(c, retrieved, sweep["id"])
        written.append(_write(out / repo_path, log.model_dump_json(exclude_none=True, indent=2) + "\n"))
        written.append(_write(out / (repo_path[:-len(".json")] + "_samples.jsonl"), text))
        if c.get("paper"):
            identities[str(c["paper"].get("name"))] = log.model_info
    figures = sweep.get("figures") or {}
    for conf in figures.get("configurations") or []:
        info = identities.get(str(conf.get("name"))) or paper_identity(conf)
        made = documentation_record(figures, conf, info, retrieved) if info is not None else None
        if made is not None:
            log, repo_path = made
            written.append(_write(out / repo_path, log.model_dump_json(exclude_none=True, indent=2) + "\n"))
    return written
