"""Motion and gripper tools: bounded, guarded, honest about partial motion.

Semantics follow the paper's tool surface (FACTS A.4-A.6): displacement clamp 0.30 m with the
direction preserved; waypoint legs of at most 0.03 m, each re-aimed from the measured TCP while
holding the call-start orientation; a leg budget of 3*ceil(|delta|/leg); stall (progress below
1 mm on two consecutive legs), trajectory deviation and leg-budget aborts; planner refusals as
FAILED with the planner's diagnosis. Categories of non-completion: planner, stall, deviation,
allowance. The agent gets no error figures: it reads ``commanded`` against ``observed_after``.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field

from cab_core.errors import ToolArgumentError
from cab_core.geometry import orientation_block, quat_angle, quat_normalize
from cab_core.tools.models import (
    CONTACT_IMPULSE_THRESHOLD,
    DELTA_LIMIT_M,
    WORKSPACE,
    Args,
    Arm,
    Delta,
    Delta3,
    Direction3,
    ObservationSummary,
    QuatWXYZ,
    Result,
    Vec3,
    bounded,
)
from cab_core.tools.registry import ToolOutput, tool

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.planner import PlanResult
    from cab_core.tools.context import RobotContext

MAX_STEP_M = 0.30
LEG_M = 0.03
REACH_CORRECTION_TRIGGER_M = 0.01
REACH_MAX_CORRECTIONS = 2
REACH_MISS_M = 0.02  # a reach that ends further than this from its target did not complete
STALL_PROGRESS_M = 0.001
LEG_MAX_JOINT_JUMP = 0.6  # rad: a Cartesian leg of <= 3 cm needing more is a configuration switch
JOINT_SPEED = 1.2  # rad/s cap for joint-space interpolation of legs
TCP_SPEED = 0.20  # m/s cap for Cartesian legs
SETTLE_MAX_STEPS = 40
GRIPPER_FULL_STEPS = 200  # 0.8 s for a full open<->close, as upstream

HARNESS_PARAMETERS = {
    "max_step_m": MAX_STEP_M, "contact_leg_m": LEG_M,
    "leg_convergence_tolerance_m": "min(0.005, max(0.002, 0.25*|commanded|))",
    "leg_budget": "3*ceil(|delta|/contact_leg_m)",
    "reach_correction_trigger_m": REACH_CORRECTION_TRIGGER_M, "reach_max_corrections": REACH_MAX_CORRECTIONS,
    "planner_interpolation_dt_s": 1 / 250,
    "trajectory_deviation_rule": "ABORTED if actual_leg > max(0.09, 4*commanded_leg) or lateral > max(0.06, 3*commanded_leg) or remaining distance grows by > max(0.05, 2*commanded_leg)",
    "contact_impulse_threshold_Ns": CONTACT_IMPULSE_THRESHOLD,
    "stall": "progress < 0.001 m on 2 consecutive legs -> ABORTED/stalled",
    "orientation_anchor": True,
    "workspace_envelope": {"x": list(WORKSPACE["x"]), "y": list(WORKSPACE["y"]), "z": list(WORKSPACE["z"])},
    "planner_collision_world": "robot_self only (no table, objects, other arm or held object)",
}


# ---------------------------------------------------------------------------------------------
# robot snapshots and contact evidence (anonymous)
# ---------------------------------------------------------------------------------------------
def _r(a, n=5):
    return [round(float(x), n) for x in np.asarray(a).reshape(-1)]


def arm_contacts(ctx: RobotContext, arm: str) -> dict:
    """Anonymous contact evidence for one arm: which of its parts touch something that is not
    the robot itself, and robot self-contact with the other arm."""
    spec = ctx.arm(arm)
    fingers = {f"robot/{link}" for link in spec.gripper.finger_links}
    own = {f"robot/{link}" for link in spec.links} | fingers
    per_finger: dict[str, float] = {}
    arm_link_impulse = 0.0
    self_impulse = 0.0
    for c in ctx.sim.get_contacts():
        if c.impulse < CONTACT_IMPULSE_THRESHOLD:
            continue
        for mine, other in ((c.a, c.b), (c.b, c.a)):
            if mine not in own:
                continue
            if other.startswith("robot/"):
                if other not in own:
                    self_impulse += c.impulse
                continue
            if mine in fingers:
                k = mine.split("/", 1)[1]
                per_finger[k] = per_finger.get(k, 0.0) + c.impulse
            else:
                arm_link_impulse += c.impulse
    parts = []
    if per_finger:
        parts.append({"part": "fingertip", "arms": [arm]})
    if arm_link_impulse > 0:
        parts.append({"part": "arm_link", "arms": [arm]})
    if self_impulse > 0:
        parts.append({"part": "robot_self", "arms": sorted(ctx.emb.arms)})
    return {"in_contact": bool(parts), "fingers_in_contact": sorted(per_finger),
            "finger_impulse_Ns": {k: round(v, 6) for k, v in sorted(per_finger.items())},
            "contact_parts": parts}


def robot_snapshot(ctx: RobotContext) -> dict:
    out = {}
    for arm in sorted(ctx.emb.arms):
        tcp = ctx.tcp_pose(arm)
        out[arm] = {"tcp_pose": _r(tcp), "orientation": orientation_block(tcp[3:], snapshot=True),
                    "gripper_val": round(ctx.gripper_cmd[arm], 4), "finger_gap_m": round(ctx.finger_gap(arm), 5),
                    "contact": arm_contacts(ctx, arm)}
    return out


# ---------------------------------------------------------------------------------------------
# execution primitives
# ---------------------------------------------------------------------------------------------
def _set_arm_targets(ctx: RobotContext, targets: dict[str, np.ndarray],
                     velocities: dict[str, np.ndarray] | None = None) -> None:
    """Arm joint position (and velocity) targets; every other joint keeps its position target
    and gets a zero velocity target."""
    t = ctx.sim.get_drive_targets().copy()
    v = np.zeros_like(t)
    for arm, q in targets.items():
        idx = ctx.joint_indices(ctx.arm(arm).joints)
        t[idx] = q
        if velocities is not None:
            v[idx] = velocities[arm]
    ctx.sim.set_drive_targets(t, v)


def _execute(ctx: RobotContext, trajs: dict[str, np.ndarray], settle: bool = True) -> int:
    """Stream joint position and velocity targets at one row per physics step (as a planned
    trajectory is executed), then let the arms settle.

    The rows for every driven joint are laid out before the first step (each arm's trajectory,
    its last row held once it has ended, velocity targets from finite differences and zero
    elsewhere; the other joints keep their position targets), so the loop only hands one row a
    step to the simulator."""
    n = max((len(v) for v in trajs.values()), default=0)
    steps0 = ctx.clock.steps
    dt = ctx.sim.timestep
    sim, clock = ctx.sim, ctx.clock
    if n:
        pos = np.repeat(sim.get_drive_targets()[None, :], n, axis=0)
        vel = np.zeros_like(pos)
        for a, tr in trajs.items():
            idx = ctx.joint_indices(ctx.arm(a).joints)
            m = len(tr)
            pos[:m, idx] = tr
            pos[m:, idx] = tr[-1]
            if m > 1:
                vel[:m - 1, idx] = np.diff(tr, axis=0) / dt
        for i in range(n):
            sim.set_drive_targets(pos[i], vel[i])
            clock.step(1)
    if trajs:
        _set_arm_targets(ctx, {a: tr[-1] for a, tr in trajs.items()})
    if settle and trajs:
        idx = np.concatenate([ctx.joint_indices(ctx.arm(a).joints) for a in trajs])
        final = np.concatenate([trajs[a][-1] for a in trajs])
        for _ in range(SETTLE_MAX_STEPS):
            err = float(np.max(np.abs(sim.get_qpos()[idx] - final)))
            vel_now = float(np.max(np.abs(sim.get_qvel())))
            if err < 2e-3 and vel_now < 0.05:
                break
            clock.step(1)
    if ctx.clock.steps > steps0:
        ctx.tick += 1
    return ctx.clock.steps - steps0


def _interp(q0: np.ndarray, q1: np.ndarray, dt: float, min_steps: int = 5, extra_time: float = 0.0) -> np.ndarray:
    d = float(np.max(np.abs(q1 - q0)))
    n = max(min_steps, int(math.ceil(d / (JOINT_SPEED * dt))) + int(extra_time / dt))
    s = np.linspace(0.0, 1.0, n + 1)[1:]
    s = s * s * (3 - 2 * s)  # smoothstep: zero velocity at both ends
    return q0[None, :] + s[:, None] * (q1 - q0)[None, :]


def _workspace_violation(xyz) -> str | None:
    for i, k in enumerate("xyz"):
        lo, hi = WORKSPACE[k]
        if not lo <= xyz[i] <= hi:
            return f"target {k}={xyz[i]:.3f} outside the workspace envelope [{lo}, {hi}]"
    return None


def _planner_block(res) -> dict:
    meaning = {"success": "a trajectory was found", "no_ik": "goal_pose_unreachable: no IK solution for the TCP target",
               "no_path": "IK found but no collision-free path was found", "invalid_start": "the start state is invalid",
               "invalid_goal": "the goal is invalid"}
    return {"code": res.status if res.status != "no_ik" else "goal_pose_unreachable", "status": res.status,
            "meaning": meaning.get(res.status, res.status), "attempts": res.attempts,
            "position_error_m": None if res.position_error_m is None else round(res.position_error_m, 5),
            "rotation_error_rad": None if res.rotation_error_rad is None else round(res.rotation_error_rad, 5),
            "message": res.message[:240]}


class Failure(Result):
    stage: str | None = Field(
        default=None, description="Where it failed, e.g. planner_query, execution, workspace_prefilter.")
    code: str = Field(description="Stable failure code, e.g. goal_pose_unreachable, stalled, RAY_PARALLEL_TO_PLANE.")
    category: str | None = Field(
        default=None, description="planner / stall / deviation / allowance / workspace / contact / other.")
    message: str = Field(default="", description="Short human-readable explanation.")


class Planning(Result):
    status: Literal["NOT_APPLICABLE", "NOT_RUN", "SUCCEEDED", "FAILED", "NOT_REPORTED"] = Field(
        description="Planner outcome.")


class Execution(Result):
    status: Literal["NOT_STARTED", "COMPLETED", "INTERRUPTED", "FAILED", "UNKNOWN"] = Field(
        description="Execution outcome.")
    post_state_observed: bool = Field(description="Whether the robot state was read after execution.")
    state_changed: bool = Field(description="Whether the robot measurably moved.")
    physics_steps: int = Field(description="Physics steps consumed (1/250 s each).")
    partial: bool = Field(default=False, description="Paired calls: one arm executed while the other did not.")


class ActionResult(Result):
    """Result of every motion and gripper tool (and the motion inside capture_motion_pair)."""
    action_id: str = Field(description="Unique id of this action.")
    status: Literal["SUCCESS", "FAILED", "ABORTED"] = Field(
        description="SUCCESS: executed as specified; FAILED: refused or not achieved; ABORTED: stopped by a guard.")
    abort_reason: str | None = Field(
        default=None, description="stalled / trajectory_deviation / leg_budget / arm_lock, when ABORTED.")
    commanded: dict[str, Any] = Field(description="What was asked, after clamping (delta, target, path mode).")
    achieved: dict[str, Any] = Field(
        description="Measured outcome: guard, contact, stall evidence, planner status, mode details.")
    resulting_pose: dict[str, Any] = Field(
        description="Measured TCP pose(s) after the action: {tcp} or {left_tcp, right_tcp}.")
    planning: Planning = Field(description="Planner outcome.")
    execution: Execution = Field(description="Execution outcome.")
    failure: Failure | None = Field(default=None, description="Why it failed or aborted; null on SUCCESS.")
    observed_before: dict[str, Any] = Field(description="Two-arm robot snapshot before the action.")
    observed_after: dict[str, Any] = Field(description="Two-arm robot snapshot after the action.")
    tick: int = Field(description="Actuation tick after the action.")
    call_status: Literal["OK"] = Field(default="OK", description="The call itself was dispatched.")


def _result(ctx: RobotContext, *, action_id: str, status: str, commanded: dict, achieved: dict, before: dict,
            arms: list[str], planning: str, execution: str, steps: int, partial: bool = False,
            failure: dict | None = None, abort_reason: str | None = None) -> ToolOutput:
    after = robot_snapshot(ctx)
    moved = any(np.linalg.norm(np.subtract(after[a]["tcp_pose"][:3], before[a]["tcp_pose"][:3])) > 5e-4 for a in arms)
    if len(arms) == 1:
        resulting = {"tcp": after[arms[0]]["tcp_pose"]}
    else:
        resulting = {f"{a}_tcp": after[a]["tcp_pose"] for a in arms}
    payload = {
        "action_id": action_id, "status": status, "abort_reason": abort_reason,
        "commanded": commanded, "achieved": achieved, "resulting_pose": resulting,
        "planning": {"status": planning},
        "execution": {"status": execution, "post_state_observed": True, "state_changed": bool(moved),
                      "physics_steps": steps, "partial": bool(partial)},
        "failure": failure, "observed_before": before, "observed_after": after,
        "tick": ctx.tick, "call_status": "OK",
    }
    return ToolOutput(payload, [], status=status, physics_steps=steps)


def _fail(stage: str, code: str, category: str, message: str) -> dict:
    return {"stage": stage, "code": code, "category": category, "message": message}


# ---------------------------------------------------------------------------------------------
# Cartesian legs (shared by move_delta, move_both_delta, probe_contact_along, capture_motion_pair)
# ---------------------------------------------------------------------------------------------
def _next_leg(ctx: RobotContext, a: str, st: dict[str, Any], goal: np.ndarray, quat: np.ndarray, tol: float,
              allowed: int, leg_m: float) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, float]] | None:
    """Arm ``a``'s next leg toward ``goal``: its joint trajectory and (TCP at the leg's start, commanded
    step, distance to go), or None when the arm stops here: within ``tol`` of its goal, out of its
    ``allowed`` legs, or without a nearby IK solution (the last two recorded in ``st``)."""
    cur = ctx.tcp_pose(a)[:3]
    rem = goal - cur
    dist = float(np.linalg.norm(rem))
    if dist <= tol:
        return None
    if st["legs"] >= allowed:
        st.update(status="ABORTED", reason="leg_budget",
                  failure=_fail("execution", "leg_budget", "allowance",
                                f"leg budget of {allowed} legs exhausted with {dist:.4f} m to go"))
        return None
    step_vec = rem if dist <= leg_m else rem / dist * leg_m
    target = np.concatenate([cur + step_vec, quat])
    ik = ctx.planner.ik(a, target, ctx.arm_qpos(a))
    if not ik.ok:
        st.update(status="FAILED", reason="planner",
                  failure=_fail("planning", "goal_pose_unreachable", "planner",
                                f"no IK solution for the next leg target {np.round(target[:3], 4).tolist()}"),
                  planner={"code": "goal_pose_unreachable", "meaning": "no IK solution", "message": ik.message[:200]})
        return None
    assert ik.qpos is not None  # the planner contract: an IK result that is ok carries its joint positions
    q0 = ctx.arm_qpos(a)
    jump = float(np.max(np.abs(ik.qpos - q0)))
    if jump > LEG_MAX_JOINT_JUMP:
        # the nearest IK solution is a different arm configuration: a 3 cm leg would swing
        # the arm through the workspace, so refuse before moving
        st.update(status="FAILED", reason="planner",
                  failure=_fail("planning", "ik_discontinuity", "planner",
                                f"the next {float(np.linalg.norm(step_vec)):.3f} m leg needs a {jump:.2f} rad joint "
                                "change (another arm configuration); not executed"),
                  planner={"code": "ik_discontinuity", "meaning": "no nearby IK solution for the next leg",
                           "max_joint_change_rad": round(jump, 3)})
        return None
    tr = _interp(q0, ik.qpos, ctx.sim.timestep, extra_time=float(np.linalg.norm(step_vec)) / TCP_SPEED)
    return tr, (cur.copy(), step_vec, dist)


def _leg_went_well(ctx: RobotContext, a: str, st: dict[str, Any], goal: np.ndarray,
                   leg: tuple[np.ndarray, np.ndarray, float]) -> bool:
    """Whether arm ``a`` goes on after the leg it just executed (TCP at its start, commanded step,
    distance to go before it); when it deviated from its line or stalled, ``st`` records why and False."""
    cur0, step_vec, dist0 = leg
    st["legs"] += 1
    now = ctx.tcp_pose(a)[:3]
    moved = now - cur0
    cmd = float(np.linalg.norm(step_vec))
    along = float(np.dot(moved, step_vec / max(cmd, 1e-9)))
    lateral = float(np.linalg.norm(moved - along * step_vec / max(cmd, 1e-9)))
    dist1 = float(np.linalg.norm(goal - now))
    if (np.linalg.norm(moved) > max(0.09, 4 * cmd) or lateral > max(0.06, 3 * cmd)
            or dist1 - dist0 > max(0.05, 2 * cmd)):
        st.update(status="ABORTED", reason="trajectory_deviation",
                  failure=_fail("execution", "trajectory_deviation", "deviation",
                                f"leg deviated: moved {np.linalg.norm(moved):.4f} m, lateral {lateral:.4f} m"))
        return False
    if along < STALL_PROGRESS_M:
        st["no_progress"] += 1
    else:
        st["no_progress"] = 0
    if st["no_progress"] >= 2:
        contact = arm_contacts(ctx, a)
        st.update(status="ABORTED", reason="stalled",
                  failure=_fail("execution", "stalled", "stall", "progress below 0.001 m on 2 consecutive legs"),
                  blocked_in_contact=contact["in_contact"], contact_parts=contact["contact_parts"],
                  pose_at_contact=_r(ctx.tcp_pose(a)))
        return False
    return True


def _legs(ctx: RobotContext, deltas: dict[str, np.ndarray], *, stop_on_contact_change: str | None = None,
          leg_m: float = LEG_M) -> dict:
    """Move each arm's TCP by its delta in legs of at most ``leg_m``, re-aimed from the measured
    TCP, holding the call-start orientation. Returns per-arm outcome and aggregate evidence."""
    start = {a: ctx.tcp_pose(a) for a in deltas}
    goal = {a: start[a][:3] + d for a, d in deltas.items()}
    quat = {a: start[a][3:] for a in deltas}
    norm = {a: float(np.linalg.norm(d)) for a, d in deltas.items()}
    legs_allowed = {a: max(1, 3 * int(math.ceil(norm[a] / leg_m - 1e-9))) for a in deltas}
    tol = {a: min(0.005, max(0.002, 0.25 * norm[a])) for a in deltas}
    state: dict[str, dict[str, Any]] = {a: {"status": "SUCCESS", "legs": 0, "reason": None, "failure": None,
                                            "no_progress": 0, "planner": None} for a in deltas}
    active = {a for a in deltas if norm[a] > 1e-6}
    steps = 0
    start_contacts = {a: tuple(arm_contacts(ctx, a)["fingers_in_contact"]) for a in deltas}
    transition = None
    while active:
        trajs = {}
        leg_info = {}
        for a in sorted(active):
            leg = _next_leg(ctx, a, state[a], goal[a], quat[a], tol[a], legs_allowed[a], leg_m)
            if leg is None:
                active.discard(a)
                continue
            trajs[a], leg_info[a] = leg
        if not trajs:
            break
        steps += _execute(ctx, trajs)
        for a, info in leg_info.items():
            if not _leg_went_well(ctx, a, state[a], goal[a], info):
                active.discard(a)
                continue
            if stop_on_contact_change == a:
                fingers = tuple(arm_contacts(ctx, a)["fingers_in_contact"])
                if fingers != start_contacts[a]:
                    transition = {"before": list(start_contacts[a]), "after": list(fingers),
                                  "fingers_added": sorted(set(fingers) - set(start_contacts[a])),
                                  "fingers_lost": sorted(set(start_contacts[a]) - set(fingers))}
                    active.discard(a)
    return {"state": state, "steps": steps, "goal": goal, "start": start, "transition": transition,
            "legs_allowed": legs_allowed, "tol": tol}


def _clamp(delta: np.ndarray) -> tuple[np.ndarray, bool]:
    """The displacement with its norm clamped to MAX_STEP_M, direction kept, for any finite input:
    the norm is taken of the delta scaled by its largest component, so it cannot overflow."""
    delta = np.asarray(delta, float)
    if not np.all(np.isfinite(delta)):
        raise ToolArgumentError("bad arguments: displacement must be finite")
    big = float(np.max(np.abs(delta))) if delta.size else 0.0
    if big == 0.0:
        return delta, False
    unit_dir = delta / big
    unit_dir = unit_dir / float(np.linalg.norm(unit_dir))
    if big * float(np.linalg.norm(delta / big)) > MAX_STEP_M:
        return unit_dir * MAX_STEP_M, True
    return delta, False


# ---------------------------------------------------------------------------------------------
# tools
# ---------------------------------------------------------------------------------------------
class MoveDeltaArgs(Args):
    arm: Arm = Field(description="Arm to move.")
    dx: Delta = Field(default=0.0, description="TCP displacement along world +x (robot right), metres.")
    dy: Delta = Field(default=0.0, description="TCP displacement along world +y (forward), metres.")
    dz: Delta = Field(default=0.0, description="TCP displacement along world +z (up), metres.")
    path: Literal["waypoint_legs", "single_plan"] = Field(
        default="waypoint_legs",
        description="'waypoint_legs': guarded legs of at most contact_leg_m (0.03 m), each re-aimed from the "
                    "measured TCP; 'single_plan': one planned trajectory.")


@tool(group="motion", kind="act", result=ActionResult)
def move_delta(ctx: RobotContext, args: MoveDeltaArgs) -> ToolOutput:
    """Moves one arm's TCP by a world-frame displacement (m), holding the call-start orientation. The norm is
    clamped to 0.30 m (direction kept); by default it runs as guarded legs of at most 0.03 m that stop on
    stall or deviation. Returns an ActionResult. Consumes simulated time."""
    arm = args.arm
    ctx.arm(arm)
    raw = np.array([args.dx, args.dy, args.dz], float)
    delta, clamped = _clamp(raw)
    before = robot_snapshot(ctx)
    aid = ctx.next_action_id()
    path = getattr(args, "path", "waypoint_legs") or "waypoint_legs"
    commanded = {"arm": arm, "delta_m": _r(raw), "applied_delta_m": _r(delta), "clamped": clamped, "path": path,
                 "target_tcp_xyz": _r(before[arm]["tcp_pose"][:3] + delta)}
    if np.linalg.norm(delta) < 1e-6:
        return _result(ctx, action_id=aid, status="SUCCESS", commanded=commanded, achieved={"path_mode": path, "note": "zero displacement"},
                       before=before, arms=[arm], planning="NOT_APPLICABLE", execution="NOT_STARTED", steps=0)
    if path == "single_plan":
        target = np.concatenate([np.array(before[arm]["tcp_pose"][:3]) + delta, before[arm]["tcp_pose"][3:]])
        return _plan_and_go(ctx, {arm: target}, aid, commanded, before, corrections=0)
    out = _legs(ctx, {arm: delta})
    st = out["state"][arm]
    achieved = {"path_mode": "waypoint_legs", "legs_executed": st["legs"], "leg_budget": out["legs_allowed"][arm],
                "convergence_tolerance_m": round(out["tol"][arm], 4), "guard": {"stall_progress_m": STALL_PROGRESS_M},
                "contact": arm_contacts(ctx, arm)}
    for k in ("blocked_in_contact", "contact_parts", "pose_at_contact"):
        if k in st:
            achieved[k] = st[k]
    if st["planner"]:
        achieved["planner_status"] = st["planner"]
    planning = "FAILED" if st["status"] == "FAILED" else "SUCCEEDED"
    execution = "COMPLETED" if st["status"] == "SUCCESS" else ("INTERRUPTED" if st["status"] == "ABORTED" else
                                                                ("FAILED" if st["legs"] == 0 else "INTERRUPTED"))
    return _result(ctx, action_id=aid, status=st["status"], commanded=commanded, achieved=achieved, before=before,
                   arms=[arm], planning=planning, execution=execution, steps=out["steps"],
                   partial=st["status"] != "SUCCESS" and st["legs"] > 0, failure=st["failure"],
                   abort_reason=st["reason"] if st["status"] == "ABORTED" else None)


class MoveBothDeltaArgs(Args):
    left_delta: Delta3 = Field(description="Left TCP displacement [dx, dy, dz], world metres.")
    right_delta: Delta3 = Field(description="Right TCP displacement [dx, dy, dz], world metres.")


@tool(group="motion", kind="act", result=ActionResult)
def move_both_delta(ctx: RobotContext, args: MoveBothDeltaArgs) -> ToolOutput:
    """Moves both TCPs by world-frame displacements (m) together. A FAILED result may still mean one arm moved
    (execution.partial). Returns an ActionResult with a sync block. Consumes simulated time."""
    deltas = {}
    commanded: dict[str, Any] = {}
    before = robot_snapshot(ctx)
    for arm, raw in (("left", args.left_delta), ("right", args.right_delta)):
        d, clamped = _clamp(np.array(raw, float))
        deltas[arm] = d
        commanded[arm] = {"delta_m": _r(raw), "applied_delta_m": _r(d), "clamped": clamped,
                          "target_tcp_xyz": _r(np.array(before[arm]["tcp_pose"][:3]) + d)}
    aid = ctx.next_action_id()
    out = _legs(ctx, deltas)
    statuses = {a: out["state"][a]["status"] for a in deltas}
    status = "ABORTED" if "ABORTED" in statuses.values() else ("FAILED" if "FAILED" in statuses.values() else "SUCCESS")
    failed = [a for a, s in statuses.items() if s != "SUCCESS"]
    stalled = [a for a in deltas if out["state"][a]["reason"] == "stalled"]
    achieved = {"path_mode": "waypoint_legs", "sync": {"mode": "paired_legs", "plan_success": not any(out["state"][a]["status"] == "FAILED" for a in deltas),
                                                       "planner_status": {a: out["state"][a]["planner"] for a in deltas},
                                                       "planner_status_available": True, "failed_arm": failed or None},
                "stalled_arms": stalled, "legs_executed": {a: out["state"][a]["legs"] for a in deltas},
                "per_arm_status": statuses}
    failure = next((out["state"][a]["failure"] for a in failed), None)
    reason = next((out["state"][a]["reason"] for a in failed if out["state"][a]["status"] == "ABORTED"), None)
    partial = bool(failed) and any(out["state"][a]["legs"] > 0 for a in deltas)
    return _result(ctx, action_id=aid, status=status, commanded=commanded, achieved=achieved, before=before,
                   arms=["left", "right"], planning="FAILED" if any(s == "FAILED" for s in statuses.values()) else "SUCCEEDED",
                   execution="COMPLETED" if status == "SUCCESS" else "INTERRUPTED", steps=out["steps"], partial=partial,
                   failure=failure, abort_reason=reason)


def _target_pose(ctx: RobotContext, arm: str, xyz, quat) -> np.ndarray:
    xyz = np.asarray(xyz, float)
    if quat is None:
        q = ctx.tcp_pose(arm)[3:]
    else:
        q = quat_normalize(np.asarray(quat, float))
    return np.concatenate([xyz, q])


def _planned(plan: PlanResult) -> np.ndarray:
    """The joint trajectory of a plan that succeeded (the planner contract: such a plan carries its positions)."""
    assert plan.positions is not None, f"a plan with status {plan.status!r} carries no positions"
    return plan.positions


def _plan_and_go(ctx: RobotContext, targets: dict[str, np.ndarray], aid: str, commanded: dict, before: dict,
                 corrections: int = REACH_MAX_CORRECTIONS) -> ToolOutput:
    arms = sorted(targets)
    for a in arms:
        v = _workspace_violation(targets[a][:3])
        if v:
            return _result(ctx, action_id=aid, status="FAILED", commanded=commanded,
                           achieved={"stage": "workspace_prefilter", "arm": a}, before=before, arms=arms,
                           planning="NOT_RUN", execution="NOT_STARTED", steps=0,
                           failure=_fail("workspace_prefilter", "target_outside_workspace", "allowance", v))
    plans = {a: ctx.planner.plan_to_pose(a, ctx.arm_qpos(a), targets[a]) for a in arms}
    ok = [a for a in arms if plans[a].ok]
    bad = [a for a in arms if not plans[a].ok]
    steps = _execute(ctx, {a: _planned(plans[a]) for a in ok}) if ok else 0
    n_corr = 0
    for _ in range(corrections):
        resid = {a: float(np.linalg.norm(ctx.tcp_pose(a)[:3] - targets[a][:3])) for a in ok}
        need = [a for a in ok if resid[a] >= REACH_CORRECTION_TRIGGER_M]
        if not need:
            break
        n_corr += 1
        corr = {}
        for a in need:
            p = ctx.planner.plan_to_pose(a, ctx.arm_qpos(a), targets[a])
            if p.ok:
                corr[a] = _planned(p)
        if not corr:
            break
        steps += _execute(ctx, corr)
    residual = {a: float(np.linalg.norm(ctx.tcp_pose(a)[:3] - targets[a][:3])) for a in ok}
    achieved = {"planner_status": {a: _planner_block(plans[a]) for a in arms}, "correction_plans": n_corr,
                "quat_mode": commanded.get("quat_mode"), "contact": {a: arm_contacts(ctx, a) for a in arms}}
    if bad:
        code = plans[bad[0]].status
        failure = _fail("planning", "goal_pose_unreachable" if code == "no_ik" else f"planner_{code}", "planner",
                        f"planner refused for {', '.join(bad)}: {_planner_block(plans[bad[0]])['meaning']}")
        return _result(ctx, action_id=aid, status="FAILED", commanded=commanded, achieved=achieved, before=before,
                       arms=arms, planning="FAILED", execution="COMPLETED" if ok else "NOT_STARTED", steps=steps,
                       partial=bool(ok), failure=failure)
    short = [a for a in ok if residual[a] > REACH_MISS_M]
    if short:
        contact = {a: arm_contacts(ctx, a) for a in short}
        blocked = any(c["in_contact"] for c in contact.values())
        failure = _fail("execution", "stalled" if blocked else "target_not_reached", "stall" if blocked else "deviation",
                        f"{', '.join(short)} stopped short of the target after {n_corr} correction plan(s)"
                        + (" while in contact" if blocked else ""))
        return _result(ctx, action_id=aid, status="ABORTED", commanded=commanded, achieved=achieved, before=before,
                       arms=arms, planning="SUCCEEDED", execution="INTERRUPTED", steps=steps, partial=True,
                       failure=failure, abort_reason="stalled" if blocked else "trajectory_deviation")
    return _result(ctx, action_id=aid, status="SUCCESS", commanded=commanded, achieved=achieved, before=before,
                   arms=arms, planning="SUCCEEDED", execution="COMPLETED", steps=steps)


class ReachTcpArgs(Args):
    arm: Arm = Field(description="Arm to move.")
    target_xyz: Vec3 = Field(
        description="Target TCP position, world metres (workspace x, y in [-0.8, 0.8], z in [0.4, 1.5]).")
    target_quat: QuatWXYZ | None = Field(
        default=None,
        description="Target TCP orientation, world quaternion [w, x, y, z]; default keeps the call-start one.")


@tool(group="motion", kind="act", result=ActionResult)
def reach_tcp(ctx: RobotContext, args: ReachTcpArgs) -> ToolOutput:
    """Moves one arm's TCP to an absolute world position (m) and optional orientation (wxyz; default keeps the
    call-start orientation): one full plan, then a guarded waypoint fallback and up to 2 correction plans.
    Returns an ActionResult; compare commanded with observed_after. Consumes simulated time."""
    arm = args.arm
    ctx.arm(arm)
    before = robot_snapshot(ctx)
    target = _target_pose(ctx, arm, args.target_xyz, args.target_quat)
    commanded = {"arm": arm, "target_xyz": _r(target[:3]), "target_quat": _r(target[3:]),
                 "quat_mode": "explicit" if args.target_quat is not None else "hold_call_start"}
    return _plan_and_go(ctx, {arm: target}, ctx.next_action_id(), commanded, before)


class ReachBothTcpArgs(Args):
    left_xyz: Vec3 = Field(description="Left arm target TCP position, world metres.")
    right_xyz: Vec3 = Field(description="Right arm target TCP position, world metres.")
    left_quat: QuatWXYZ | None = Field(
        default=None, description="Left target orientation [w, x, y, z]; default keeps the current one.")
    right_quat: QuatWXYZ | None = Field(
        default=None, description="Right target orientation [w, x, y, z]; default keeps the current one.")


@tool(group="motion", kind="act", result=ActionResult)
def reach_both_tcp(ctx: RobotContext, args: ReachBothTcpArgs) -> ToolOutput:
    """Moves both TCPs to absolute world positions (m) with optional orientations, planned and executed
    together. A FAILED result may still mean one arm moved (execution.partial). Consumes simulated time."""
    before = robot_snapshot(ctx)
    targets = {"left": _target_pose(ctx, "left", args.left_xyz, args.left_quat),
               "right": _target_pose(ctx, "right", args.right_xyz, args.right_quat)}
    commanded = {a: {"target_xyz": _r(t[:3]), "target_quat": _r(t[3:])} for a, t in targets.items()}
    commanded["quat_mode"] = {"left": "explicit" if args.left_quat is not None else "hold_call_start",
                              "right": "explicit" if args.right_quat is not None else "hold_call_start"}
    return _plan_and_go(ctx, targets, ctx.next_action_id(), commanded, before)


class ProbeContactAlongArgs(Args):
    arm: Arm = Field(description="Arm to move.")
    direction_xyz: Direction3 = Field(description="World direction of travel (non-zero; normalised internally).")
    distance_m: Annotated[float, bounded(0.0, DELTA_LIMIT_M, lo_open=True)] = Field(
        description="Maximum travel, metres (> 0; clamped to 0.30).")
    step_m: Annotated[float, bounded(0.002, DELTA_LIMIT_M)] = Field(
        description="Step between contact checks, metres (>= 0.002; clamped to 0.03).")


@tool(group="motion", kind="act", result=ActionResult)
def probe_contact_along(ctx: RobotContext, args: ProbeContactAlongArgs) -> ToolOutput:
    """Moves one arm's TCP along a world direction in small steps until the set of fingers in contact changes or
    the distance is used up (distance clamped to 0.30 m, step to 0.03 m). SUCCESS means only that contact
    changed; the result reports the stop reason, transition and finger poses. Consumes simulated time."""
    arm = args.arm
    ctx.arm(arm)
    d = np.asarray(args.direction_xyz, float)
    n = float(np.linalg.norm(d))
    if n < 1e-9 or not np.isfinite(n):
        raise ToolArgumentError("bad arguments: direction_xyz must be a non-zero finite vector")
    unit = d / n
    dist = min(float(args.distance_m), MAX_STEP_M)
    step = min(max(float(args.step_m), 0.002), LEG_M)
    before = robot_snapshot(ctx)
    aid = ctx.next_action_id()
    out = _legs(ctx, {arm: unit * dist}, stop_on_contact_change=arm, leg_m=step)
    st = out["state"][arm]
    tr = out["transition"]
    travelled = float(np.linalg.norm(ctx.tcp_pose(arm)[:3] - out["start"][arm][:3]))
    end_contact = arm_contacts(ctx, arm)
    achieved = {"direction_unit_world": _r(unit, 4), "travel_budget_m": round(dist, 4), "effective_step_m": round(step, 4),
                "travelled_m": round(travelled, 4), "guard": {"stall_progress_m": STALL_PROGRESS_M},
                "start_contact": before[arm]["contact"], "end_contact": end_contact,
                "transition": tr, "fingers_added": tr["fingers_added"] if tr else [],
                "fingers_lost": tr["fingers_lost"] if tr else []}
    if tr:
        status, reason, failure = "SUCCESS", None, None
        achieved["stop_reason"] = "contact_set_changed"
    elif st["status"] == "SUCCESS":
        status, reason = "FAILED", None
        failure = _fail("execution", "no_contact_change", "allowance", "no change of the contacting-finger set within the probe distance")
        achieved["stop_reason"] = "travel_budget_spent"
    else:
        status, reason, failure = st["status"], st["reason"] if st["status"] == "ABORTED" else None, st["failure"]
        achieved["stop_reason"] = st["reason"]
        for k in ("blocked_in_contact", "contact_parts", "pose_at_contact"):
            if k in st:
                achieved[k] = st[k]
    return _result(ctx, action_id=aid, status=status, commanded={"arm": arm, "direction_xyz": _r(d), "distance_m": args.distance_m,
                                                                 "step_m": args.step_m},
                   achieved=achieved, before=before, arms=[arm], planning="SUCCEEDED" if st["status"] != "FAILED" else "FAILED",
                   execution="COMPLETED" if status == "SUCCESS" or st["status"] == "SUCCESS" else "INTERRUPTED",
                   steps=out["steps"], partial=False, failure=failure, abort_reason=reason)


class SetGripperArgs(Args):
    arm: Arm = Field(description="Arm whose gripper to actuate.")
    pos: Annotated[float, bounded(0.0, 1.0)] = Field(
        description="Normalised opening command: 1 = fully open, 0 = fully closed.")


@tool(group="motion", kind="act", result=ActionResult)
def set_gripper(ctx: RobotContext, args: SetGripperArgs) -> ToolOutput:
    """Drives one gripper to a normalised opening (1 = open, 0 = closed) over about 0.8 s. SUCCESS means the
    actuation completed, not that something is held: read finger_gap_m and contact in the result. Consumes
    simulated time."""
    arm = args.arm
    spec = ctx.arm(arm)
    pos = float(args.pos)
    g = spec.gripper
    before = robot_snapshot(ctx)
    aid = ctx.next_action_id()
    old = ctx.gripper_cmd[arm]
    ctx.gripper_cmd[arm] = pos
    idx = ctx.joint_indices(g.joints)
    t0 = ctx.sim.get_drive_targets()[idx].copy()
    t1 = np.full(len(idx), g.closed_target + pos * (g.open_target - g.closed_target))
    n = max(50, int(math.ceil(GRIPPER_FULL_STEPS * abs(pos - old))))
    steps0 = ctx.clock.steps
    for i in range(1, n + 1):
        t = ctx.sim.get_drive_targets().copy()
        t[idx] = t0 + (t1 - t0) * (i / n)
        ctx.sim.set_drive_targets(t)
        ctx.clock.step(1)
    for _ in range(25):
        ctx.clock.step(1)
    ctx.tick += 1
    steps = ctx.clock.steps - steps0
    gap = ctx.finger_gap(arm)
    achieved = {"gripper_val": round(pos, 4), "drive_error": round(float(np.max(np.abs(ctx.finger_qpos(arm) - t1))), 5),
                "opening_m": round(pos * g.max_opening_m, 4), "finger_gap_m": round(gap, 5),
                "finger_gap_minus_empty_close_m": round(gap - g.empty_close_gap_m, 5),
                "empty_close_finger_gap_m": g.empty_close_gap_m, "drive_commanded_closed": pos < 0.2,
                "contact": arm_contacts(ctx, arm),
                "note": "SUCCESS means the actuation completed; it is not evidence of a grasp"}
    return _result(ctx, action_id=aid, status="SUCCESS", commanded={"arm": arm, "pos": pos}, achieved=achieved,
                   before=before, arms=[arm], planning="NOT_APPLICABLE", execution="COMPLETED", steps=steps)


class CheckTcpPoseReachabilityArgs(Args):
    arm: Arm = Field(description="Arm to plan for.")
    target_xyz: Vec3 = Field(description="Target TCP position, world metres.")
    target_quat: QuatWXYZ | None = Field(
        default=None,
        description="Target TCP orientation, world quaternion [w, x, y, z]; default keeps the current one.")


@tool(group="geometry", kind="plan")
def check_tcp_pose_reachability(ctx: RobotContext, args: CheckTcpPoseReachabilityArgs) -> ToolOutput:
    """Asks the motion planner for a trajectory from the current arm configuration to a TCP pose without moving:
    whether one was found, planner status and diagnostics. Only robot self-collision is modelled (no table,
    objects or other arm)."""
    arm = args.arm
    ctx.arm(arm)
    target = _target_pose(ctx, arm, args.target_xyz, args.target_quat)
    base = {"arm": arm, "target_xyz": _r(target[:3]), "target_quat": _r(target[3:]),
            "quat_mode": "explicit" if args.target_quat is not None else "keep_current",
            "interpolation_dt_s": ctx.sim.timestep, "state_unchanged": True, "tick": ctx.tick,
            "note": "self-collision only: the planner world has no table, objects, other arm or held object"}
    v = _workspace_violation(target[:3])
    if v:
        return ToolOutput({**base, "planner_found_trajectory": False, "planner_status": "REJECTED",
                           "trajectory_sample_count": 0, "planner_diagnostic": None, "stage": "workspace_prefilter",
                           "reason": v})
    try:
        res = ctx.planner.plan_to_pose(arm, ctx.arm_qpos(arm), target)
    except Exception as e:  # the planner itself failed
        return ToolOutput({**base, "planner_found_trajectory": False, "planner_status": "EXCEPTION",
                           "trajectory_sample_count": 0, "planner_diagnostic": None, "stage": "planner_exception",
                           "reason": str(e)[:240]})
    return ToolOutput({**base, "planner_found_trajectory": res.ok, "planner_status": "SUCCESS" if res.ok else "FAILED",
                       "trajectory_sample_count": 0 if res.positions is None else int(len(res.positions)),
                       "planner_diagnostic": {**_planner_block(res), "valid_query": res.status != "invalid_start"},
                       "stage": "planner_query", "reason": _planner_block(res)["meaning"]})


class PairValidity(Result):
    motion_succeeded: bool = Field(description="The guarded motion returned SUCCESS.")
    baseline_nonzero: bool = Field(description="The wrist camera actually moved (baseline above ~1 mm).")
    contact_free: bool = Field(description="No finger or arm contact before, during or after the motion.")


class ObservationPair(Result):
    """Result of capture_motion_pair. The host keeps ``ctx.pairs[pair_id] = {"before": obs_id,
    "after": obs_id, "valid": {motion_succeeded, baseline_nonzero, contact_free}}`` for
    triangulate_correspondence."""
    pair_id: str = Field(description="Pass to triangulate_correspondence.")
    before: ObservationSummary = Field(description="Wrist observation before the motion.")
    after: ObservationSummary = Field(description="Wrist observation after the motion.")
    motion: ActionResult = Field(description="The guarded motion between the two images.")
    camera_delta_world_m: list[float] = Field(description="Measured camera translation [dx, dy, dz], world m.")
    camera_baseline_m: float = Field(description="Norm of the camera translation, m.")
    camera_rotation_deg: float = Field(description="Camera rotation between the images, degrees.")
    contact_evidence: dict[str, Any] = Field(
        description="{contact_free, scope, before, after, motion_abort_reason}: anonymous contact around the motion.")
    validity: PairValidity = Field(description="Preconditions for a triangulation from this pair.")
    obs_ids: list[str] = Field(description="[before, after] obs_ids.")
    images: list[str] = Field(description="obs_ids whose images are attached.")


class CaptureMotionPairArgs(Args):
    arm: Arm = Field(description="Arm to move; its wrist camera takes the before/after images.")
    dx: Delta = Field(description="World-frame displacement along +x (robot right), metres.")
    dy: Delta = Field(description="World-frame displacement along +y (forward), metres.")
    dz: Delta = Field(description="World-frame displacement along +z (up), metres.")


@tool(group="geometry", kind="act", result=ObservationPair, renders=True)
def capture_motion_pair(ctx: RobotContext, args: CaptureMotionPairArgs) -> ToolOutput:
    """Moves one arm by a small world-frame displacement (dx, dy, dz in m) as a real guarded motion, capturing
    its wrist RGB before and after. Returns both observations, the motion's ActionResult, the measured camera
    translation and rotation, contact evidence and validity flags, and a pair_id for
    triangulate_correspondence. Consumes simulated time."""
    from types import SimpleNamespace

    arm = args.arm
    ctx.arm(arm)
    cam = f"{arm}_camera"
    obs_before = ctx.capture(cam)
    pose0 = ctx.sim.camera_pose(cam)
    contact0 = arm_contacts(ctx, arm)
    motion = move_delta(ctx, SimpleNamespace(arm=arm, dx=args.dx, dy=args.dy, dz=args.dz, path="waypoint_legs"))
    obs_after = ctx.capture(cam)
    pose1 = ctx.sim.camera_pose(cam)
    contact1 = arm_contacts(ctx, arm)
    delta = pose1[:3] - pose0[:3]
    rot = math.degrees(quat_angle(pose0[3:], pose1[3:]))
    pid = ctx.next_pair_id()
    validity = {"motion_succeeded": motion.status == "SUCCESS", "baseline_nonzero": bool(np.linalg.norm(delta) > 1e-3),
                "contact_free": not contact0["in_contact"] and not contact1["in_contact"]}
    ctx.pairs[pid] = {"before": obs_before.obs_id, "after": obs_after.obs_id, "camera": cam, "valid": validity}
    payload = {"pair_id": pid, "before": obs_before.summary(), "after": obs_after.summary(), "motion": motion.payload,
               "camera_delta_world_m": _r(delta), "camera_baseline_m": round(float(np.linalg.norm(delta)), 5),
               "camera_rotation_deg": round(rot, 3),
               "contact_evidence": {"contact_free": validity["contact_free"], "scope": f"{arm} arm, anonymous",
                                    "before": contact0, "after": contact1,
                                    "motion_abort_reason": motion.payload.get("abort_reason")},
               "validity": validity, "obs_ids": [obs_before.obs_id, obs_after.obs_id],
               "images": [obs_before.obs_id, obs_after.obs_id]}
    return ToolOutput(payload, [obs_before.obs_id, obs_after.obs_id], status=motion.status, physics_steps=motion.physics_steps)

