"""The comparison contract: a digest of everything that makes two runs measure the same thing.

Two attempts (or two sweeps, two machines, two cab versions) can be put side by side only where
they ran the same benchmark: the same tools, task definitions, budgets, simulator, planner... The
contract names each of those things as a *part*, digests each part separately (SHA-256 of its
canonical JSON: sorted keys, no whitespace, integral floats written as integers, so the digest is
the same under every Python from 3.11 and every numpy: :mod:`cab_core.attempt.contract`), and digests the parts together::

    "contract": {"digest": "<sha256 hex>", "parts": {"budget": "<sha256 hex>", "planner": ..., ...}}

Every ``result.json`` holds its attempt's contract (:func:`cab_core.attempt.engine.contract.attempt_contract`,
from the resolved :class:`cab_core.attempt.spec.AttemptSpec`); a sweep's manifest holds one per
configuration (:mod:`cab_core.apps.sweep_contracts`; :func:`combined`: each part over the set of its
attempts' digests of that part). The parts
(:data:`PARTS`):

- ``tools``: every tool's schema and description as the agent sees them (:func:`cab_core.tools.schemas`);
- ``task``: the task's name, instruction, scoring, subgoals and spatial checkpoints, and the source of
  its class and the classes it derives from (verifier and checkpoint code);
- ``seeds``: the task instance (task and seed) and the attempt number;
- ``budget``: tool calls, simulated and wall seconds, internal calls of a program, the cost cap;
- ``embodiment``, ``planner``, ``simulator``: each option's configuration and the versions of the
  plugin distribution that provides it and of that distribution's requirements (a planner library,
  the physics engine);
- ``variation``: perturbation and appearance randomisation;
- ``harness``: the harness's configuration (its context policy among it) and its distribution's version;
- ``sandbox``: how programs are confined and limited;
- ``serving``: the serving engine and its version, where the harness learnt them (a local model
  server's probe); absent otherwise.

Not in it: the model (the configuration being compared), output folders, the machine (host name,
paths, ``CAB_NUMERICS``, CPU), launcher and sweep settings, and settings that only say how the
harness is reached (:data:`NOT_MEASURED`).

Public API (this module): :func:`of_result` (a result's contract, None for records
written before it existed), :func:`differing` (the parts two contracts differ in, by name),
:func:`combined`, :func:`report_check` (the parts a set of attempts put in one table disagree on) and
:func:`table_contracts` (what cab-report says of them, or :class:`ContractsDiffer`: its refusal).
"""
from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from typing import Any

from cab_core.attempt.contract import NOT_MEASURED, PARTS, canonical_json, combined, digest
from cab_core.errors import RecordError

_HEX = re.compile(r"^[0-9a-f]{64}$")


# -- reading and comparing ------------------------------------------------------------------------
def _checked(c: Any, where: str) -> dict:
    if not isinstance(c, Mapping) or not isinstance(c.get("digest"), str) or not isinstance(c.get("parts"), Mapping):
        raise RecordError(f"{where} contract should be {{'digest': <sha256>, 'parts': {{...}}}}, got {c!r:.80}")
    for k, v in c["parts"].items():
        if not isinstance(v, str) or not _HEX.match(v):
            raise RecordError(f"{where} contract part {k!r} should be a SHA-256 hex digest, got {v!r:.80}")
    return {"digest": c["digest"], "parts": dict(c["parts"])}


def of_result(result: Mapping, where: str = "result.json") -> dict | None:
    """The contract a result (``result.json`` as read) holds, None for a record written before cab
    kept one; a malformed one is a :class:`RecordError` naming it."""
    c = result.get("contract")
    return None if c is None else _checked(c, where)


def differing(a: Mapping, b: Mapping) -> list[str]:
    """The names of the parts contracts ``a`` and ``b`` differ in (a part only one has counts), in
    :data:`PARTS` order; ``[]`` when they are the same."""
    pa, pb = a["parts"], b["parts"]
    names = {p for p in set(pa) | set(pb) if pa.get(p) != pb.get(p)}
    return [p for p in PARTS if p in names] + sorted(names - set(PARTS))


#: what a part must agree within, when attempts are put in one table: a task's definition and its
#: budgets per task, the simulator per simulator (two simulators are two configurations, the table
#: says which), the harness per harness, the serving engine per configuration; the instance (seeds)
#: is what the table's tests pair, never a reason to refuse; every other part everywhere
_WITHIN = {"task": "task", "budget": "task", "simulator": "sim", "harness": "harness", "serving": "config"}


def report_check(rows: Iterable[Mapping]) -> list[str]:
    """The parts the attempts ``rows`` (each with ``config``, ``task``, ``sim``, ``harness`` and its
    ``contract``, None for an older record) disagree on, where they would be one table: by name, in
    :data:`PARTS` order. Records without a contract are not counted."""
    seen: dict[str, dict[Any, set]] = {}
    for r in rows:
        c = r.get("contract")
        if not c:
            continue
        parts = c["parts"]
        for p in set(parts) | {"serving"}:
            if p == "seeds":
                continue
            key = r.get(_WITHIN[p]) if p in _WITHIN else None
            seen.setdefault(p, {}).setdefault(key, set()).add(parts.get(p))
    bad = {p for p, groups in seen.items() if any(len(v) > 1 for v in groups.values())}
    return [p for p in PARTS if p in bad] + sorted(bad - set(PARTS))


class ContractsDiffer(RecordError):
    """Attempts put in one table ran under different comparison contracts; ``parts`` names what differs."""

    def __init__(self, parts: list[str], where: str):
        self.parts = parts
        super().__init__(f"the attempts under {where} ran under different comparison contracts (they differ in: "
                         f"{', '.join(parts)}); not put in one table: report them apart, or pass --mix-contracts "
                         "for an exploratory table")


def table_contracts(rows: list[Mapping], mix: bool, where: str) -> dict:
    """What a report says of the contracts of the attempts ``rows`` it puts in one table (see
    :func:`report_check`): ``differing`` (part names), ``exploratory`` (they differ and ``mix``
    allowed it), ``by_config`` (each configuration's :func:`combined` digest, None where none of its
    records has a contract) and ``without`` (records written before cab kept one). Raises
    :class:`ContractsDiffer` when they differ and ``mix`` is false."""
    bad = report_check(rows)
    if bad and not mix:
        raise ContractsDiffer(bad, where)
    by: dict[str, list] = {}
    for r in rows:
        by.setdefault(r["config"], []).append(r.get("contract"))
    return {"exploratory": bool(bad), "differing": bad, "without": sum(1 for r in rows if not r.get("contract")),
            "by_config": {c: (combined([x for x in cs if x])["digest"] if any(cs) else None)
                          for c, cs in sorted(by.items())}}


def exploratory_note(parts: list[str]) -> str:
    """The words that mark a table whose attempts' contracts differ."""
    return f"EXPLORATORY: comparison contracts differ in {', '.join(parts)}"


__all__ = ["NOT_MEASURED", "PARTS", "ContractsDiffer", "canonical_json", "combined", "differing", "digest",
           "exploratory_note", "of_result", "report_check", "table_contracts"]
