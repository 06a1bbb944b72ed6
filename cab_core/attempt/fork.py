"""Forks: an attempt that starts where an earlier attempt (its parent) stood after its charged call K.

A fork re-executes the parent's first K charged calls (and the free calls among them) in a fresh
world built from the parent's resolved configuration, through the same call server, clock and
ledger as any attempt: programs re-run in the sandbox, budgets are charged, observations are
taken again under the same ids, a latched event latches again. The simulators are deterministic
(the same scene built the same way steps identically, see the simulator conformance suite), so
the world after the prefix is the parent's; the fork checks that against the parent's privileged
snapshots (every TCP and object within ``FORK_TOLERANCE_M``, the same calls with the same
statuses and physics steps) and refuses to go on (:class:`ForkDiverged`) where it is not.

Why re-execution, not stored simulator states: it needs nothing the records do not already hold,
so any attempt ever recorded can be forked (the real agent attempts in the project's shared data
included); a state blob written after every call would perturb the run it is taken from (a simulator may
write a saved state back into its world, see its plugin) and may cost a world rebuild per call.

The child's records hold the prefix's events (marked ``"fork_prefix": true``) and snapshots, then
a ``fork`` event, then its own agent's; ``result.json`` names the parent (a path relative to the
child) and K. A fork of a fork replays the child's records, which already hold the first prefix.

This module is the fork point (:class:`ForkPoint`: what the parent's records hold up to call K) and
the comparison of a prefix made again with them (:func:`compare_prefix`). The episode makes the
prefix again itself (:meth:`cab_core.attempt.engine.episode.Episode.replay_prefix`); a harness
rebuilds its agent's conversation with :mod:`cab_core.kits.harness.conversation`; how a fork ended,
as a recovery, is :mod:`cab_core.attempt.records.recovery`; the viewer lists the forks of an
attempt with :func:`cab_core.analysis.viewer.forks_of`."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cab_core.errors import CabError, ConfigError, RecordError
from cab_core.kits.harness.conversation import DIRECT
from cab_core.kits.jsonfiles import read_jsonl

FORK_TOLERANCE_M = 0.005
#: the parent's settings a fork keeps: everything that decides the world and the budgets
KEPT = ("task", "seed", "sim", "embodiment", "planner", "budget_tool_calls", "budget_sim_seconds",
        "budget_wall_seconds", "run_code_max_internal_calls", "sandbox", "sim_cfg", "planner_cfg",
        "embodiment_cfg", "perturb", "randomize")
FORKS_FILE = "forks.jsonl"  # in the parent: one line per fork made of it (best effort)


class ForkDiverged(CabError):
    """The re-executed prefix did not reproduce the parent's world (another machine, another
    version of a simulator or a program whose behaviour is not reproducible)."""


def is_charged(e: dict) -> bool:
    return e.get("kind") == "call" and e.get("charged", True) is not False


def charged_calls(events: list[dict]) -> int:
    return sum(1 for e in events if is_charged(e))


@dataclass
class ForkPoint:
    """Where a fork starts: the parent's records up to and including its charged call ``at``."""
    parent: Path
    at: int
    config: dict  # the parent's resolved configuration (its ``attempt_start`` event)
    events: list[dict]  # the parent's events up to and including charged call ``at``
    snapshots: list[dict]  # the parent's privileged snapshots taken up to then
    wall_seconds: float  # the parent's wall-clock budget spent by then
    parent_calls: int  # the parent's charged calls in all
    lineage: list[dict] = field(default_factory=list)  # the parent's own fork, and its parent's...

    @classmethod
    def load(cls, parent: str | Path, at: Any) -> ForkPoint:
        """The fork point of ``parent`` (an attempt directory) after its charged call ``at``;
        ConfigError for a K out of range or a folder that holds no attempt."""
        if isinstance(at, bool) or not isinstance(at, int) or at < 0:
            raise ConfigError(f"fork.at must be a non-negative integer (a charged call of the parent), got {at!r}")
        d = Path(parent).expanduser()
        if not (d / "events.jsonl").is_file():
            raise ConfigError(f"fork.from={parent}: no attempt there (events.jsonl is missing)")
        torn = torn_last_line(d / "events.jsonl")
        if torn:
            raise RecordError(f"fork.from={parent}: events.jsonl line {torn} is torn (not valid JSON: the attempt was "
                              "cut off while writing it); the parent's records are incomplete, so it is not forked "
                              "(remove that line to fork the calls before it)")
        events = read_jsonl(d / "events.jsonl")
        start = next((e for e in events if e.get("kind") == "attempt_start"), None)
        if start is None or not isinstance(start.get("config"), dict):
            raise RecordError(f"fork.from={parent}: the records lack the resolved configuration "
                              "(attempt_start.config); attempts recorded before cab stored it cannot be forked")
        total = charged_calls(events)
        if at > total:
            raise ConfigError(f"fork.at={at}: the parent made {total} charged call(s); choose 0 to {total}")
        cut, n = 0, 0
        for i, e in enumerate(events):
            if n == at:
                break
            cut = i + 1
            n += is_charged(e)
        if at == 0:
            cut = next(i for i, e in enumerate(events) if e is start) + 1
        prefix = events[:cut]
        snaps = read_jsonl(d / "privileged" / "snapshots.jsonl") if (d / "privileged" / "snapshots.jsonl").is_file() else []
        snaps = [s for s in snaps if s.get("label") != "end" and int(s.get("calls", 0)) <= at]
        waited = sum(float(e.get("waited_s") or 0.0) for e in prefix if e.get("kind") == "model_turn")
        t_end = float(prefix[-1].get("t_wall", 0.0)) if at else float(start.get("t_wall", 0.0))
        wall = max(0.0, t_end - float(start.get("t_wall", 0.0)) - waited)
        lineage = []
        own = start.get("config", {}).get("fork")
        if isinstance(own, dict):
            lineage.append(own)
        return cls(d.resolve(), at, dict(start["config"]), prefix, snaps, round(wall, 3), total, lineage)

    def calls(self) -> list[tuple[str, dict]]:
        """The direct calls to make again, in order."""
        return [(e["tool"], e.get("arguments") or {}) for e in self.events if e.get("kind") in DIRECT]

    def as_record(self, child: Path) -> dict:
        """``fork`` in the child's config and ``result.json``: the parent relative to the child."""
        return {"parent": relative(self.parent, child), "at": self.at}


def torn_last_line(path: Path) -> int:
    """The number of the last line of an append-only log when it is not valid JSON (a process
    killed mid-write; :func:`~cab_core.kits.jsonfiles.read_jsonl` drops it), else 0."""
    lines = Path(path).read_text(errors="replace").splitlines()  # a torn multi-byte character included
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        return 0
    try:
        json.loads(lines[-1])
    except ValueError:
        return len(lines)
    return 0


def relative(path: Path, start: Path) -> str:
    """``path`` relative to ``start``, with forward slashes (records name no machine path)."""
    return os.path.relpath(Path(path).resolve(), Path(start).resolve()).replace(os.sep, "/")


def fork_config(spec_fields: dict, point: ForkPoint) -> dict:
    """The child's spec fields: the parent's world and budgets (``KEPT``), the child's agent,
    harness, record settings and output directory."""
    out = dict(spec_fields)
    for k in KEPT:
        if k in point.config:
            out[k] = point.config[k]
    return out


def distance(p, q) -> float:
    return float(np.linalg.norm(np.asarray(p[:3], float) - np.asarray(q[:3], float)))


def snapshot_deviation(orig: dict, new: dict) -> tuple[float, float, list[str]]:
    """The largest TCP and object position differences between two snapshots of one world, and
    what is missing from the second."""
    tcp = obj = 0.0
    missing = []
    for arm, s in (orig.get("arms") or {}).items():
        if arm in (new.get("arms") or {}):
            tcp = max(tcp, distance(s["tcp_pose"], new["arms"][arm]["tcp_pose"]))
        else:
            missing.append(f"arm {arm!r}")
    for name, s in (orig.get("objects") or {}).items():
        if name in (new.get("objects") or {}):
            obj = max(obj, distance(s["pose"], new["objects"][name]["pose"]))
        else:
            missing.append(f"object {name!r}")
    return tcp, obj, missing


def _same_state(a: dict, b: dict) -> bool:
    """Whether two snapshots hold the same state as the record rounds it."""
    return (a.get("objects") == b.get("objects") and a.get("physics_step") == b.get("physics_step")
            and {k: v.get("tcp_pose") for k, v in (a.get("arms") or {}).items()}
            == {k: v.get("tcp_pose") for k, v in (b.get("arms") or {}).items()})


def compare_prefix(point: ForkPoint, made: list[dict], snapshots: list[dict], charged: int,
                   tolerance: float = FORK_TOLERANCE_M) -> dict:
    """Compare a prefix made again with the parent's records of it: ``made``, the events the
    re-execution recorded (those marked ``fork_prefix``), ``snapshots``, the privileged snapshots it
    took, ``charged``, the charged calls it made. Returns the comparison's fields of the ``fork``
    event (``snapshots_compared``, ``exact``, ``max_tcp_error_m``, ``max_object_error_m``); raises
    :class:`ForkDiverged` naming the first differences when the world is not the parent's."""
    problems: list[str] = []
    if charged != point.at:
        problems.append(f"{charged} charged calls made again, {point.at} asked for")
    theirs = [e for e in point.events if e.get("kind") in DIRECT + ("internal_call",)]
    ours = [e for e in made if e.get("kind") in DIRECT + ("internal_call",)]
    if len(ours) != len(theirs):
        problems.append(f"{len(theirs)} calls in the parent's prefix, {len(ours)} made again")
    for i, (x, y) in enumerate(zip(theirs, ours)):
        for key in ("tool", "status", "physics_steps"):
            if x.get(key) != y.get(key):
                problems.append(f"call {i + 1} ({x.get('tool')}): {key} {x.get(key)!r} in the parent, {y.get(key)!r} now")
                break
    max_tcp = max_obj = 0.0
    if len(snapshots) != len(point.snapshots) and point.snapshots:
        problems.append(f"{len(point.snapshots)} snapshots in the parent's prefix, {len(snapshots)} now")
    for x, y in zip(point.snapshots, snapshots):
        tcp, obj, missing = snapshot_deviation(x, y)
        max_tcp, max_obj = max(max_tcp, tcp), max(max_obj, obj)
        problems += [f"snapshot {x.get('label')}: {m} missing now" for m in missing]
    if max_tcp > tolerance or max_obj > tolerance:
        problems.append(f"the world is {1000 * max(max_tcp, max_obj):.1f} mm from the parent's "
                        f"(tolerance {1000 * tolerance:g} mm)")
    exact = bool(point.snapshots) and len(snapshots) >= len(point.snapshots) and all(
        _same_state(x, y) for x, y in zip(point.snapshots, snapshots))
    if problems:
        raise ForkDiverged(f"fork of {point.parent.name} at call {point.at}: the re-executed prefix differs "
                           f"from the parent's records: {'; '.join(problems[:5])}"
                           + (f" (and {len(problems) - 5} more)" if len(problems) > 5 else ""))
    return {"snapshots_compared": min(len(snapshots), len(point.snapshots)), "exact": exact,
            "max_tcp_error_m": round(max_tcp, 6), "max_object_error_m": round(max_obj, 6)}


def link_parent(point: ForkPoint, child: Path) -> bool:
    """Append the child to the parent's ``forks.jsonl`` so the parent's viewer links to it; a
    parent that cannot be written to (a read-only archive) is left as it is."""
    try:
        with open(point.parent / FORKS_FILE, "a") as f:
            f.write(json.dumps({"child": relative(child, point.parent), "at": point.at}) + "\n")
        return True
    except OSError:
        return False
