"""The paper's measures, per attempt and per configuration, computed from records alone.

Definitions follow the paper (section "Results" and the appendices on consistency, cost, programs,
motion outcomes, termination, checkpoints and failure analysis):

* success rate with a Wilson 95% score interval; task coverage (tasks solved at least once) and
  consistency (tasks by number of successful attempts, k/n);
* stopping condition: done, tool (charged-call limit), phys (simulated-time limit), other;
* completion claim against the verifier: correct, over (success claimed, failed), under (failure
  claimed, succeeded), absent (no Boolean claim, including no ``done``);
* program share: charged calls submitted through ``run_code`` over all charged calls; program
  errors: returned programs that raised or were rejected (not robot-action interruptions);
* non-completed robot actions (direct and inside programs), by planner refusal, stall, trajectory
  deviation and motion allowance (leg budget, probe travel), and how many of them advanced the
  simulation (a stopped action can still change the scene);
* the MCP clients that played a configuration's attempts (name/version, from ``result.json``
  ``agent``; none for other harnesses);
* calls (mean), simulated, wall and provider-wait time (medians); cost (total, median, IQR);
  infrastructure retries (tries a sweep redid for simulator or provider faults, not counted as failures);
* pass@k and pass^k (k = 1..n, unbiased over each task's n attempts, averaged over tasks;
  :mod:`cab_core.analysis.stats`);
* subgoal and spatial checkpoint coverage: per attempt the attained fraction, averaged over a
  task's attempts, then over tasks with equal weight; the same for spatial coverage at each
  charged-call count k (matches within the first k calls count; an ended attempt keeps its value).
"""
from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from statistics import median
from typing import TYPE_CHECKING

from cab_core.analysis.stats import pass_k_curve

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.analysis.attempts import Attempt

STOPPING = ("done", "tool", "phys", "other")
CLAIMS = ("correct", "over", "under", "absent")
ACTION_CAUSES = ("planner", "stall", "deviation", "allowance", "other")
# tools whose use the paper relates to success (its table of geometric and contact tool use)
ESTIMATION_TOOLS = ("plane_intersect", "triangulate_correspondence", "scale_from_gripper",
                    "scale_from_object_size", "probe_contact_along")


def wilson(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion (95% by default); (0, 0) for n = 0."""
    if n <= 0:
        return 0.0, 0.0
    p = successes / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z / den * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def stopping(reason: str) -> str:
    return {"done": "done", "tool_budget": "tool", "sim_budget": "phys"}.get(reason, "other")


def claim_category(claim: bool | None, success: bool) -> str:
    if claim is None:
        return "absent"
    if claim == success:
        return "correct"
    return "over" if claim else "under"


# an aborted action's abort_reason -> its cause (any other reason, or none: "other")
_ABORT_CAUSES: dict[str | None, str] = {"stalled": "stall", "trajectory_deviation": "deviation",
                                        "leg_budget": "allowance"}


def action_cause(result: dict) -> str | None:
    """Why a robot action did not complete (None when it completed or is not an action)."""
    status = result.get("status")
    if "action_id" not in result or status == "SUCCESS":
        return None
    stop = (result.get("achieved") or {}).get("stop_reason")
    if stop == "travel_budget_spent":
        return "allowance"
    if status == "FAILED":
        return "planner"
    return _ABORT_CAUSES.get(result.get("abort_reason"), "other")


def program_error(result: dict) -> bool:
    """A returned program that raised or was rejected; an action interruption (ABORTED) or the
    attempt ending inside it is not a program error."""
    if result.get("ok") or result.get("status") == "ABORTED" or result.get("ended"):
        return False
    return bool(result.get("error"))


def _provider(events: list[dict]) -> tuple[float | None, float | None]:
    """(provider wait seconds, cost USD) from the harness's usage events; None when the harness
    records none (model-free agents, or a harness that does not report them)."""
    total = next((e for e in events if e.get("kind") == "model_usage_total"), None)
    turns = [e for e in events if e.get("kind") == "model_turn"]
    if total is not None:
        return (float(total.get("latency_s", 0.0)) + float(total.get("waited_s", 0.0)),
                float(total["usd"]) if total.get("usd") is not None else None)
    if not turns:
        return None, None
    wait = sum(float(e.get("latency_s") or 0.0) + float(e.get("waited_s") or 0.0) for e in turns)
    usd = [(e.get("cost") or {}).get("usd") for e in turns]
    return wait, (sum(u for u in usd if u is not None) if any(u is not None for u in usd) else None)


#: provider failures that are the serving endpoint's, not the model's (a template error answering 500
#: to ``tools``, a request the server refused)
SERVER_ERROR_KINDS = ("server", "bad_request")


def _server_side(events: list[dict]) -> dict:
    """What the serving endpoint, not the model, got wrong in one attempt: tool calls the harness
    salvaged from the server's output (left in the text, a lost brace), calls whose arguments
    still did not parse, whether a server error ended it, and the endpoint probe's problems."""
    calls = [c for e in events if e.get("kind") == "model_turn" for c in e.get("tool_calls") or []]
    probe = next((e for e in events if e.get("kind") == "endpoint_probe"), None)
    ended = any(e.get("kind") == "provider_failure" and e.get("error_kind") in SERVER_ERROR_KINDS for e in events)
    return {"salvaged_calls": sum(bool(c.get("salvaged")) for c in calls),
            "unparseable_calls": sum(c.get("arguments") is None for c in calls),
            "ended_by_server_error": ended,
            "probe_problems": list((probe or {}).get("problems") or [])}


def _client_labels(a: Attempt) -> list[str]:
    """``name/version`` of each distinct client recorded in the attempt's ``agent`` block."""
    agent = a.agent
    return list(dict.fromkeys(c.label for c in agent.clients)) if agent is not None else []


@dataclass
class AttemptMeasures:
    """Everything the report needs from one attempt."""
    rel: str
    config: str
    task: str
    attempt: int
    success: bool
    termination: str
    stopping: str
    claim: str
    charged_calls: int
    program_calls: int
    programs_returned: int
    program_errors: int
    actions: int
    not_completed: dict
    not_completed_moved: int  # non-completed actions during which the simulation advanced
    sim_seconds: float
    wall_seconds: float | None
    wait_seconds: float | None
    cost_usd: float | None
    subgoal_coverage: float | None
    spatial_coverage: float | None
    spatial_match_calls: list  # charged-call index of each spatial checkpoint's first match (None: never)
    tools: list
    infra_retries: int = 0  # tries before this one that failed for reasons not the model's
    clients: list = field(default_factory=list)  # MCP clients that played it, "name/version", in order seen
    failure_stage: str | None = None
    failure_detail: str = ""
    margin: float | None = None  # the deciding predicate's margin, as a fraction of its tolerance
    margin_predicate: str | None = None
    borderline: bool | None = None  # None: a record written before margins were recorded
    seed: int | None = None  # the task instance's seed: attempts on the same (task, seed) are paired
    randomize: str = "none"  # the appearance randomisation option (cab_core.attempt.variation.randomize)
    server_side: dict = field(default_factory=dict)  # the serving endpoint's faults (_server_side)

    @classmethod
    def of(cls, a: Attempt) -> AttemptMeasures:
        r = a.result
        ev = a.events
        calls = [e for e in ev if e.get("kind") == "call" and e.get("charged", True)]
        programs = [e for e in calls if e.get("tool") == "run_code"]
        act_events = [e for e in ev if e.get("kind") in ("call", "internal_call") and "action_id" in (e.get("result") or {})]
        acts = [e["result"] for e in act_events]
        causes = Counter(c for c in (action_cause(x) for x in acts) if c)
        moved = sum(1 for e in act_events if action_cause(e["result"]) and (e.get("physics_steps") or 0) > 0)
        wait, usd = _provider(ev)
        ck = r.get("checkpoints")
        ck = ck if isinstance(ck, dict) else {}
        ok_ck = bool(ck) and "error" not in ck
        spatial = ck.get("spatial", []) if ok_ck else []
        success = a.success
        decided = r["verdict"].get("margin")
        decided = decided if isinstance(decided, dict) else None
        return cls(
            rel=a.rel, config=a.config, task=r["task"], attempt=r["attempt"], success=success,
            termination=r["termination"]["reason"], stopping=stopping(r["termination"]["reason"]),
            claim=claim_category(r["claim"].get("success_claim"), success),
            charged_calls=int(r["budget"].get("tool_calls_used", len(calls))), program_calls=len(programs),
            programs_returned=sum(1 for e in programs if isinstance(e.get("result"), dict)),
            program_errors=sum(1 for e in programs if program_error(e.get("result") or {})),
            actions=len(acts), not_completed={c: causes.get(c, 0) for c in ACTION_CAUSES}, not_completed_moved=moved,
            sim_seconds=float(r["budget"].get("sim_seconds_used", 0.0)),
            wall_seconds=(r.get("timing") or {}).get("wall_seconds"), wait_seconds=wait, cost_usd=usd,
            subgoal_coverage=ck.get("subgoal_coverage") if ok_ck and ck.get("subgoals") else None,
            spatial_coverage=ck.get("spatial_coverage") if ok_ck and spatial else None,
            spatial_match_calls=[(s.get("first") or {}).get("calls") if s.get("attained") else None for s in spatial],
            tools=sorted({e.get("tool") for e in ev if e.get("kind") in ("call", "internal_call")} - {None, "done"}),
            infra_retries=len((r.get("infrastructure") or {}).get("failures") or []),
            clients=_client_labels(a),
            margin=None if decided is None or decided.get("fraction") is None else float(decided["fraction"]),
            margin_predicate=None if decided is None else decided.get("predicate"),
            borderline=None if decided is None else bool(decided.get("borderline")),
            seed=r.get("seed"),
            randomize=str((r.get("randomization") or {}).get("name") or "none"),
            server_side=_server_side(ev),
        )

    def spatial_at(self, k: int) -> float | None:
        """Spatial coverage counting matches within the first ``k`` charged calls."""
        if self.spatial_coverage is None:
            return None
        n = len(self.spatial_match_calls)
        return sum(1 for c in self.spatial_match_calls if c is not None and c <= k) / n


def _task_weighted(values: dict[str, list[float]]) -> float | None:
    """Mean over tasks (equal weight) of the mean over each task's attempts."""
    per_task = [sum(v) / len(v) for v in values.values() if v]
    return sum(per_task) / len(per_task) if per_task else None


def _quantiles(xs: list[float]) -> tuple[float, float, float]:
    """(first quartile, median, third quartile), linear interpolation between order statistics."""
    s = sorted(xs)

    def q(p: float) -> float:
        pos = p * (len(s) - 1)
        lo = math.floor(pos)
        hi = min(lo + 1, len(s) - 1)
        return s[lo] + (s[hi] - s[lo]) * (pos - lo)

    return q(0.25), q(0.5), q(0.75)


@dataclass
class ConfigSummary:
    """One configuration's measures over its attempts."""
    config: str
    attempts: int
    successes: int
    success_rate: float
    wilson95: tuple
    tasks: int
    coverage: int
    consistency: dict
    stopping: dict
    claims: dict
    charged_calls: int
    program_calls: int
    program_share: float | None
    programs_returned: int
    program_errors: int
    actions: int
    not_completed: dict
    not_completed_total: int
    not_completed_moved: int
    calls_mean: float
    sim_seconds_median: float
    wall_seconds_median: float | None
    wait_seconds_median: float | None
    cost_total: float | None
    cost_median: float | None
    cost_iqr: tuple | None
    subgoal_coverage: float | None
    spatial_coverage: float | None
    spatial_curve: list
    progress: dict
    failure_stages: dict
    infra_retries: int = 0
    tool_use: dict = field(default_factory=dict)
    clients: list = field(default_factory=list)  # distinct MCP clients ("name/version") over its attempts, sorted
    #: verdicts decided by less than BORDERLINE_FRACTION of a tolerance: could flip on another machine
    borderline: dict = field(default_factory=dict)
    #: {"k": [1..n], "pass_at_k": [...], "pass_hat_k": [...]}: unbiased per task, averaged over tasks
    pass_k: dict = field(default_factory=dict)
    #: the serving endpoint's faults, counted apart from the model's: tool calls salvaged from its
    #: output, calls left unparseable, attempts a server error ended, the probe's problems
    server_side: dict = field(default_factory=dict)

    @classmethod
    def of(cls, config: str, ms: list[AttemptMeasures], max_calls: int) -> ConfigSummary:
        n = len(ms)
        succ = sum(m.success for m in ms)
        by_task: dict[str, list[AttemptMeasures]] = defaultdict(list)
        for m in ms:
            by_task[m.task].append(m)
        consistency = Counter(f"{sum(x.success for x in v)}/{len(v)}" for v in by_task.values())
        charged = sum(m.charged_calls for m in ms)
        prog = sum(m.program_calls for m in ms)
        nc = {c: sum(m.not_completed[c] for m in ms) for c in ACTION_CAUSES}
        waits = [m.wait_seconds for m in ms if m.wait_seconds is not None]
        walls = [m.wall_seconds for m in ms if m.wall_seconds is not None]
        costs = [m.cost_usd for m in ms if m.cost_usd is not None]
        q = _quantiles(costs) if costs else None
        sub = {t: [m.subgoal_coverage for m in v if m.subgoal_coverage is not None] for t, v in by_task.items()}
        spa = {t: [m.spatial_coverage for m in v if m.spatial_coverage is not None] for t, v in by_task.items()}
        curve = [_task_weighted({t: [x for x in (m.spatial_at(k) for m in v) if x is not None]
                                 for t, v in by_task.items()}) for k in range(max_calls + 1)]
        failed = [m for m in ms if not m.success]
        progress = {"success": succ,
                    "subgoal": sum(1 for m in failed if (m.subgoal_coverage or 0) > 0),
                    "spatial_only": sum(1 for m in failed if not (m.subgoal_coverage or 0) and (m.spatial_coverage or 0) > 0),
                    "none": sum(1 for m in failed if not (m.subgoal_coverage or 0) and not (m.spatial_coverage or 0))}
        tools = sorted({t for m in ms for t in m.tools})
        return cls(
            config=config, attempts=n, successes=succ, success_rate=succ / n if n else 0.0, wilson95=wilson(succ, n),
            tasks=len(by_task), coverage=sum(1 for v in by_task.values() if any(x.success for x in v)),
            consistency=dict(sorted(consistency.items())),
            stopping={s: sum(m.stopping == s for m in ms) for s in STOPPING},
            claims={c: sum(m.claim == c for m in ms) for c in CLAIMS},
            charged_calls=charged, program_calls=prog, program_share=prog / charged if charged else None,
            programs_returned=sum(m.programs_returned for m in ms), program_errors=sum(m.program_errors for m in ms),
            actions=sum(m.actions for m in ms), not_completed=nc, not_completed_total=sum(nc.values()),
            not_completed_moved=sum(m.not_completed_moved for m in ms),
            calls_mean=charged / n if n else 0.0, sim_seconds_median=median(m.sim_seconds for m in ms) if ms else 0.0,
            wall_seconds_median=median(walls) if walls else None, wait_seconds_median=median(waits) if waits else None,
            cost_total=sum(costs) if costs else None, cost_median=q[1] if q else None,
            cost_iqr=(q[0], q[2]) if q else None,
            subgoal_coverage=_task_weighted(sub), spatial_coverage=_task_weighted(spa), spatial_curve=curve,
            progress=progress,
            failure_stages=dict(Counter(m.failure_stage for m in failed if m.failure_stage)),
            infra_retries=sum(m.infra_retries for m in ms),
            tool_use={t: {"attempts": sum(t in m.tools for m in ms), "successes": sum(t in m.tools and m.success for m in ms)}
                      for t in tools},
            clients=sorted({c for m in ms for c in m.clients}),
            borderline=_borderline(ms),
            pass_k=pass_k_curve({t: (len(v), sum(x.success for x in v)) for t, v in by_task.items()}),
            server_side={"salvaged_calls": sum(m.server_side.get("salvaged_calls", 0) for m in ms),
                         "unparseable_calls": sum(m.server_side.get("unparseable_calls", 0) for m in ms),
                         "attempts_ended_by_server_error": sum(bool(m.server_side.get("ended_by_server_error"))
                                                               for m in ms),
                         "probe_problems": sorted({p for m in ms for p in m.server_side.get("probe_problems", [])})},
        )

    def as_dict(self) -> dict:
        return asdict(self)


def _borderline(ms: list[AttemptMeasures]) -> dict:
    """Borderline verdicts (successes and failures), attempts without margins on record, and the
    smallest deciding margin of a success (the one nearest to flipping)."""
    succ = [m.margin for m in ms if m.success and m.margin is not None]
    return {"successes": sum(bool(m.borderline) and m.success for m in ms),
            "failures": sum(bool(m.borderline) and not m.success for m in ms),
            "unrecorded": sum(m.borderline is None for m in ms),
            "min_success_margin": min(succ) if succ else None,
            "attempts": [m.rel for m in ms if m.borderline]}


def matrix(ms: list[AttemptMeasures]) -> dict[str, dict[str, list[int]]]:
    """task -> configuration -> [successes, attempts]."""
    out: dict[str, dict[str, list[int]]] = defaultdict(dict)
    for m in ms:
        cell = out[m.task].setdefault(m.config, [0, 0])
        cell[0] += int(m.success)
        cell[1] += 1
    return {t: dict(sorted(v.items())) for t, v in sorted(out.items())}
