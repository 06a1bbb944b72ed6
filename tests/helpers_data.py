"""Helpers the tests share for building variants of nested JSON-like data (dicts and lists)."""
from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any


def replaced(value: Any, path: Sequence[Any], new: Any) -> Any:
    """A deep copy of ``value`` in which the item at ``path`` (one key or index per level) is ``new``;
    ``value`` itself is left as it was."""
    value = copy.deepcopy(value)
    node = value
    for step in path[:-1]:
        node = node[step]
    node[path[-1]] = new
    return value
