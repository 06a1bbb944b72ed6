"""An attempt's comparison contract, computed from its resolved spec
(:class:`cab_core.attempt.spec.AttemptSpec`) and the installed code: what each part of
:data:`cab_core.attempt.contract.PARTS` covers (docs/comparing.md). The episode writes it into
``result.json``; ``cab -m`` computes it for each configuration of a sweep
(:mod:`cab_core.apps.sweep_contracts`)."""
from __future__ import annotations

import hashlib
import inspect
import re
from collections.abc import Mapping
from functools import cache, lru_cache
from importlib import metadata
from typing import Any

from cab_core.attempt.contract import NOT_MEASURED, digest, whole
from cab_core.plugins import GROUP, _installed_tasks, registry
from cab_core.tools import schemas


def _measured(cfg: Mapping | None) -> dict:
    return {k: v for k, v in (cfg or {}).items() if k not in NOT_MEASURED}


@cache
def _plugin_distributions() -> dict[str, str]:
    """``{top-level module: distribution}`` of the distributions that provide cab's entry points."""
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
    return whole(attempt_parts(spec, serving))
