"""Checkpoints (paper §"Checkpoint definitions"): subgoal checkpoints derived from the verifier's
named sub-predicates, and spatial checkpoints, regions for the TCP around references that follow
moving objects. Both are evaluated from an attempt's records (privileged snapshots and TCP poses),
counted once at their first confirmed match; spatial matches need their prerequisites first.

Tasks declare them with the vocabulary of :mod:`cab_core.contracts.checkpoints`; this module
evaluates them.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule
from cab_core.contracts.simulator import Contact, Simulator
from cab_core.contracts.verifier import WorldView
from cab_core.plugins import all_tasks, create


@dataclass
class CheckpointReport:
    subgoals: list[dict] = field(default_factory=list)
    spatial: list[dict] = field(default_factory=list)
    subgoals_at_start: list[bool] = field(default_factory=list)

    @property
    def subgoal_coverage(self) -> float:
        return sum(s["attained"] for s in self.subgoals) / len(self.subgoals) if self.subgoals else 0.0

    @property
    def spatial_coverage(self) -> float:
        return sum(s["attained"] for s in self.spatial) / len(self.spatial) if self.spatial else 0.0

    def as_dict(self) -> dict:
        return {"subgoals": self.subgoals, "spatial": self.spatial, "subgoals_at_start": self.subgoals_at_start,
                "subgoal_coverage": round(self.subgoal_coverage, 4), "spatial_coverage": round(self.spatial_coverage, 4)}


# ---------------------------------------------------------------------------------------------
# evaluation from records
# ---------------------------------------------------------------------------------------------
class SnapshotState:
    """A recorded privileged snapshot seen through the read-only part of the Simulator contract,
    so a task's ``WorldView``-based predicates run on records without a simulator."""

    def __init__(self, snap: dict, emb):
        self.snap = snap
        self._tcp = {emb.arms[a].tcp_link: a for a in emb.arms}

    def get_object_pose(self, name: str) -> np.ndarray:
        return np.asarray(self.snap["objects"][name]["pose"], float)

    def get_object_qpos(self, name: str) -> np.ndarray:
        return np.asarray(self.snap["objects"][name].get("qpos", []), float)

    def get_object_link_pose(self, name: str, link: str) -> np.ndarray:
        return np.asarray(self.snap["objects"][name]["links"][link], float)

    def get_link_pose(self, link: str) -> np.ndarray:
        if link not in self._tcp:
            raise KeyError(f"only TCP poses are recorded, not {link!r}")
        return np.asarray(self.snap["arms"][self._tcp[link]]["tcp_pose"], float)

    def get_contacts(self):
        return [Contact(a, b, float(i)) for a, b, i in self.snap.get("contacts", [])]


def load_snapshots(attempt_dir) -> list[dict]:
    p = Path(attempt_dir) / "privileged" / "snapshots.jsonl"
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def evaluate(task, emb, info: dict, snapshots: list[dict], latched: bool = False) -> CheckpointReport:
    """First confirmed match of every subgoal and spatial checkpoint over the snapshots (in
    order). A subgoal already true at the start is not credited until it has been false once
    (baseline). ``latched``: the attempt's latch event, which satisfies a latch task's event
    subgoal (``info['latch_subgoals']`` lists their indices, when a task declares them)."""
    n_sub = len(task.info.subgoals)
    rules: list[SpatialRule] = list(task.spatial_checkpoints(info)) if hasattr(task, "spatial_checkpoints") else []
    sub_first: list[dict | None] = [None] * n_sub
    sub_armed = [True] * n_sub
    sp_first: list[dict | None] = [None] * len(rules)
    sp_z: list[dict] = [dict() for _ in rules]  # arm -> TCP z at the match (for relative lifts)
    start_values: list[bool] = []
    for k, snap in enumerate(snapshots):
        state = SnapshotState(snap, emb)
        grips = {a: snap["arms"][a]["gripper_cmd"] for a in snap["arms"]}
        # cast: a SnapshotState answers, from a record, the reads a WorldView makes of a Simulator
        # (object and link poses, joint positions, contacts); it implements none of its other methods
        w = WorldView(cast(Simulator, state), emb, grips, info)
        where = {"snapshot": k, "label": snap.get("label"), "calls": snap.get("calls"),
                 "physics_step": snap.get("physics_step")}
        if hasattr(task, "subgoals") and n_sub:
            vals = list(task.subgoals(w))
            if k == 0:
                start_values = [bool(v) for v in vals[:n_sub]]
            for i, v in enumerate(vals[:n_sub]):
                if k == 0:
                    sub_armed[i] = not v
                    continue
                if sub_first[i] is None:
                    if v and sub_armed[i]:
                        sub_first[i] = where
                    elif not v:
                        sub_armed[i] = True
        for i, r in enumerate(rules):
            if sp_first[i] is not None or k == 0:
                continue
            if not r.ready(sp_first):
                continue
            arms = [a for a in sorted(snap["arms"])] if r.arm == "either" else [r.arm]
            for a in arms:
                tcp = np.asarray(snap["arms"][a]["tcp_pose"][:3], float)
                if r.lift_above_cm is not None:
                    base = None
                    for j in r.prerequisites:
                        base = sp_z[j].get(a, base)
                    if base is None:
                        continue
                    need = r.lift_above_cm(w) if callable(r.lift_above_cm) else r.lift_above_cm
                    ok = (tcp[2] - base) * 100.0 > need
                else:
                    assert r.reference is not None and r.test is not None  # a region rule has both
                    ref = np.asarray(r.reference(w), float)
                    ok = bool(r.test((tcp - ref) * 100.0))
                if ok:
                    sp_first[i] = {**where, "arm": a}
                    sp_z[i][a] = float(tcp[2])
                    break
    if latched and info.get("latch_subgoals"):
        for i in info["latch_subgoals"]:
            if sub_first[i] is None:
                sub_first[i] = {"snapshot": None, "label": "latch event", "calls": None, "physics_step": None}
    rep = CheckpointReport(subgoals_at_start=start_values)
    for i, text in enumerate(task.info.subgoals):
        rep.subgoals.append({"index": i + 1, "text": text, "attained": sub_first[i] is not None, "first": sub_first[i]})
    for i, r in enumerate(rules):
        rep.spatial.append({"index": i + 1, "name": r.name, "arm": r.arm, "attained": sp_first[i] is not None,
                            "first": sp_first[i]})
    return rep


def evaluate_attempt(attempt_dir, task=None, emb=None) -> CheckpointReport:
    """Checkpoints of a recorded attempt, from its directory alone (plus the installed task)."""
    d = Path(attempt_dir)
    result = json.loads((d / "result.json").read_text())
    scene = json.loads((d / "privileged" / "scene_info.json").read_text())
    task = task or all_tasks()[result["task"]]
    emb = emb or create("embodiments", result["embodiment"], {})
    latched = bool(((result.get("verdict") or {}).get("latch") or {}).get("latched"))
    return evaluate(task, emb, scene["info"], load_snapshots(d), latched=latched)
