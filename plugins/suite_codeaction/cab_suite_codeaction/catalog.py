"""The suite's task catalog: instructions, seeds, scoring rules, budgets, checkpoints and reference
figures of the 25 tasks.

The data are the suite's copy of the benchmark's catalog (``cab_suite_codeaction/data/catalog.yaml``,
transcribed from the seed paper). This module is its only reader: each task of the suite takes its
:class:`~cab_core.contracts.task.TaskInfo` from :func:`task_info`, so instructions and budgets have one source.
The core learns about tasks only through the task-suite hook (``cab_core.plugins.task_info``).
"""
from __future__ import annotations

import copy
from functools import lru_cache
from importlib import resources
from typing import Any

from cab_core.contracts.task import TaskInfo
from cab_core.errors import ConfigError

SCORING_MODES = ("final", "latch")
_REQUIRED = ("name", "instruction", "seed", "scoring", "budget_tool_calls", "budget_sim_s")


@lru_cache(maxsize=1)
def _load() -> dict[str, Any]:
    import yaml

    text = resources.files(__package__).joinpath("data", "catalog.yaml").read_text(encoding="utf-8")
    data = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml where built: ~10x faster
    if not isinstance(data, dict) or not isinstance(data.get("tasks"), list):
        raise ConfigError(f"{__package__}/data/catalog.yaml has no 'tasks:' list")
    seen: set[str] = set()
    for i, t in enumerate(data["tasks"]):
        missing = [k for k in _REQUIRED if k not in t]
        if missing:
            raise ConfigError(f"catalog task #{i} ({t.get('name', '?')}) lacks {', '.join(missing)}")
        if t["name"] in seen:
            raise ConfigError(f"catalog task {t['name']!r} is listed twice")
        if t["scoring"] not in SCORING_MODES:
            raise ConfigError(f"catalog task {t['name']!r}: scoring {t['scoring']!r} not in {SCORING_MODES}")
        seen.add(t["name"])
    return data


def load_catalog() -> dict[str, Any]:
    """The whole catalog as plain data (a deep copy: callers may not mutate the cached original)."""
    return copy.deepcopy(_load())


def task_names() -> list[str]:
    """Catalog task names, in catalog order."""
    return [t["name"] for t in _load()["tasks"]]


def has_catalog_entry(name: str) -> bool:
    """Whether the catalog has an entry ``name``."""
    return any(t["name"] == name for t in _load()["tasks"])


def task_info(name: str) -> TaskInfo:
    """The catalog entry of task ``name`` (a fresh object each call). Unknown names raise
    :class:`ConfigError` listing the choices."""
    for t in _load()["tasks"]:
        if t["name"] == name:
            return _to_info(t)
    raise ConfigError(f"unknown task {name!r}; choices: {', '.join(sorted(task_names()))}")


def _to_info(t: dict[str, Any]) -> TaskInfo:
    def opt(key: str, kind):
        v = t.get(key)
        return None if v is None else kind(v)

    return TaskInfo(
        name=str(t["name"]),
        instruction=str(t["instruction"]),  # verbatim
        seed=int(t["seed"]),
        scoring=str(t["scoring"]),
        budget_tool_calls=int(t["budget_tool_calls"]),
        budget_sim_s=float(t["budget_sim_s"]),
        category=str(t.get("category", "")),
        reference_solution_api_calls=opt("reference_solution_api_calls", int),
        reference_solution_sim_s=opt("reference_solution_sim_s", float),
        subgoals=tuple(str(s) for s in t.get("subgoals") or ()),
        spatial_checkpoints=tuple(copy.deepcopy(dict(c)) for c in t.get("spatial_checkpoints") or ()),
    )
