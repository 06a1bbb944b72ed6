"""The attempt record's format: ``result.json`` as a versioned pydantic model
(:class:`AttemptRecord`), how it is read back (:func:`parse_record`: a :class:`MalformedRecord`
naming what is wrong; :func:`cab_core.analysis.attempts.read_record` reads a file), and how a record file is written (JSON that takes
numpy values; written atomically, so a reader never sees half a file).

The model is the one definition of ``result.json``: the episode writes it
(:meth:`AttemptRecord.build`), the sweep writes an infrastructure result and annotates a good one
with it, and analysis, the sweep's record checks and replay read through it.

Version. Every record carries ``record_version``. The typed model writes what the dict-built
records before it wrote, key for key and value for value, so it is still ``cab-record/1``: a
change of the written content (a key removed, renamed or retyped) is what takes a new version,
and then :data:`READABLE_VERSIONS` names every version this cab still reads.

Keys and nulls. A record keeps the keys it was written with: a key absent from the file is absent
when the record is dumped again, a ``null`` stays ``null`` (:meth:`AttemptRecord.dump` dumps the keys
that were set). The writer passes every key; those the format leaves out when there is nothing to
say (``agent``, ``perturbation``, ``video.render_seconds``) are dropped when None. Keys were added
to ``cab-record/1`` over time (``counts.tool_errors``, ``sandbox.layers``, ``verdict.margins``,
``checkpoints``...), so all but the identity and the blocks every record has are optional.
Unknown keys are kept, not refused (a reader tolerates what a later writer of the same version
adds); the types of the known ones are checked strictly: a JSON boolean is not an integer, a string
is not a number, and a number keeps the kind it was written with (``60`` stays ``60``).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainValidator,
    ValidationError,
    field_validator,
    model_serializer,
    model_validator,
)
from pydantic_core import PydanticCustomError

from cab_core.errors import RecordError
from cab_core.sandbox.truncate import NON_FINITE_KEY, finite_json, non_finite_note

RECORD_VERSION = "cab-record/1"  # what this cab writes
READABLE_VERSIONS = (RECORD_VERSION,)  # what it reads
RESULT_FILE = "result.json"
INFRA_REASON = "infrastructure_failure"  # the termination (and verdict exclusion) of an infrastructure result

# Termination reasons that are not the agent's: the attempt is retried by a sweep and excluded from
# every measure. ``error`` is the reason that records written before this rule gave a host fault of
# any kind (agent-caused or not); it is still read as infrastructure, since such a record cannot
# tell which it was. Nothing writes it any more.
INFRASTRUCTURE_TERMINATIONS = {
    "provider_failure": "provider outage",
    "host_fault": "host fault",
    "error": "host fault (older record)",
}

# Terminations that are never scored: the infrastructure failures above, and an attempt the person
# running it stopped (Ctrl-C, SIGTERM). A sweep retries the infrastructure ones only; a report, the
# export and the studio exclude all of them and list them with the reason. The record of such an
# attempt says so in ``verdict.excluded`` (:meth:`AttemptRecord.build`).
INTERRUPTED = "interrupted"
UNSCORED_TERMINATIONS = {**INFRASTRUCTURE_TERMINATIONS, INTERRUPTED: "interrupted by the user"}


# -- writing JSON ---------------------------------------------------------------------------------
def _json_default(o: Any):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def dumps(obj: Any, **kw) -> str:
    """Strict JSON (what ``jq`` and ``JSON.parse`` read): a NaN or infinity is written as null, and an
    object gets ``non_finite_as_null`` listing where that happened."""
    try:
        return json.dumps(obj, default=_json_default, allow_nan=False, **kw)
    except ValueError:  # a non-finite number somewhere (or a circular structure, which stays an error)
        found: list[str] = []
        clean = finite_json(obj, "", found)
        if found and isinstance(clean, dict):
            clean[NON_FINITE_KEY] = non_finite_note(found, clean.get(NON_FINITE_KEY))
        return json.dumps(clean, default=_json_default, allow_nan=False, **kw)


def write_json_atomic(path: Path, obj: Any) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    text = dumps(obj, indent=2, sort_keys=False)
    try:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # a full disk, a signal: the old file stays whole, no half-written copy is left
        tmp.unlink(missing_ok=True)
        raise


# -- the model ------------------------------------------------------------------------------------
def _number(v: Any) -> int | float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise PydanticCustomError("number_type", "Input should be a number")
    return v


#: a JSON number, kept as written (an integer stays an integer, a float a float)
Num = Annotated[int | float, PlainValidator(_number)]


class Block(BaseModel):
    """A block of the record: strict types, unknown keys kept, the keys of ``omit_if_none`` left out
    of the dump when None."""
    model_config = ConfigDict(strict=True, extra="allow")
    omit_if_none: ClassVar[tuple[str, ...]] = ()

    @model_serializer(mode="wrap")
    def _leave_out_nones(self, handler):
        out = handler(self)
        for k in self.omit_if_none:
            if k in out and out[k] is None:
                del out[k]
        return out


class Termination(Block):
    """Why the attempt ended: ``reason`` (``done``, ``tool_budget``, ``no_done``, ``provider_failure``,
    ``interrupted``, ``infrastructure_failure``...) and a sentence. The reasons of
    :data:`UNSCORED_TERMINATIONS` are never scored."""
    reason: str
    detail: str | None = None


class Claim(Block):
    """What the agent said when it called ``done`` (both null when it never did)."""
    success_claim: bool | None = None
    report: str | None = None


class Margin(Block):
    """How far one predicate's measured quantity is inside (``slack > 0``) or outside its threshold
    (:class:`cab_core.contracts.verifier.Margin`). Null where the measurement was not a number
    (strict JSON holds no NaN: :func:`dumps`)."""
    slack: Num | None
    scale: Num | None
    fraction: Num | None
    unit: str
    measured: Num | None = None
    threshold: Num | None = None


class DecidingMargin(Block):
    """What decided the verdict and by how much (:func:`cab_core.contracts.verifier.deciding_margin`)."""
    predicate: str | None = None
    fraction: Num | None = None
    borderline: bool | None = None
    threshold: Num | None = None


class Latch(Block):
    """A latch task's event: whether it latched, at which physics step, and whether it was armed
    (false) at the start."""
    latched: bool
    at_step: int | None = None
    armed_at_start: bool | None = None


class Verdict(Block):
    """The hidden verdict. ``success`` is true or false, null only in a record that is not scored (then
    ``excluded`` says why: ``infrastructure_failure`` for a sweep's given-up attempt, else the
    termination reason, e.g. ``provider_failure`` or ``interrupted``); ``error`` when scoring itself
    failed (``success`` false)."""
    success: bool | None
    scoring: str | None = None
    final_state_success: bool | None = None
    predicates: dict[str, bool] | None = None
    values: dict[str, Num | None] | None = None  # null: not a number (strict JSON)
    final_requirements: dict[str, bool] | None = None
    guard: dict[str, bool] | None = None
    latch: Latch | None = None  # null for final-state tasks
    baseline_success: bool | None = None
    margins: dict[str, Margin] | None = None
    margins_at: Literal["latch", "final"] | None = None
    margins_at_step: int | None = None
    margin: DecidingMargin | None = None
    error: str | None = None
    excluded: str | None = None


class Budget(Block):
    """The budgets, used and limits (:meth:`cab_core.attempt.budget.BudgetLedger.summary`); empty in an
    infrastructure result."""
    tool_calls_used: int | None = None
    tool_calls_limit: int | None = None
    sim_seconds_used: Num | None = None
    sim_seconds_limit: Num | None = None
    physics_steps: int | None = None
    sim_dt: Num | None = None
    wall_seconds_used: Num | None = None
    wall_seconds_limit: Num | None = None
    wall_seconds_credited: Num | None = None
    run_code_internal_calls_limit: int | None = None
    omit_if_none = ("cost_usd_used", "cost_usd_limit")
    cost_usd_used: Num | None = None  # the spend counted against budget.cost_usd, where a cap was set
    cost_usd_limit: Num | None = None


class Timing(Block):
    """Wall-clock seconds of the whole attempt and of building its world; empty in an
    infrastructure result."""
    wall_seconds: Num | None = None
    setup_seconds: Num | None = None


class Counts(Block):
    """Charged calls, observations shown to the agent, tool errors (the host's faults)."""
    charged_calls: int | None = None
    observations: int | None = None
    tool_errors: int | None = None


class Sandbox(Block):
    """How ``run_code`` programs were confined: the mechanism, each OS layer, and why one is missing."""
    confinement: str | None = None
    layers: dict[str, str] | None = None
    note: str | None = None


class Versions(Block):
    """What ran the attempt (:func:`cab_core.attempt.engine.finishing.versions`); empty in an infrastructure
    result."""
    cab: str | None = None
    python: str | None = None
    platform: str | None = None
    simulator: dict[str, Any] | None = None
    planner: dict[str, Any] | None = None
    packages: dict[str, str] | None = None
    numerics: dict[str, Any] | None = None


class CheckpointHit(Block):
    """Where a checkpoint was first attained: the snapshot, its label, the charged calls and the
    physics step then (all null for a subgoal a latch event satisfied), and for a spatial one the arm."""
    omit_if_none = ("arm",)
    snapshot: int | None = None
    label: str | None = None
    calls: int | None = None
    physics_step: int | None = None
    arm: str | None = None


class Subgoal(Block):
    index: int
    text: str
    attained: bool
    first: CheckpointHit | None = None


class SpatialCheckpoint(Block):
    index: int
    name: str
    arm: str
    attained: bool
    first: CheckpointHit | None = None


class Checkpoints(Block):
    """Subgoal and spatial checkpoints (:mod:`cab_core.attempt.engine.checkpoint_scoring`), or ``error`` when they
    could not be evaluated."""
    subgoals: list[Subgoal] | None = None
    spatial: list[SpatialCheckpoint] | None = None
    subgoals_at_start: list[bool] | None = None
    subgoal_coverage: Num | None = None
    spatial_coverage: Num | None = None
    error: str | None = None


class Video(Block):
    """The head-view video: its file (relative to the attempt directory), frames, physics steps
    between frames, and whether frames were rendered in the loop or after the attempt."""
    omit_if_none = ("render_seconds",)
    file: str
    frames: int | None = None
    every_steps: int | None = None
    rendered: str | None = None
    render_seconds: Num | None = None


class ClientInfo(Block):
    """One MCP client's identity from its handshake, and the MCP session it came in."""
    name: str
    version: str
    session: int = Field(1, ge=1)


class ModelUsage(Block):
    """What a harness that pays for a model spent on the attempt: tokens, USD (null without pricing),
    seconds waited on the shared rate limits (:mod:`cab_core.kits.harness.limits`) and on retries."""
    input_tokens: int = 0
    output_tokens: int = 0
    usd: Num | None = None
    waited_on_limits_s: Num = 0.0
    waited_on_retries_s: Num = 0.0


class Agent(Block):
    """Who played (:mod:`cab_core.kits.harness.agent_info`): optional, written by harnesses that know."""
    omit_if_none = ("usage",)
    kind: str
    named_by: Literal["config", "client", "placeholder"]
    client: ClientInfo | None = None
    clients: list[ClientInfo] = Field(default_factory=list)
    usage: ModelUsage | None = None


class Perturbation(Block):
    """What ``perturb.seed`` drew (:mod:`cab_core.attempt.variation.perturb`): the settings and, per object,
    the shift, turn and parameter scales."""
    seed: int
    position_m: Num | None = None
    angle_deg: Num | None = None
    physics_fraction: Num | None = None
    objects: dict[str, dict[str, Num]] | None = None


class Randomization(Block):
    """What appearance randomisation drew (:mod:`cab_core.attempt.variation.randomize`): the option, its
    parts' parameters and, per part, the draws."""
    omit_if_none = ("lighting", "textures", "camera", "distractors")
    name: str
    parts: dict[str, dict[str, Any]] = Field(default_factory=dict)
    lighting: dict[str, Any] | None = None
    textures: dict[str, Any] | None = None
    camera: dict[str, Any] | None = None
    distractors: dict[str, Any] | None = None


class Fork(Block):
    """A fork (:mod:`cab_core.attempt.fork`): the parent (relative to this attempt's folder), the
    charged call after which it started, and how closely the re-executed prefix matched."""
    parent: str
    at: int = Field(ge=0)
    calls_made_again: int | None = None
    exact: bool | None = None
    max_tcp_error_m: Num | None = None
    max_object_error_m: Num | None = None
    lineage: list[dict[str, Any]] = Field(default_factory=list)
    #: ``{"parent": ..., "fork": ...}`` where ``fork.planner=own`` made the prefix again with another planner
    planner: dict[str, str] | None = None


class InfrastructureFailure(Block):
    """One try that failed for reasons that are not the model's (:mod:`cab_core.sweep.supervisor`)."""
    kind: str
    detail: str | None = None
    log_tail: str | None = None
    try_no: int | None = None
    wall_seconds: Num | None = None
    at: Num | None = None
    records: str | None = None


class Infrastructure(Block):
    """Written by the sweep: the tries that failed before this one (``failed`` false), or every try
    failed and the record holds no verdict (``failed`` true)."""
    failed: bool
    failures: list[InfrastructureFailure] = Field(default_factory=list)


class Contract(Block):
    """The comparison contract (:mod:`cab_core.analysis.contract`): the digest over the parts, and
    each part's digest by name (``tools``, ``task``, ``seeds``, ``budget``, ``embodiment``,
    ``planner``, ``simulator``, ``variation``, ``harness``, ``sandbox``, ``serving`` where known)."""
    digest: str
    parts: dict[str, str]


class AttemptRecord(Block):
    """``result.json``: one attempt's identity, verdict, termination, claim, budgets, timings,
    counts, sandbox, versions, checkpoints, video and, where they apply, who played, what was
    perturbed and the infrastructure failures, and the comparison contract. Fields in the order they are written."""
    omit_if_none = ("agent", "perturbation", "randomization", "fork", "contract")
    record_version: str
    task: str
    seed: int
    attempt: int
    sim: str
    embodiment: str | None = None
    planner: str | None = None
    model: str
    harness: str | None = None  # every scored record has one; an infrastructure result need not
    agent: Agent | None = None
    instruction: str | None = None
    scoring: str | None = None
    perturbation: Perturbation | None = None
    randomization: Randomization | None = None
    fork: Fork | None = None
    verdict: Verdict
    termination: Termination
    claim: Claim
    budget: Budget
    timing: Timing
    counts: Counts | None = None
    sandbox: Sandbox | None = None
    versions: Versions
    checkpoints: Checkpoints | None = None
    video: Video | None = None
    infrastructure: Infrastructure | None = None
    contract: Contract | None = None  # absent in records written before cab kept one

    @field_validator("record_version")
    @classmethod
    def _readable(cls, v: str) -> str:
        if v not in READABLE_VERSIONS:
            raise PydanticCustomError("record_version", f"{v!r} is not a record version this cab reads "
                                      f"({', '.join(READABLE_VERSIONS)})")
        return v

    @model_validator(mode="after")
    def _scored(self) -> AttemptRecord:
        if not self.excluded:
            if self.harness is None:
                raise PydanticCustomError("scored", "a scored record needs 'harness'")
            if not isinstance(self.verdict.success, bool):
                raise PydanticCustomError("scored", "verdict.success should be true or false")
        return self

    @property
    def excluded(self) -> bool:
        """A record that is not scored: an infrastructure result, an attempt that ended on an
        infrastructure failure or was interrupted (:data:`UNSCORED_TERMINATIONS`; a record written
        before this rule, with a verdict, is read so too). Not the model's failure: reports exclude
        it, a resumed sweep runs it again."""
        return bool(self.verdict.excluded) or bool(self.infrastructure and self.infrastructure.failed) \
            or self.termination.reason == INFRA_REASON or self.termination.reason in UNSCORED_TERMINATIONS

    @property
    def excluded_reason(self) -> str | None:
        """Why the record is not scored (a termination reason or ``infrastructure_failure``), None when it is."""
        if not self.excluded:
            return None
        return self.verdict.excluded or (INFRA_REASON if self.infrastructure and self.infrastructure.failed
                                         else self.termination.reason)

    def dump(self) -> dict:
        """The record as ``result.json`` holds it: the keys that were set, in the model's order."""
        return self.model_dump(mode="python", exclude_unset=True)

    @classmethod
    def build(cls, **fields: Any) -> AttemptRecord:
        """A record from its fields as the host has them (numpy values, paths): made JSON first, so
        the record holds what ``result.json`` will, then validated (:class:`MalformedRecord`). An
        attempt that ended on a termination that is never scored (:data:`UNSCORED_TERMINATIONS`)
        gets ``verdict.success`` null and ``verdict.excluded`` naming the reason."""
        obj = json.loads(dumps(fields))
        reason = (obj.get("termination") or {}).get("reason") if isinstance(obj.get("termination"), dict) else None
        verdict = obj.get("verdict")
        if reason in UNSCORED_TERMINATIONS and isinstance(verdict, dict) and not verdict.get("excluded"):
            verdict["success"] = None
            verdict["excluded"] = reason
        return parse_record(obj)


# -- reading --------------------------------------------------------------------------------------
class MalformedRecord(RecordError):
    """A record that does not match :class:`AttemptRecord`; ``problems`` lists each mismatch."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        shown = "; ".join(problems[:3])
        super().__init__(shown + (f"; and {len(problems) - 3} more" if len(problems) > 3 else ""))


_KINDS = {"string_type": "a string", "bool_type": "true or false", "int_type": "an integer",
          "float_type": "a number", "number_type": "a number", "dict_type": "an object",
          "model_type": "an object", "model_attributes_type": "an object", "list_type": "a list"}


def _where(loc: tuple) -> str:
    out = ""
    for p in loc:
        out += f"[{p}]" if isinstance(p, int) else ("." if out else "") + str(p)
    return out


def _shown(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


def problems_of(err: ValidationError, name: str = RESULT_FILE) -> list[str]:
    """Each error of a validation, as a sentence naming the key (``result.json lacks 'verdict'``,
    ``result.json agent.client.version should be a string, got 3``)."""
    out = []
    for e in err.errors(include_url=False):
        where, kind, msg = _where(e["loc"]), e["type"], e["msg"]
        if kind == "missing":
            out.append(f"{name} lacks {where!r}")
        elif kind in _KINDS:
            out.append(f"{name} {where} should be {_KINDS[kind]}, got {_shown(e['input'])}")
        elif msg.startswith("Input should be "):
            out.append(f"{name} {where} should be {msg[len('Input should be '):]}, got {_shown(e['input'])}")
        else:
            out.append(f"{name} {where}{' ' if where else ''}{msg}".replace(" :", ":"))
    return out


def parse_record(obj: Any, name: str = RESULT_FILE) -> AttemptRecord:
    """The record a parsed ``result.json`` holds; :class:`MalformedRecord` when it does not match."""
    if not isinstance(obj, dict):
        raise MalformedRecord([f"{name} does not hold a JSON object"])
    try:
        return AttemptRecord.model_validate(obj)
    except ValidationError as e:
        raise MalformedRecord(problems_of(e, name)) from None


def write_record(path: Path, record: AttemptRecord) -> dict:
    """Write ``record`` to ``path`` (atomically); returns what was written."""
    out = record.dump()
    write_json_atomic(path, out)
    return out
