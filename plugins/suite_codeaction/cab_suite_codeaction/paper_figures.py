"""The paper's published figures: every number of its per-configuration tables, as data.

The data are ``cab_suite_codeaction/data/paper_figures.yaml`` (transcribed once from the seed paper;
tests/test_paper_figures.py compares each number with the paper's text where ``../shared`` is
present); the file's header says what each block holds and which table it comes from. This module
is their only reader, and offers them to cab through the hook ``cab_published_figures`` under the
name ``paper`` (:mod:`cab_suite_codeaction.plugin`), which ``cab-report <dir> --against paper`` reads.
"""
from __future__ import annotations

import copy
from functools import lru_cache
from importlib import resources
from typing import Any

from cab_core.errors import ConfigError

FILE = "paper_figures.yaml"
#: the blocks a configuration may carry, each from one of the paper's tables (``tables:`` of the file)
BLOCKS = ("consistency", "resource_use", "termination", "completion_judgment", "programs", "actions", "tool_use")


@lru_cache(maxsize=1)
def _load() -> dict[str, Any]:
    import yaml

    text = resources.files(__package__).joinpath("data", FILE).read_text(encoding="utf-8")
    data = yaml.safe_load(text)
    where = f"{__package__}/data/{FILE}"
    if not isinstance(data, dict) or not isinstance(data.get("configurations"), list):
        raise ConfigError(f"{where} has no 'configurations:' list")
    tables = data.get("tables") or {}
    seen: set[str] = set()
    for i, row in enumerate(data["configurations"]):
        name = row.get("name") if isinstance(row, dict) else None
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{where}: configuration #{i} has no name")
        if name in seen:
            raise ConfigError(f"{where}: configuration {name!r} is listed twice")
        seen.add(name)
        cab = row.get("cab")
        if not isinstance(cab, dict) or not cab.get("model") or not cab.get("harness"):
            raise ConfigError(f"{where}: configuration {name!r} lacks cab: {{model, harness}}")
        unknown = set(row) - {"name", "cab", "model_id", *BLOCKS}
        if unknown:
            raise ConfigError(f"{where}: configuration {name!r} has unknown block(s) {', '.join(sorted(unknown))}")
        untabled = [b for b in BLOCKS if b in row and b not in tables]
        if untabled:
            raise ConfigError(f"{where}: block(s) {', '.join(untabled)} name no table under 'tables:'")
    return data


def published_figures() -> dict[str, Any]:
    """The paper's figures as plain data (a deep copy: callers may not mutate the cached original)."""
    return copy.deepcopy(_load())
