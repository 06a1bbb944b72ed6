"""``cab-replay <attempt dir>``: re-execute an attempt from its records and validate it; or, with
``--regrade``, recompute the verdict-derived analyses from the records without a simulator.

Replay rebuilds the attempt from the resolved configuration recorded in its ``attempt_start``
event, issues the recorded direct calls in order through the same Episode machinery (programs
re-run in the sandbox, so their internal calls happen again), and compares the new records with
the original (paper, "Replay validation"):

* tool-call and action order (direct and internal calls), execution statuses, physics steps per call;
* every privileged snapshot: its label and physics step, TCP and object positions within 5 mm;
* the termination reason and the verifier's outcome.

The replay's own records go to a new directory (default ``<attempt>/replay``, then ``replay-2``...),
with ``replay.json`` holding the validation. Analysis never counts an attempt nested in another.
"""
from __future__ import annotations

import json
import os
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from cab_core.analysis.attempts import Attempt
from cab_core.analysis.failure import Classifier
from cab_core.analysis.measures import claim_category
from cab_core.attempt.engine.checkpoint_scoring import evaluate_attempt
from cab_core.attempt.engine.episode import Episode
from cab_core.attempt.spec import AttemptSpec
from cab_core.errors import AttemptEnded, CabError, RecordError
from cab_core.plugins import task_names

TOLERANCE_M = 0.005
CALL_KINDS = ("call", "internal_call", "call_refused", "host_fault", "tool_fault")  # tool_fault: older records
# terminations the replayed calls decide by themselves; any other (the wall clock, which a replay
# does not reproduce, or a harness's decision) is mirrored once the recorded calls are made
EPISODE_ENDINGS = ("done", "tool_budget", "sim_budget", "no_done", "error")  # error: older records
MAX_LISTED = 25


@dataclass
class Validation:
    """The outcome of comparing a replay's records with the original's."""
    attempt: str
    replay_dir: str  # relative to the attempt directory: records name no machine path
    valid: bool = True
    mismatches: list[str] = field(default_factory=list)
    mismatch_count: int = 0
    calls_compared: int = 0
    snapshots_compared: int = 0
    max_tcp_error_m: float = 0.0
    max_object_error_m: float = 0.0
    original_success: bool | None = None
    replay_success: bool | None = None

    def fail(self, what: str) -> None:
        self.valid = False
        self.mismatch_count += 1
        if len(self.mismatches) < MAX_LISTED:
            self.mismatches.append(what)


class ReplayAgent:
    """Issues recorded direct calls, in order, through an episode's public call path."""

    def __init__(self, calls: list[tuple[str, dict]]):
        self.calls = calls
        self.unplayed = 0

    def run(self, episode) -> None:
        for i, (tool, args) in enumerate(self.calls):
            try:
                episode.call(tool, args)
            except AttemptEnded:
                self.unplayed = len(self.calls) - i
                return


def recorded_calls(events: list[dict]) -> list[tuple[str, dict]]:
    """The agent's direct calls (refused ones included: they end an attempt at its tool budget)."""
    return [(e["tool"], e.get("arguments") or {}) for e in events if e.get("kind") in ("call", "call_refused")]


def _spec(attempt: Attempt, out: Path):
    config = attempt.start_event().get("config")
    if not isinstance(config, dict):
        raise RecordError(f"{attempt.dir}: the records lack the resolved configuration (attempt_start.config); "
                          "attempts recorded before cab stored it cannot be replayed")
    # a fork's records hold its prefix's calls: replaying them all rebuilds its world from the start
    config = {k: v for k, v in config.items() if k != "fork"}
    try:
        spec = AttemptSpec(**config, output_dir=out)
    except TypeError as e:
        raise RecordError(f"attempt_start.config does not match this cab's AttemptSpec: {e}") from e
    spec.record = {**(spec.record or {}), "video": False}  # the video changes no physics
    spec.budget_wall_seconds = 1e9  # wall time is not replayed (no model latency); see EPISODE_ENDINGS
    return spec


def execute(attempt: Attempt, out: Path) -> ReplayAgent:
    """Run the replay episode into ``out``; returns the agent (for calls left unplayed)."""
    spec = _spec(attempt, out)
    if spec.task not in task_names():
        raise RecordError(f"task {spec.task!r} is not installed")
    agent = ReplayAgent(recorded_calls(attempt.events))
    episode = Episode.open(spec, observers=[])  # a replay re-checks the record; the original's observers need not be installed
    try:
        agent.run(episode)
        term = attempt.record.termination
        if not episode.ended and term.reason not in EPISODE_ENDINGS:
            episode.end(term.reason, term.detail or "")
        episode.finish()
    finally:
        episode.close()
    return agent


def _label(e: dict, i: int) -> str:
    return f"{e.get('kind')} {i + 1} ({e.get('tool')})"


def compare_calls(v: Validation, orig: list[dict], new: list[dict]) -> None:
    a = [e for e in orig if e.get("kind") in CALL_KINDS]
    b = [e for e in new if e.get("kind") in CALL_KINDS]
    if len(a) != len(b):
        v.fail(f"{len(a)} calls recorded, {len(b)} in the replay")
    for i, (x, y) in enumerate(zip(a, b)):
        v.calls_compared += 1
        if (x.get("kind"), x.get("tool")) != (y.get("kind"), y.get("tool")):
            v.fail(f"{_label(x, i)}: the replay made {y.get('kind')} {y.get('tool')!r} instead")
            return  # order broken: later pairs are not comparable
        rx, ry = x.get("result") or {}, y.get("result") or {}
        for key, sx, sy in (("status", x.get("status"), y.get("status")), ("program ok", rx.get("ok"), ry.get("ok")),
                            ("physics steps", x.get("physics_steps"), y.get("physics_steps"))):
            if sx != sy:
                v.fail(f"{_label(x, i)}: {key} {sx!r} recorded, {sy!r} in the replay")


def _dist(p, q) -> float:
    return float(np.linalg.norm(np.asarray(p[:3], float) - np.asarray(q[:3], float)))


def compare_snapshots(v: Validation, orig: list[dict], new: list[dict], tol: float) -> None:
    if len(orig) != len(new):
        v.fail(f"{len(orig)} state snapshots recorded, {len(new)} in the replay")
    for i, (x, y) in enumerate(zip(orig, new)):
        v.snapshots_compared += 1
        where = f"snapshot {i} ({x.get('label')})"
        if (x.get("label"), x.get("physics_step")) != (y.get("label"), y.get("physics_step")):
            v.fail(f"{where} at step {x.get('physics_step')}: the replay has {y.get('label')} at step {y.get('physics_step')}")
            continue
        for arm, s in x.get("arms", {}).items():
            d = _dist(s["tcp_pose"], y["arms"][arm]["tcp_pose"])
            v.max_tcp_error_m = max(v.max_tcp_error_m, d)
            if d > tol:
                v.fail(f"{where}: {arm} TCP {1000 * d:.1f} mm from the recorded position")
        for name, s in x.get("objects", {}).items():
            if name not in y.get("objects", {}):
                v.fail(f"{where}: object {name!r} missing in the replay")
                continue
            d = _dist(s["pose"], y["objects"][name]["pose"])
            v.max_object_error_m = max(v.max_object_error_m, d)
            if d > tol:
                v.fail(f"{where}: object {name!r} {1000 * d:.1f} mm from the recorded position")


def validate(original: Attempt, replayed: Attempt, tol: float = TOLERANCE_M) -> Validation:
    """Compare two attempts' records (the original first)."""
    v = Validation(original.rel, os.path.relpath(replayed.dir, original.dir).replace(os.sep, "/"))
    compare_calls(v, original.events, replayed.events)
    compare_snapshots(v, original.snapshots, replayed.snapshots, tol)
    ta, tb = original.record.termination.reason, replayed.record.termination.reason
    if ta != tb:
        v.fail(f"termination {ta!r} recorded, {tb!r} in the replay")
    v.original_success, v.replay_success = original.success, replayed.success
    if original.success != replayed.success:
        v.fail(f"verdict success={original.success} recorded, success={replayed.success} in the replay")
    return v


def next_free(d: Path) -> Path:
    out = d / "replay"
    n = 1
    while out.exists():
        n += 1
        out = d / f"replay-{n}"
    return out


def replay(attempt_dir: Path, out: Path | None = None, tol: float = TOLERANCE_M) -> Validation:
    """Re-execute an attempt and validate it against its records; writes ``replay.json`` in ``out``."""
    original = Attempt.load(Path(attempt_dir))
    out = Path(out) if out is not None else next_free(original.dir)
    agent = execute(original, out)
    v = validate(original, Attempt.load(out), tol)
    if agent.unplayed:
        v.fail(f"the replay ended with {agent.unplayed} recorded call(s) not yet made")
    (out / "replay.json").write_text(json.dumps(asdict(v), indent=1))
    return v


def regrade(attempt_dir: Path) -> dict:
    """Checkpoints, claim correctness and failure stage recomputed from the records alone, each
    beside the recorded value. No simulator runs."""
    a = Attempt.load(Path(attempt_dir))
    ck = evaluate_attempt(a.dir).as_dict()
    recorded = a.result.get("checkpoints") or {}
    changed = [f"{kind} {c['index']}: attained {c['attained']} (recorded "
               f"{(recorded.get(kind) or [{}] * c['index'])[c['index'] - 1].get('attained')})"
               for kind in ("subgoals", "spatial") for c in ck[kind]
               if c["attained"] != ((recorded.get(kind) or [{}] * c["index"])[c["index"] - 1].get("attained"))]
    stage, why = Classifier()(a)
    return {"attempt": str(a.dir), "success": a.success,
            "claim": claim_category(a.record.claim.success_claim, a.success),
            "checkpoints": ck, "checkpoints_changed": changed, "failure_stage": stage, "failure_detail": why}


def main(argv: list[str] | None = None) -> None:
    import argparse

    ap = argparse.ArgumentParser(prog="cab-replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", help="an attempt directory (holding result.json)")
    ap.add_argument("--out", help="where the replay's records go (default: <dir>/replay, replay-2, ...)")
    ap.add_argument("--tolerance-mm", type=float, default=1000 * TOLERANCE_M, help="position tolerance (default 5)")
    ap.add_argument("--regrade", action="store_true", help="recompute checkpoints, claim and failure stage; no simulator")
    a = ap.parse_args(argv)
    try:
        if a.regrade:
            g = regrade(Path(a.dir))
            print(json.dumps({k: v for k, v in g.items() if k != "checkpoints"}, indent=1))
            return
        v = replay(Path(a.dir), Path(a.out) if a.out else None, a.tolerance_mm / 1000)
    except CabError as e:
        print(f"cab-replay: {e}", file=sys.stderr)
        sys.exit(2)
    print(f"cab-replay: {'VALID' if v.valid else 'INVALID'}: {v.calls_compared} calls and {v.snapshots_compared} "
          f"snapshots compared; max TCP error {1000 * v.max_tcp_error_m:.2f} mm, max object error "
          f"{1000 * v.max_object_error_m:.2f} mm; success {v.original_success} -> {v.replay_success}")
    for m in v.mismatches:
        print(f"  {m}")
    if v.mismatch_count > len(v.mismatches):
        print(f"  ... and {v.mismatch_count - len(v.mismatches)} more")
    print(f"cab-replay: records and replay.json in {Path(a.dir) / v.replay_dir}")
    sys.exit(0 if v.valid else 1)
