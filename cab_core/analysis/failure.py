"""Failure stages (paper, Appendix "Failure Analysis"): each failed attempt is assigned the earliest
stage its records support, for the first subgoal that does not hold at termination.

Stages, in execution order:

* ``arrival``         unconfirmed arrival: no spatial match for the region the unmet subgoal needs
                      (no request reached it, or requests failed);
* ``object_control``  unconfirmed object control: arrival without confirmed common motion of a
                      held object, or transport lost (released and drifted) before arrival;
* ``subgoal_outcome`` arrival and control confirmed, the required object state never reached;
* ``state_loss``      the subgoal held earlier and no longer holds at termination (an event
                      subgoal, once latched, is never lost);
* ``final_condition`` every subgoal holds, an additional final condition of the verifier (e.g. the
                      final gripper state, a guard) does not;
* ``unresolved``      the records cannot support a stage (no snapshots, checkpoint errors, ...).

Common motion (paper's criterion): both fingers of one arm contact the object after an action,
and over that action both the TCP and the object move at least 3 cm while the object-minus-TCP
vector changes by at most 3 cm. The task's subgoal predicates are evaluated on the recorded final
snapshot; no simulator is involved.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from cab_core.attempt.engine.checkpoint_scoring import SnapshotState
from cab_core.contracts.simulator import WorldReads
from cab_core.contracts.verifier import WorldView
from cab_core.kits.jsonfiles import read_json_object as read_json
from cab_core.plugins import all_tasks, create

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.analysis.attempts import Attempt

STAGES = ("arrival", "object_control", "subgoal_outcome", "state_loss", "final_condition", "unresolved")
LABELS = {"arrival": "Unconfirmed arrival", "object_control": "Unconfirmed object control",
          "subgoal_outcome": "Subgoal outcome not reached", "state_loss": "Subgoal state lost",
          "final_condition": "Final condition unmet", "unresolved": "Unresolved"}
MOVE_M = 0.03  # TCP and object displacement over one action, and the relative-drift bound


@dataclass(frozen=True)
class Grip:
    """One confirmed common motion: after snapshot ``k``, ``arm`` carried ``obj``."""
    k: int
    arm: str
    obj: str


def _pos(pose) -> np.ndarray:
    return np.asarray(pose[:3], float)


def common_motions(snaps: list[dict], fingers: dict[str, tuple[str, str]]) -> list[Grip]:
    """Every action (consecutive snapshot pair) with confirmed common motion of arm and object."""
    out = []
    for k in range(1, len(snaps)):
        a, b = snaps[k - 1], snaps[k]
        touching: dict[str, set] = {}
        for x, y, _ in b.get("contacts", []):
            for link, other in ((x, y), (y, x)):
                touching.setdefault(other, set()).add(link.rsplit("/", 1)[-1])
        for arm, links in fingers.items():
            tcp0, tcp1 = _pos(a["arms"][arm]["tcp_pose"]), _pos(b["arms"][arm]["tcp_pose"])
            if np.linalg.norm(tcp1 - tcp0) < MOVE_M:
                continue
            for obj, parts in touching.items():
                if not set(links) <= parts or obj not in a["objects"] or obj not in b["objects"]:
                    continue
                o0, o1 = _pos(a["objects"][obj]["pose"]), _pos(b["objects"][obj]["pose"])
                if np.linalg.norm(o1 - o0) >= MOVE_M and np.linalg.norm((o1 - tcp1) - (o0 - tcp0)) <= MOVE_M:
                    out.append(Grip(k, arm, obj))
    return out


def transport_lost(snaps: list[dict], grip: Grip) -> bool:
    """After the carrying action, the gripper opened and the object drifted from the TCP."""
    a, last = snaps[grip.k], snaps[-1]
    opened = float(last["arms"][grip.arm].get("gripper_cmd", 0.0)) > 0.5
    rel0 = _pos(a["objects"][grip.obj]["pose"]) - _pos(a["arms"][grip.arm]["tcp_pose"])
    rel1 = _pos(last["objects"][grip.obj]["pose"]) - _pos(last["arms"][grip.arm]["tcp_pose"])
    return opened and float(np.linalg.norm(rel1 - rel0)) > MOVE_M


def final_subgoals(task, emb, info: dict, snaps: list[dict]) -> list[bool]:
    """The task's subgoal predicates on the recorded final snapshot."""
    last = snaps[-1]
    grips = {a: last["arms"][a]["gripper_cmd"] for a in last["arms"]}
    # cast: a SnapshotState answers from its record every read of WorldReads but object_names,
    # which only a live world is asked (WorldView.remember_start, the oracles' helpers)
    w = WorldView(cast(WorldReads, SnapshotState(last, emb)), emb, grips, info)
    return [bool(v) for v in list(task.subgoals(w))[:len(task.info.subgoals)]]


def classify(attempt: Attempt, task, emb) -> tuple[str | None, str]:
    """(stage, why) for a failed attempt; (None, "") for a successful one."""
    if attempt.success:
        return None, ""
    ck = attempt.result.get("checkpoints")
    if not isinstance(ck, dict) or "error" in ck or not ck.get("subgoals"):
        return "unresolved", "no usable checkpoint record"
    snaps = attempt.snapshots
    if not snaps:
        return "unresolved", "no privileged snapshots"
    try:
        info = read_json(attempt.dir / "privileged" / "scene_info.json")["info"]
        final = final_subgoals(task, emb, info, snaps)
    except Exception as e:  # a missing scene record, or a predicate needing state the snapshots lack
        return "unresolved", f"subgoals not evaluable from the records: {e!r}"
    subgoals = ck["subgoals"]
    latch = set(info.get("latch_subgoals") or [])
    held = [bool(f) or (i in latch and subgoals[i]["attained"]) for i, f in enumerate(final)]
    if all(held):
        v = attempt.result["verdict"]
        unmet = [k for part in ("final_requirements", "guard") for k, ok in (v.get(part) or {}).items() if not ok]
        return "final_condition", "all subgoals hold; unmet: " + (", ".join(unmet) or "the verifier's final condition")
    i = held.index(False)
    target = f"subgoal {i + 1} ({subgoals[i]['text']})"
    if subgoals[i]["attained"]:
        return "state_loss", f"{target} held from call {subgoals[i]['first'].get('calls')} and was lost"
    spatial = ck.get("spatial") or []
    reached = [s for s in spatial if s["attained"]]
    if not reached:
        return "arrival", f"{target}: no spatial checkpoint matched"
    fingers = {a: tuple(emb.arms[a].gripper.finger_links) for a in emb.arms}
    grips = common_motions(snaps, fingers)
    if not grips:
        return "object_control", f"{target}: arrival at {reached[-1]['name']!r} without confirmed object control"
    missing = [s for s in spatial if not s["attained"]]
    if not missing:
        return "subgoal_outcome", f"{target}: every region reached and an object carried, the state not reached"
    if transport_lost(snaps, grips[-1]):
        return "object_control", f"{target}: {grips[-1].obj} released and lost before {missing[0]['name']!r}"
    return "arrival", f"{target}: {missing[0]['name']!r} not reached"


class Classifier:
    """Classifies attempts, loading each task and embodiment from the plugins once (no simulator)."""

    def __init__(self):
        self._tasks = None
        self._embs: dict[str, object] = {}

    def __call__(self, attempt: Attempt) -> tuple[str | None, str]:
        if attempt.success:
            return None, ""
        if self._tasks is None:
            self._tasks = all_tasks()
        r = attempt.result
        task = self._tasks.get(r["task"])
        if task is None or not hasattr(task, "subgoals"):
            return "unresolved", f"task {r['task']!r} is not installed or declares no subgoals"
        name = r.get("embodiment", "")
        try:
            if name not in self._embs:
                self._embs[name] = create("embodiments", name, {})
        except Exception as e:
            return "unresolved", f"embodiment {name!r} unavailable: {e}"
        return classify(attempt, task, self._embs[name])
