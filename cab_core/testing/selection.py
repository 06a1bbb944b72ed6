"""What ``pytest --cab-conformance`` selected in this run: groups, simulators, tasks and parallel
attempts (set by :mod:`cab_core.testing.pytest_plugin`, read by the checks it collects)."""
from __future__ import annotations

from dataclasses import dataclass

import pytest

GROUPS = ("sims", "tasks", "determinism")
NODE = "cab-conformance"  # the node id the items are collected under


@dataclass(frozen=True)
class Selection:
    groups: tuple[str, ...]
    sims: tuple[str, ...]
    tasks: tuple[str, ...]
    jobs: int


SELECTION = pytest.StashKey[Selection]()


def selection(config: pytest.Config) -> Selection | None:
    """What ``--cab-conformance`` selected in this run (None: the option is off)."""
    return config.stash.get(SELECTION, None)
