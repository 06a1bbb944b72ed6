"""Conformance checks every task passes on every simulator: at the task's catalog seed its oracle
succeeds within the catalog's budgets and attains every subgoal, the idle agent fails with no
subgoal satisfied at the start, and both verdicts record their margins consistently
(:func:`check_pair`); the task's world is deterministic and its saved states restore
(:func:`check_determinism_and_restore`).

The attempts run as ``cab-suite-check`` runs them (:func:`cab_core.sweep.supervisor.run_batch`: composed by
Hydra as ``cab task=T sim=S model=oracle|idle`` composes them, supervised, in warm workers, ``jobs``
at a time); :func:`run_attempts` runs a batch of ``(task, sim)`` pairs and returns one
:class:`PairResult` per pair, and :func:`check_pair` asserts on it. Outside pytest::

    from cab_core.testing import task_conformance as tc

    for pair, res in tc.run_attempts([("my_task", "my_sim")], jobs=2, out=Path("out")).items():
        tc.check_pair(res)
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from cab_core.attempt.engine.world import BuiltWorld
from cab_core.attempt.spec import attempt_spec
from cab_core.plugins import task_info
from cab_core.sweep.supervisor import attempt_configs, run_batch
from cab_core.tools.context import RobotContext

AGENTS = ("oracle", "idle")


@dataclass
class PairResult:
    """The suite check's rows of one task on one simulator, by agent."""

    task: str
    sim: str
    rows: dict[str, dict] = field(default_factory=dict)


def run_attempts(pairs: list[tuple[str, str]], jobs: int, out: Path) -> dict[tuple[str, str], PairResult]:
    """Run the oracle and the idle agent of every ``(task, sim)`` pair at the task's catalog seed.
    Pairs are grouped so that the tasks shared by several simulators run in one batch."""
    by_sim: dict[str, list[str]] = {}
    for task, sim in pairs:
        if task not in by_sim.setdefault(sim, []):
            by_sim[sim].append(task)
    groups: dict[tuple[str, ...], list[str]] = {}
    for sim, tasks in by_sim.items():
        groups.setdefault(tuple(tasks), []).append(sim)
    results = {(t, s): PairResult(t, s) for t, s in pairs}
    for i, (batch, sims) in enumerate(groups.items()):
        for row in run_batch(list(batch), None, max(1, jobs), Path(out) / f"batch-{i}", AGENTS, tuple(sims)):
            res = results.get((row["task"], row["sim"]))
            if res is not None:
                res.rows[row["agent"]] = row
    return results


def margins_agree(predicates: dict, margins: dict) -> None:
    """Every margin (a record: slack, scale, fraction) belongs to a predicate and has its sign:
    inside its threshold (slack > 0) exactly where the predicate holds."""
    assert set(margins) <= set(predicates), f"margins of no predicate: {sorted(set(margins) - set(predicates))}"
    for k, m in margins.items():
        assert m["scale"] > 0 and math.isfinite(m["slack"]), (k, m)
        assert abs(m["fraction"] - m["slack"] / m["scale"]) < 1e-9, (k, m)
        if m["slack"] != 0:
            assert (m["slack"] > 0) == predicates[k], (k, m, predicates[k])


def recorded_margins_agree(row: dict) -> None:
    """The attempt's verdict records its predicates' margins with their signs, and what decided it;
    an oracle success is decided by a thresholded predicate of its task."""
    verdict = json.loads((Path(row["dir"]) / "result.json").read_text())["verdict"]
    preds = {**verdict["predicates"], **verdict["final_requirements"], **verdict["guard"]}
    if verdict["margins_at"] == "latch":  # the event's predicates all held when it latched
        preds = {**preds, **{k: True for k in verdict["predicates"]}}
    margins_agree(preds, verdict["margins"])  # an idle attempt may have none: no contact, no distance
    d = verdict["margin"]
    assert set(d) == {"predicate", "fraction", "borderline", "threshold"}, d
    if row["agent"] == "oracle":
        assert d["predicate"] in verdict["margins"] and d["fraction"] > 0, (row["task"], d)
        assert row["margin"] == d["fraction"], (row["margin"], d)


def _number(v: float) -> str:
    return f"{v:.4g}"


def _predicate_line(name: str, m: dict | None) -> str:
    """``name false: measured M unit, threshold T unit, margin S unit (F of its tolerance)``; without
    a threshold (an event: a contact exists), ``name false (no threshold)``."""
    if not m:
        return f"{name} false (no threshold)"
    unit = f" {m['unit']}" if m.get("unit") else ""
    parts = []
    if m.get("measured") is not None:
        parts.append(f"measured {_number(m['measured'])}{unit}")
    if m.get("threshold") is not None:
        parts.append(f"threshold {_number(m['threshold'])}{unit}")
    if m.get("slack") is None:  # a measurement that was not a finite number (null in the record)
        parts.append("margin not measured")
    else:
        frac = "" if m.get("fraction") is None else f" ({m['fraction']:+.0%} of its tolerance)"
        parts.append(f"margin {m['slack']:+.4g}{unit}{frac}")
    return f"{name} false: {', '.join(parts)}"


def failing_predicates(verdict: dict) -> str:
    """What made a verdict fail, in one line: each failing predicate (the task's, its final
    requirements, its guard) with its measured value, threshold and margin as the verdict records
    them; a latch task whose event never latched says so first. Empty when no predicate failed."""
    parts = []
    if verdict.get("error"):
        parts.append(f"scoring failed: {verdict['error']}")
    latch = verdict.get("latch") or {}
    if verdict.get("scoring") == "latch" and not latch.get("latched"):
        parts.append("the event never latched")
    margins = verdict.get("margins") or {}
    for group in ("predicates", "final_requirements", "guard"):
        for name, ok in (verdict.get(group) or {}).items():
            if not ok:
                parts.append(_predicate_line(name, margins.get(name)))
    return "; ".join(parts)


def _verdict(row: dict) -> dict:
    try:
        return json.loads((Path(row["dir"]) / "result.json").read_text())["verdict"] or {}
    except (OSError, ValueError, KeyError, TypeError):  # no record to read: the row's own words only
        return {}


def _ran(res: PairResult, agent: str) -> dict:
    row = res.rows.get(agent)
    assert row is not None, f"{res.task} on {res.sim}: the {agent} attempt did not run"
    assert "error" not in row, f"{res.task} on {res.sim}: the {agent} attempt failed: {row['error']}"
    return row


def check_pair(res: PairResult) -> None:
    """The oracle succeeds within budgets with every subgoal attained; the idle agent fails with no
    subgoal satisfied at the start; both record consistent margins."""
    where = f"{res.task} on {res.sim}"
    o = _ran(res, "oracle")
    if not o["success"]:
        why = failing_predicates(_verdict(o))
        raise AssertionError(f"{where}: the oracle failed ({o['termination']})" + (f": {why}" if why else "")
                             + f"; records in {o['dir']}")
    assert o["calls"] <= o["calls_limit"], f"{where}: the oracle used {o['calls']} calls of {o['calls_limit']}"
    assert o["sim_s"] <= o["sim_s_limit"], f"{where}: the oracle used {o['sim_s']} simulated s of {o['sim_s_limit']}"
    assert all(o["subgoals"]), f"{where}: subgoals attained by the oracle: {o['subgoals']}"
    assert not o.get("checkpoint_error"), f"{where}: checkpoints: {o['checkpoint_error']}"
    i = _ran(res, "idle")
    assert not i["success"], f"{where}: the idle agent succeeded; records in {i['dir']}"
    assert not any(i["subgoals_at_start"]), f"{where}: a subgoal holds at the start: {i['subgoals_at_start']}"
    recorded_margins_agree(o)
    recorded_margins_agree(i)


# -- determinism and save/restore on a task's own world ---------------------------------------------

MOTION_STEPS = 250


def _world(task: str, sim: str, out: Path):
    """The world of ``cab task=T sim=S model=idle`` at the task's catalog seed, built as an attempt
    builds it (robot at home, settled), physics only; and a robot context to read it with."""
    [cfg] = attempt_configs([(task, task_info(task).seed, "idle", str(out), sim)], cold=False)
    cfg["sim"] = {**cfg["sim"], "render": False}
    world = BuiltWorld.open(attempt_spec(cfg, out))
    # no step clock and no observation store: the context serves the robot's read-only calls only
    return world, RobotContext(world.sim, world.planner, world.emb, None, None)  # type: ignore[arg-type]


def _drive(w, base, steps: int) -> None:
    """Every arm joint along its own sine about ``base`` (0.15 rad), the grippers closing and
    opening, one target per step."""
    import numpy as np

    order = w.emb.joint_order()
    grip = {j for a in w.emb.arms.values() for j in a.gripper.joints}
    for i in range(steps):
        t = i * w.sim.timestep
        tgt = np.array(base, float)
        for k, j in enumerate(order):
            tgt[k] = base[k] * (0.5 + 0.5 * math.cos(3.0 * t)) if j in grip else base[k] + 0.15 * math.sin(2.0 * t + k)
        w.sim.set_drive_targets(tgt)
        w.sim.step(1)


def _state(w) -> dict:
    import numpy as np

    s = {"qpos": np.asarray(w.sim.get_qpos(), float), "qvel": np.asarray(w.sim.get_qvel(), float)}
    for n in w.sim.object_names():
        s[n] = np.concatenate([w.sim.get_object_pose(n), w.sim.get_object_velocity(n), w.sim.get_object_qpos(n)])
    return s


def check_determinism_and_restore(task: str, sim: str, out: Path) -> None:
    """On the task's world at its catalog seed (:func:`_world`): two builds in one process, each
    saving its state after settling and then moving the arms alike, give identical privileged
    snapshots after settling and after the motion; the saved state restores exactly, and the motion
    replayed from it agrees within 1e-6. (Taking a snapshot may change a backend's next steps, so
    both builds take one.)"""
    import numpy as np

    def run(name: str, replay: bool) -> list[str]:
        w, ctx = _world(task, sim, Path(out) / name)
        try:
            snaps = [json.dumps(w.snapshot(ctx, 0))]
            snap = w.sim.save_state()
            start = _state(w)
            base = w.sim.get_drive_targets().copy()
            _drive(w, base, MOTION_STEPS)
            snaps.append(json.dumps(w.snapshot(ctx, MOTION_STEPS)))
            if not replay:
                return snaps
            moved = _state(w)
            w.sim.restore_state(snap)
            restored = _state(w)
            for k in start:
                assert np.array_equal(start[k], restored[k]), f"{task} on {sim}: {k} differs after restore_state"
            _drive(w, base, MOTION_STEPS)
            replayed = _state(w)
            for k in moved:
                d = float(np.max(np.abs(moved[k] - replayed[k]), initial=0.0))
                assert d <= 1e-6, f"{task} on {sim}: the motion replayed from the saved state differs by {d:g} at {k}"
            return snaps
        finally:
            w.sim.close()

    a = run("a", replay=True)
    b = run("b", replay=False)
    for label, x, y in zip(("after settling", "after the motion"), a, b):
        assert x == y, f"{task} on {sim}: a second build gives another privileged snapshot {label}"
