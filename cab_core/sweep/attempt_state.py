"""The state of one attempt directory inside a sweep, as resume and the supervisor see it.

An attempt directory is *complete* when its ``result.json`` validates: the record schema
(:class:`cab_core.attempt.records.result_format.AttemptRecord`), the identity of the attempt it should hold, and the
completeness of the records it points to (the event log ends with ``attempt_end``, the observations
and the video it counts exist), and it is not an infrastructure failure. Anything else that holds
records is *partial*: a worker killed mid-attempt, or a try that failed for reasons that are not the
model's. Partial records are never deleted: they are moved aside into ``set_aside/NN-<why>/`` inside
the same attempt directory.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from cab_core.attempt.records.result_format import (
    INFRA_REASON,
    INFRASTRUCTURE_TERMINATIONS,
    RECORD_VERSION,
    UNSCORED_TERMINATIONS,
    AttemptRecord,
    Infrastructure,
    MalformedRecord,
    parse_record,
    write_record,
)

SET_ASIDE = "set_aside"
# Why a resumed sweep sets an attempt's records aside: a half-written attempt (the sweep stopped
# during that try), or an attempt every try of which failed (its tries have folders of their own).
INTERRUPTED, GIVEN_UP = "interrupted", "infrastructure"
INFRA_LOG = "infrastructure.jsonl"
# Terminations that are failures of the infrastructure, not of the model (the fault rule).
INFRA_TERMINATIONS = INFRASTRUCTURE_TERMINATIONS
_IDENTITY = ("task", "seed", "attempt", "sim", "model")


@dataclass
class RecordCheck:
    """What an attempt directory holds: ``absent``, ``complete`` or ``partial`` (with the reasons)."""
    state: str
    problems: list[str] = field(default_factory=list)
    result: dict | None = None
    record: AttemptRecord | None = None  # the result, typed (when it validates)


def is_infrastructure_failure(result: dict) -> bool:
    """True for a result that must not count for or against the model (reports exclude it). For a
    raw dict, unvalidated (:attr:`AttemptRecord.excluded` is the same rule on a validated record)."""
    infra = result.get("infrastructure") or {}
    reason = (result.get("termination") or {}).get("reason")
    return bool(infra.get("failed")) or bool((result.get("verdict") or {}).get("excluded")) \
        or reason == INFRA_REASON or reason in UNSCORED_TERMINATIONS


def _kept_names(job_log: str | None) -> set[str]:
    """Entries of an attempt directory that are not the attempt's records (Hydra's and ours)."""
    return {".hydra", SET_ASIDE, INFRA_LOG} | ({job_log} if job_log else set())


def record_entries(attempt_dir: Path, job_log: str | None = None) -> list[Path]:
    """The attempt's own records in ``attempt_dir`` (everything Hydra and the sweep did not put there)."""
    if not attempt_dir.is_dir():
        return []
    keep = _kept_names(job_log)
    return sorted(p for p in attempt_dir.iterdir() if p.name not in keep)


def _last_event_kind(events: Path) -> str | None:
    """Kind of the last complete line of an append-only event log (None when there is none)."""
    with open(events, "rb") as f:
        f.seek(0, os.SEEK_END)
        size = f.tell()
        f.seek(max(0, size - 65536))
        lines = f.read().splitlines()
    for line in reversed(lines):
        try:
            return json.loads(line).get("kind")
        except (json.JSONDecodeError, AttributeError):
            return None
    return None


def _named_by_client(rec: AttemptRecord) -> bool:
    """An attempt whose configuration left the model unnamed and whose harness named it after the
    agent that played it (``agent.named_by == "client"``, e.g. ``mcp:<client>``): its ``model``
    differs from the planned one by design, so it is not another attempt's record."""
    return rec.agent is not None and rec.agent.named_by == "client"


def _problems(d: Path, res: object, expect: dict) -> tuple[list[str], AttemptRecord | None]:
    try:
        rec = parse_record(res)
    except MalformedRecord as e:
        return e.problems, None
    out = [f"{k} is {getattr(rec, k)!r}, expected {v!r}" for k, v in expect.items()
           if getattr(rec, k) != v and not (k == "model" and _named_by_client(rec))]
    if out:
        return out, rec
    if rec.excluded:
        return [f"infrastructure failure: {rec.termination.detail}"], rec
    events = d / "events.jsonl"
    if not events.is_file():
        out.append("events.jsonl is missing")
    elif _last_event_kind(events) != "attempt_end":
        out.append("events.jsonl does not end with attempt_end")
    n_obs = int((rec.counts.observations if rec.counts else None) or 0)
    have = len(list((d / "observations").glob("*.png"))) if (d / "observations").is_dir() else 0
    if have < n_obs:
        out.append(f"{n_obs} observations recorded, {have} image files present")
    video = rec.video
    if video and not ((d / video.file).is_file() and (d / video.file).stat().st_size > 0):
        out.append(f"video {video.file} is missing or empty")
    return out, rec


def check_attempt(attempt_dir: Path, expect: dict | None = None, job_log: str | None = None) -> RecordCheck:
    """Classify ``attempt_dir``; ``expect`` holds identity fields (task, seed, attempt, sim, model)
    the result must carry."""
    d = Path(attempt_dir)
    if not record_entries(d, job_log):
        return RecordCheck("absent")
    rp = d / "result.json"
    if not rp.is_file():
        return RecordCheck("partial", ["no result.json (interrupted)"])
    try:
        res = json.loads(rp.read_text())
    except (OSError, json.JSONDecodeError) as e:
        return RecordCheck("partial", [f"result.json unreadable: {e}"])
    probs, rec = _problems(d, res, {k: v for k, v in (expect or {}).items() if k in _IDENTITY})
    return RecordCheck("partial" if probs else "complete", probs, res if isinstance(res, dict) else None, rec)


def set_aside(attempt_dir: Path, why: str, job_log: str | None = None) -> str | None:
    """Move the attempt's records into ``set_aside/NN-<why>/`` (kept, never deleted); returns the
    folder's name relative to ``attempt_dir``, or None when there was nothing to move."""
    d = Path(attempt_dir)
    entries = record_entries(d, job_log)
    if not entries:
        return None
    base = d / SET_ASIDE
    base.mkdir(exist_ok=True)
    n = 1 + sum(1 for p in base.iterdir() if p.is_dir())
    dest = base / f"{n:02d}-{why}"
    dest.mkdir()
    for p in entries:
        os.replace(p, dest / p.name)
    return f"{SET_ASIDE}/{dest.name}"


def log_infrastructure_failure(attempt_dir: Path, entry: dict) -> None:
    """Append one failure to the attempt's ``infrastructure.jsonl`` (append-only, survives resumes).
    A line that a full disk tore earlier is ended first, so that this one stays whole. Raises
    OSError when it cannot be written (the supervisor says so; the set-aside folder still tells)."""
    p = Path(attempt_dir) / INFRA_LOG
    line = json.dumps(entry) + "\n"
    with open(p, "ab") as f:
        if f.tell() and not _ends_with_newline(p):
            line = "\n" + line
        f.write(line.encode())


def _ends_with_newline(p: Path) -> bool:
    with open(p, "rb") as f:
        f.seek(-1, os.SEEK_END)
        return f.read(1) == b"\n"


def _aside_number(name: str) -> int:
    head = name.split("-", 1)[0]
    return int(head) if head.isdigit() else 0


def _derived_failures(attempt_dir: Path, listed: set) -> list[dict]:
    """A failure for each try set aside as an infrastructure failure whose entry is missing from
    ``infrastructure.jsonl`` (a full disk kept it out): its kind is in the folder's name, its time
    is the folder's. Folders set aside on resume (``NN-interrupted``: the sweep stopped during that
    try; ``NN-infrastructure``: the result of an attempt given up on) are not failures."""
    base = Path(attempt_dir) / SET_ASIDE
    if not base.is_dir():
        return []
    out = []
    for p in sorted((q for q in base.iterdir() if q.is_dir()), key=lambda q: (_aside_number(q.name), q.name)):
        rel = f"{SET_ASIDE}/{p.name}"
        kind = p.name.split("-", 1)[1] if "-" in p.name else p.name
        if rel in listed or kind in (INTERRUPTED, GIVEN_UP):
            continue
        out.append({"kind": kind, "detail": f"its entry in {INFRA_LOG} could not be written (known from its "
                                            "set-aside records)", "at": p.stat().st_mtime, "records": rel})
    return out


def infrastructure_failures(attempt_dir: Path, unlogged: list[dict] | tuple = ()) -> list[dict]:
    """Every infrastructure failure of this attempt, oldest first: the entries of
    ``infrastructure.jsonl`` (a line a full disk tore is skipped), those of ``unlogged`` (this
    session's failures that could not be written there) not among them, and one for each try set
    aside as an infrastructure failure that neither lists (see :func:`_derived_failures`)."""
    p = Path(attempt_dir) / INFRA_LOG
    out = []
    if p.is_file():
        for line in p.read_text(errors="replace").splitlines():
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(entry, dict):
                out.append(entry)
    out += [e for e in unlogged if e not in out]
    out += _derived_failures(attempt_dir, {e.get("records") for e in out})
    return sorted(out, key=_logged_at)


def _logged_at(entry: dict) -> float:
    """When a failure entry was logged (``at``), for sorting; an entry without a time sorts last."""
    at = entry.get("at")
    return at if isinstance(at, (int, float)) else float("inf")


def unlisted_set_aside(attempt_dir: Path, result: dict) -> bool:
    """Whether ``result`` (a complete attempt's) leaves out a try that was set aside as an
    infrastructure failure (its note could not be written when that try ended)."""
    listed = {f.get("records") for f in ((result.get("infrastructure") or {}).get("failures") or [])
              if isinstance(f, dict)}
    return any(f.get("records") not in listed for f in infrastructure_failures(attempt_dir))


def infrastructure_record(identity: dict, failures: list[dict]) -> AttemptRecord:
    """The record of an attempt whose every try failed for reasons that are not the model's: no
    verdict, marked so that reports exclude it and a resumed sweep runs it again."""
    last = failures[-1] if failures else {}
    return AttemptRecord.build(
        record_version=RECORD_VERSION, **identity,
        verdict={"success": None, "excluded": INFRA_REASON},
        termination={"reason": INFRA_REASON,
                     "detail": f"{len(failures)} tries failed; last: {last.get('kind')}: {last.get('detail')}"},
        claim={"success_claim": None, "report": None},
        budget={}, timing={}, versions={},
        infrastructure={"failed": True, "failures": failures})


def write_infrastructure_result(attempt_dir: Path, identity: dict, failures: list[dict]) -> dict:
    """Write :func:`infrastructure_record` as the attempt's ``result.json``; returns what was written."""
    return write_record(Path(attempt_dir) / "result.json", infrastructure_record(identity, failures))


def annotate_result(attempt_dir: Path, failures: list[dict]) -> dict:
    """Add the infrastructure failures that preceded a good try to its ``result.json`` (atomically)."""
    rp = Path(attempt_dir) / "result.json"
    record = parse_record(json.loads(rp.read_text()))
    record.infrastructure = Infrastructure.model_validate({"failed": False, "failures": failures})
    return write_record(rp, record)
