"""The comparison contract: a digest of everything that makes two runs measure the same thing.

Two attempts (or two sweeps, two machines, two cab versions) can be put side by side only where
they ran the same benchmark: the same tools, task definitions, budgets, simulator, planner... The
contract names each of those things as a *part*, digests each part separately (SHA-256 of its
canonical JSON: sorted keys, no whitespace, integral floats written as integers, so the digest is
the same under every Python from 3.11 and every numpy), and digests the parts together::

    "contract": {"digest": "<sha256 hex>", "parts": {"budget": "<sha256 hex>", "planner": ..., ...}}

Every ``result.json`` holds its attempt's contract (:func:`attempt_contract`, from the resolved
:class:`cab_core.attempt.spec.AttemptSpec`); a sweep's manifest holds one per configuration
(:func:`combined`: each part over the set of its attempts' digests of that part). The parts
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

Public API: :func:`attempt_contract`, :func:`of_result` (a result's contract, None for records
written before it existed), :func:`differing` (the parts two contracts differ in, by name),
:func:`combined`, :func:`report_check` (the parts a set of attempts put in one table disagree on) and
:func:`table_contracts` (what cab-report says of them, or :class:`ContractsDiffer`: its refusal).
"""
from __future__ import annotations

import hashlib
import inspect
import json
import re
from collections.abc import Iterable, Mapping
from functools import cache, lru_cache
from importlib import metadata
from typing import Any

from cab_core.errors import RecordError

#: the parts of a contract, in the order a difference is named
PARTS = ("tools", "task", "seeds", "budget", "embodiment", "planner", "simulator", "variation", "harness",
         "sandbox", "serving")

#: configuration keys that do not change what an attempt measures: launcher figures, caches, how a
#: harness is reached and how long it waits for a client that went away
NOT_MEASURED = frozenset({"slot_memory_mb", "brdf_cache", "transport", "host", "port", "auth", "idle_timeout_s",
                          "linger_s", "startup_timeout_s"})

_HEX = re.compile(r"^[0-9a-f]{64}$")


# -- digests --------------------------------------------------------------------------------------
def _canonical(value: Any) -> Any:
    """``value`` as plain JSON data: mappings with string keys, lists, numbers (a float that is an
    integer written as one: ``60.0`` and ``60`` are the same budget), strings, booleans, null."""
    if hasattr(value, "item") and callable(value.item) and not isinstance(value, (str, bytes)):
        try:
            value = value.item()  # a numpy scalar
        except (TypeError, ValueError):
            pass
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        if value != value or value in (float("inf"), float("-inf")):
            raise RecordError(f"a contract holds no non-finite number, got {value!r}")
        return int(value) if value.is_integer() else value
    if hasattr(value, "tolist"):
        return _canonical(value.tolist())
    return str(value)


def canonical_json(value: Any) -> str:
    """The one text of ``value`` that is digested: sorted keys, no whitespace, ASCII."""
    return json.dumps(_canonical(value), sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def digest(value: Any) -> str:
    """SHA-256 (hex) of :func:`canonical_json` of ``value``."""
    return hashlib.sha256(canonical_json(value).encode("ascii")).hexdigest()


def _whole(parts: Mapping[str, str]) -> dict:
    return {"digest": digest(dict(parts)), "parts": dict(sorted(parts.items()))}


# -- what goes into each part ---------------------------------------------------------------------
def _measured(cfg: Mapping | None) -> dict:
    return {k: v for k, v in (cfg or {}).items() if k not in NOT_MEASURED}


@cache
def _plugin_distributions() -> dict[str, str]:
    """``{top-level module: distribution}`` of the distributions that provide cab's entry points."""
    from cab_core.plugins import GROUP

    out = {}
    for ep in metadata.entry_points(group=GROUP):
        dist = getattr(ep, "dist", None)
        if dist is not None:
            out[ep.module.split(".")[0]] = dist.name
    return out


def _distribution_of(module: str) -> str | None:
    return _plugin_distributions().get(module.split(".")[0])


@cache
def _versions(dist: str) -> tuple[tuple[str, str], ...]:
    """The version of distribution ``dist`` and of each of its installed, unconditional requirements
    (cab's own core left out: its code is digested where it matters, the tools and the task)."""
    out = {dist: metadata.version(dist)}
    for req in metadata.requires(dist) or []:
        if ";" in req:  # an extra or a marker: not what every install has
            continue
        name = re.split(r"[\s<>=!~\[(]", req.strip(), maxsplit=1)[0]
        if not name or name == _distribution_of("cab_core"):
            continue
        try:
            out[name.lower()] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return tuple(sorted(out.items()))


def _option_versions(kind: str, name: str) -> dict[str, str]:
    """The versions behind an installed option (:func:`_versions` of its plugin's distribution); ``{}``
    for an option of the core itself, and where it is not installed (a record read back elsewhere)."""
    from cab_core.plugins import registry

    factory = registry(kind).get(name)
    dist = _distribution_of(getattr(factory, "__module__", "") or "") if factory is not None else None
    if not dist or dist == _distribution_of("cab_core"):  # the core's own options: its code, not its version
        return {}
    return dict(_versions(dist))


def _class_sources(cls: type) -> list[str]:
    """The source text of ``cls`` and of the classes it derives from (``object`` and builtins left out)."""
    out = []
    for c in cls.__mro__:
        if c.__module__ in ("builtins", "abc", "typing") or c is object:
            continue
        try:
            out.append(inspect.getsource(c))
        except (OSError, TypeError):
            out.append(f"{c.__module__}.{c.__qualname__}")  # no source at hand: the name at least
    return out


@cache
def task_part(task: str) -> str:
    """The digest of task ``task``'s definition: what its info says and its code."""
    from cab_core.plugins import _installed_tasks

    tasks = _installed_tasks().tasks
    if task not in tasks:
        return digest({"task": task, "installed": False})
    t = tasks[task]
    info = t.info
    return digest({"name": info.name, "instruction": info.instruction, "scoring": info.scoring,
                   "subgoals": list(info.subgoals), "spatial_checkpoints": list(info.spatial_checkpoints),
                   "code": [hashlib.sha256(s.encode()).hexdigest() for s in _class_sources(type(t))]})


@lru_cache(maxsize=1)
def tools_part() -> str:
    """The digest of every tool's schema and description."""
    from cab_core.tools import schemas

    return digest(schemas())


def attempt_parts(spec: Mapping, serving: Mapping | None = None) -> dict[str, str]:
    """Each part's digest for one attempt: ``spec`` is :meth:`AttemptSpec.as_record` (or the
    spec itself), ``serving`` the ``agent.serving`` block where the harness wrote one."""
    s = dict(spec) if isinstance(spec, Mapping) else spec.as_record()
    parts = {
        "tools": tools_part(),
        "task": task_part(s["task"]),
        "seeds": digest({"task": s["task"], "seed": s["seed"], "attempt": s.get("attempt", 1)}),
        "budget": digest({"tool_calls": s["budget_tool_calls"], "sim_seconds": s["budget_sim_seconds"],
                          "wall_seconds": s["budget_wall_seconds"],
                          "run_code_max_internal_calls": s.get("run_code_max_internal_calls"),
                          "cost_usd": s.get("budget_cost_usd")}),
        "embodiment": digest({"cfg": _measured(s.get("embodiment_cfg")) or {"name": s.get("embodiment")},
                              "versions": _option_versions("embodiments", s.get("embodiment", ""))}),
        "planner": digest({"cfg": _measured(s.get("planner_cfg")) or {"name": s.get("planner")},
                           "versions": _option_versions("planners", s.get("planner", ""))}),
        "simulator": digest({"cfg": _measured(s.get("sim_cfg")) or {"name": s.get("sim")},
                             "versions": _option_versions("simulators", s.get("sim", ""))}),
        "variation": digest({"perturb": s.get("perturb"), "randomize": s.get("randomize")}),
        "harness": digest({"cfg": _measured(s.get("harness_cfg")) or {"name": s.get("harness")},
                           "versions": _option_versions("harnesses", s.get("harness", ""))}),
        "sandbox": digest(s.get("sandbox") or {}),
    }
    if serving and (serving.get("engine") or serving.get("version")):
        parts["serving"] = digest({"engine": serving.get("engine"), "version": serving.get("version")})
    return parts


def attempt_contract(spec: Any, serving: Mapping | None = None) -> dict:
    """``{"digest", "parts"}`` of one attempt (:func:`attempt_parts`)."""
    return _whole(attempt_parts(spec, serving))


def combined(contracts: Iterable[Mapping]) -> dict:
    """One contract over several (a configuration's attempts): each part the digest of the sorted
    set of that part's digests among them (a part some lack counts ``null`` there)."""
    cs = [c["parts"] for c in contracts]
    names = sorted({p for c in cs for p in c})
    return _whole({p: digest(sorted({c.get(p) or "" for c in cs})) for p in names})


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


__all__ = ["ContractsDiffer", "exploratory_note", "table_contracts", "NOT_MEASURED", "PARTS", "attempt_contract", "attempt_parts", "canonical_json", "combined", "differing",
           "digest", "of_result", "report_check", "task_part", "tools_part"]
