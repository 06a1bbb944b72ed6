"""Reading attempt records back: find every attempt below a directory, load and check its files.

Analysis (report, viewer, replay, regrade) reads only these records, never a simulator. A sweep may
be partial (attempts still running, or killed: ``events.jsonl`` without ``result.json``) or hold
corrupt files; :func:`scan` sorts directories into finished attempts, in-flight ones and problems,
and never raises for a bad record. ``result.json`` is validated through its model
(:class:`cab_core.attempt.records.result_format.AttemptRecord`); analysis reads it as the typed record or, where
that is simpler, as the dict it was parsed from.
"""
from __future__ import annotations

import json
import os
from dataclasses import InitVar, dataclass, field
from functools import cached_property
from pathlib import Path

from cab_core.analysis.configurations import base_label, configuration_labels
from cab_core.attempt.records.result_format import AttemptRecord, parse_record
from cab_core.errors import RecordError
from cab_core.kits.harness.agent_info import AgentRecord
from cab_core.kits.jsonfiles import read_json_object, read_jsonl  # noqa: F401  (read_jsonl: read here by the analyses)
from cab_core.sweep.attempt_state import SET_ASIDE

read_json = read_json_object  # one JSON object from a file; a missing or unparsable file is a RecordError


def read_record(path: Path) -> AttemptRecord:
    """The record in ``path`` (a ``result.json``); RecordError when it is missing, not JSON or
    malformed."""
    return parse_record(read_json_object(path), Path(path).name)

#: where ``cab-report --recoverability`` keeps the forks it makes (cab_core.analysis.recoverability):
#: a folder of that name is not part of the sweep it sits in (the forks are no attempts of the sweep)
FORKS_FOLDER = "recoverability"


class InfrastructureResult(RecordError):
    """The result of an attempt whose every try failed for reasons that are not the model's."""


def check_result(result: dict) -> AttemptRecord:
    """The typed record of a parsed ``result.json``: RecordError (:class:`MalformedRecord
    <cab_core.attempt.records.result_format.MalformedRecord>`) naming what does not match the record's model,
    InfrastructureResult for an attempt excluded as an infrastructure failure."""
    record = parse_record(result)
    if record.excluded:
        detail = record.termination.detail or ""
        raise InfrastructureResult(f"excluded ({record.verdict.excluded or 'infrastructure_failure'}): {detail}"
                                   .rstrip(": "))
    return record


@dataclass
class Attempt:
    """One finished attempt's records. ``rel``: its directory relative to the scanned root;
    ``result``: ``result.json`` as parsed, ``record``: the same, typed (validated on load)."""
    dir: Path
    rel: str
    result: dict
    checked: InitVar[AttemptRecord | None] = None  # ``result`` already validated, when the caller has it
    record: AttemptRecord = field(init=False)
    #: the configuration's name among the attempts read with it (:func:`label_configurations`); ''
    #: for an attempt read alone: its :func:`~cab_core.analysis.configurations.base_label`
    label: str = field(default="", init=False)

    def __post_init__(self, checked: AttemptRecord | None) -> None:
        self.record = checked if checked is not None else check_result(self.result)

    @classmethod
    def load(cls, d: Path, root: Path | None = None) -> Attempt:
        d = Path(d)
        result = read_json(d / "result.json")
        record = check_result(result)
        rel = os.path.relpath(d, root) if root is not None else d.name
        return cls(d, rel.replace(os.sep, "/"), result, record)

    @cached_property
    def events(self) -> list[dict]:
        return read_jsonl(self.dir / "events.jsonl")

    @cached_property
    def snapshots(self) -> list[dict]:
        return read_jsonl(self.dir / "privileged" / "snapshots.jsonl")

    @property
    def config(self) -> str:
        """The configuration this attempt belongs to, as in the paper: model, harness, simulator,
        and the model settings that differ among the attempts read with it
        (:mod:`cab_core.analysis.configurations`: ``my_model[model_id=modelA] (my_harness, my_sim)``).
        An attempt served over MCP has the name given when it was served, else ``mcp:<client>``
        (records written before clients were recorded: ``mcp_client``)."""
        r = self.result
        return self.label or base_label(r["model"], r["harness"], r["sim"])

    @cached_property
    def resolved(self) -> dict:
        """The resolved configuration the attempt ran with (its ``attempt_start`` event's ``config``,
        the first event of its log), ``{}`` for records without it. Read without loading the log."""
        try:
            with open(self.dir / "events.jsonl", encoding="utf-8") as f:
                for line in f:
                    event = json.loads(line)
                    if isinstance(event, dict) and event.get("kind") == "attempt_start":
                        config = event.get("config")
                        return config if isinstance(config, dict) else {}
        except (OSError, ValueError):
            pass
        return {}

    @property
    def agent(self) -> AgentRecord | None:
        """Who played, when the harness recorded it (``result.json`` ``agent``; MCP clients)."""
        return AgentRecord.of_result(self.result)

    @property
    def success(self) -> bool:
        return bool(self.record.verdict.success)

    def start_event(self) -> dict:
        return next((e for e in self.events if e.get("kind") == "attempt_start"), {})


def label_configurations(attempts: list[Attempt]) -> None:
    """Name each attempt's configuration among ``attempts`` (:attr:`Attempt.config`): the model
    settings that differ among attempts of one model, harness and simulator name them apart."""
    configs = [{"model": a.result["model"], "harness": a.result["harness"], "sim": a.result["sim"],
                "task": a.result["task"], "model_cfg": a.resolved.get("model_cfg")} for a in attempts]
    for a, label in zip(attempts, configuration_labels(configs)):
        a.label = label


@dataclass
class Scan:
    """What a directory tree holds: finished attempts, unfinished ones and unreadable ones."""
    root: Path
    attempts: list[Attempt] = field(default_factory=list)
    in_flight: list[str] = field(default_factory=list)  # events.jsonl but no result.json yet
    problems: list[tuple[str, str]] = field(default_factory=list)  # (relative dir, what is wrong)
    excluded: list[tuple[str, str]] = field(default_factory=list)  # infrastructure failures: no verdict


def attempt_dirs(root: Path):
    """``(directory, path relative to root, whether it holds result.json)`` for every attempt
    directory below ``root`` (``root`` itself included), in sorted order: a directory holding
    ``result.json`` or ``events.jsonl``, not searched further (a replay kept inside it is not a sweep
    attempt); hidden directories (``.hydra``), the records a sweep set aside and the forks of
    ``cab-report --recoverability`` (a folder ``recoverability``) are skipped."""
    for d, dirs, files in os.walk(root):
        dirs[:] = sorted(x for x in dirs if not x.startswith(".") and x not in (SET_ASIDE, FORKS_FOLDER))
        if "result.json" in files or "events.jsonl" in files:
            dirs[:] = []
            yield Path(d), os.path.relpath(d, root).replace(os.sep, "/"), "result.json" in files


def scan(root: Path) -> Scan:
    """Every attempt directory below ``root`` (``root`` itself included), in sorted order. An
    attempt directory is not searched further (a replay kept inside it is not a sweep attempt);
    hidden directories (``.hydra``), the records a sweep set aside (interrupted tries) and the
    forks of ``cab-report --recoverability`` are skipped. An attempt the sweep gave up on for infrastructure failures (no verdict) is listed
    apart: it is no failure of the model."""
    root = Path(root)
    if not root.is_dir():
        raise RecordError(f"{root} is not a directory")
    out = Scan(root)
    for here, rel, finished in attempt_dirs(root):
        if not finished:
            out.in_flight.append(rel)
            continue
        try:
            out.attempts.append(Attempt.load(here, root))
        except InfrastructureResult as e:
            out.excluded.append((rel, str(e)))
        except RecordError as e:
            out.problems.append((rel, str(e)))
    label_configurations(out.attempts)
    return out
