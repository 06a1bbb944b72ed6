"""Observation and feedback tools: world conventions, embodiment card, camera calibration, arm and
gripper readback, anonymous finger contact, and RGB captures.

Nothing here reads object state. Contact feedback names only the robot's own finger links.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from cab_core.contracts.simulator import ROBOT
from cab_core.errors import SimulatorError
from cab_core.geometry import orientation_block, pose_block, rnd
from cab_core.tools.models import (
    CAMERAS,
    CONTACT_IMPULSE_THRESHOLD,
    WORKSPACE,
    Args,
    Arm,
    CameraName,
    EvidenceView,
    ObservationSummary,
    Result,
)
from cab_core.tools.registry import ToolOutput, observation_output, tool

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.tools.context import Observation, RobotContext
    from cab_core.tools.overlay import Canvas

DRIVE_CLOSED_BELOW = 0.2  # commanded value below which the drive counts as "commanded closed"
_CONVENTION = ("E = [R|t] maps world to camera (p_cam = R p_world + t); camera +x right, +y down, +z forward; "
               "K pinhole, pixels, no distortion")
_VIEW_CAMERA = {"overview": "head_camera", "left_wrist": "left_camera", "right_wrist": "right_camera"}


def _param(ctx: RobotContext, key: str, default: float) -> float:
    return float(ctx.params.get(key, default))


# ==============================================================================================
# get_world_frame
# ==============================================================================================
class GetWorldFrameArgs(Args):
    """No arguments."""


@tool(group="observation", kind="read", result=ObservationSummary, renders=True)
def get_world_frame(ctx: RobotContext, args: GetWorldFrameArgs) -> ToolOutput:
    """Captures a fresh head-camera image with a display-only legend glyph in a screen corner and returns the
    world conventions: +x robot-right (left arm at -x, right arm at +x), +y forward away from the robot, +z
    up, metres, seconds, radians, wxyz quaternions, pixel convention. The legend is a schematic: it gives no
    pixel-to-world correspondence."""
    def paint(c: Canvas, K, E) -> dict:
        box = c.world_frame_legend("bottom_left")
        return {
            "tool": "get_world_frame",
            "axes": {"+x": "robot right (the left arm is at -x, the right arm at +x)",
                     "+y": "forward, away from the robot",
                     "+z": "up (gravity is -z)"},
            "handedness": "right-handed",
            "origin": "fixed to the scene; metres",
            "units": {"length": "m", "time": "s", "angle": "rad unless a tool says deg",
                      "contact_impulse": "N*s", "pixels": "px"},
            "pose_format": "[x, y, z, qw, qx, qy, qz] (quaternion w first)",
            "gripper_axes": "+x approach (wrist toward fingertips), +y finger-opening line, +z completes",
            "pixel_convention": "[u, v]: top-left origin, zero-based, u right, v down, in each observation's own image",
            "camera_convention": _CONVENTION,
            "legend": {"corner": "bottom_left", "bbox_px": box, "display_only": True,
                       "note": "a schematic glyph: it does not show where the world axes project in this image"},
            "visibility": {"legend_drawn": True, "world_axes_projected": False},
        }

    obs = ctx.capture_annotated("head_camera", paint)
    return observation_output(obs)


# ==============================================================================================
# get_embodiment
# ==============================================================================================
def _arm_side(ctx: RobotContext, name: str) -> str:
    try:
        x = float(ctx.sim.get_link_pose(ctx.arm(name).base_link)[0])
        return "-x (robot's left)" if x < 0 else "+x (robot's right)"
    except SimulatorError:
        return "-x (robot's left)" if name == "left" else "+x (robot's right)"


def _camera_card(ctx: RobotContext) -> dict:
    mounted = {c.name for c in ctx.emb.cameras if c.mount_link} or {"left_camera", "right_camera"}
    out = {}
    for cam in CAMERAS:
        try:
            h, w = ctx.sim.camera_size(cam)
            size = [int(h), int(w)]
        except SimulatorError:
            size = None
        if cam == "head_camera":
            desc = "fixed RGB camera above and behind the robot, looking forward and down at the workspace"
        else:
            side = cam.split("_")[0]
            desc = f"RGB camera on the {side} wrist; it moves and turns with the {side} arm"
        out[cam] = {"description": desc, "moves_with_arm": cam in mounted,
                    "size_hw": size, "depth": False,
                    "calibration": "get_camera_info or any observation's cam_pose_snapshot"}
    return out


def _merge(dst: dict, src: dict) -> None:
    """Fold the embodiment's declared facts into the card: dicts merge, a plain value given for a
    section becomes that section's ``description``, anything else replaces."""
    for k, v in src.items():
        if isinstance(dst.get(k), dict):
            if isinstance(v, dict):
                _merge(dst[k], v)
            else:
                dst[k]["description"] = v
        else:
            dst[k] = v


class GetEmbodimentArgs(Args):
    """No arguments."""


@tool(group="observation", kind="read")
def get_embodiment(ctx: RobotContext, args: GetEmbodimentArgs) -> ToolOutput:
    """Describes the robot: arms and their sides, gripper geometry (max opening 0.08 m, finger-gap range,
    empty-close gap), the TCP convention (nominal grasp centre; flange behind it along the approach axis,
    fingertip plane ahead), gripper-local axes (+x approach, +y opening line), cameras (qualitatively),
    reachability notes and motion limits (max single displacement 0.30 m, guarded leg 0.03 m). No scene facts
    and no preferred grasp."""
    emb = ctx.emb
    g = next(iter(emb.arms.values())).gripper
    arms = {}
    for name, arm in emb.arms.items():
        arms[name] = {"side": _arm_side(ctx, name), "dof": len(arm.joints), "gripper": "parallel two-finger",
                      "wrist_camera": f"{name}_camera", "finger_links": list(arm.gripper.finger_links)}
    card: dict[str, Any] = {
        "embodiment": emb.name,
        "arms": arms,
        "gripper": {
            "command": "gripper value in [0, 1]: 1.0 = fully open, 0.0 = closed (set_gripper pos)",
            "max_opening_m": g.max_opening_m,
            "opening_m_meaning": "gripper value x max_opening_m (tracks the command)",
            "finger_gap_range_m": [0.048, 0.142],
            "finger_gap_meaning": "distance between the two finger-link origins (physical FK)",
            "empty_close_finger_gap_m": g.empty_close_gap_m,
            "fingertip_plane_ahead_of_tcp_m": g.tip_ahead_of_tcp_m,
            "closed_threshold": DRIVE_CLOSED_BELOW,
            "actuation_time_s": 0.8,
        },
        "tcp": {
            "definition": "nominal grasp centre between the fingers",
            "flange_to_tcp_m": emb.tcp_offset_m,
            "local_axes": {"+x": "approach (from the wrist toward the fingertips)", "+y": "finger-opening line",
                           "+z": "completes a right-handed frame"},
        },
        "frame": {"axes": "+x robot-right, +y forward (away from the robot), +z up", "units": "metres"},
        "orientation": {"quaternion": "wxyz", "pose": "[x, y, z, qw, qx, qy, qz]",
                        "tool": "grasp_quat_candidates turns approach/opening axes into quaternions"},
        "cameras": _camera_card(ctx),
        "reachability": {
            "workspace_envelope_m": {k: list(v) for k, v in WORKSPACE.items()},
            "planner_world": "robot self-collision only: no scene geometry or objects, no other arm, no held object",
            "check": "check_tcp_pose_reachability plans without moving",
        },
        "motion": {"max_single_displacement_m": _param(ctx, "max_step_m", 0.30),
                   "contact_leg_m": _param(ctx, "contact_leg_m", 0.03),
                   "orientation_anchor": "relative moves hold the call-start orientation"},
        "units": {"length": "m", "angle": "rad", "time": "s", "contact_impulse": "N*s"},
    }
    _merge(card, dict(emb.facts or {}))
    # the declared limits in force are the host's, whatever the facts say
    card["motion"]["max_single_displacement_m"] = _param(ctx, "max_step_m", 0.30)
    card["motion"]["contact_leg_m"] = _param(ctx, "contact_leg_m", 0.03)
    sides = ", ".join(f"{n} at {a['side']}" for n, a in card["arms"].items() if isinstance(a, dict))
    card["prompt_text"] = (
        f"{card['embodiment']}: arms {sides}, each with a parallel two-finger gripper (max opening "
        f"{card['gripper'].get('max_opening_m')} m). The TCP is the nominal grasp centre; the flange is "
        f"{card['tcp'].get('flange_to_tcp_m')} m behind it along the approach axis (gripper +x) and the fingertip "
        f"plane {card['gripper'].get('fingertip_plane_ahead_of_tcp_m')} m ahead. Gripper +y is the finger-opening "
        f"line. One relative move covers at most {card['motion']['max_single_displacement_m']} m.")
    return ToolOutput(payload=card)


# ==============================================================================================
# get_camera_info
# ==============================================================================================
class GetCameraInfoArgs(Args):
    camera: CameraName = Field(description="Camera to describe: the fixed head camera or a wrist camera.")


@tool(group="observation", kind="read")
def get_camera_info(ctx: RobotContext, args: GetCameraInfoArgs) -> ToolOutput:
    """Returns the current calibration of one camera: 3x3 pinhole K (pixels, no distortion), 3x4 extrinsic E =
    [R|t] mapping world to camera (p_cam = R p_world + t; camera +x right, +y down, +z forward) and image
    size [H, W]. Wrist cameras move with their arm, so E changes after motion. A read failure returns
    available=false with null fields."""
    cam = args.camera
    out: dict[str, Any] = {"camera": cam, "available": True, "K": None, "E": None, "size_hw": None,
                           "freshness": "current", "read_failures": 0, "convention": _CONVENTION, "tick": ctx.tick}
    try:
        out["K"] = rnd(np.asarray(ctx.camera_K(cam), float))
        out["E"] = rnd(np.asarray(ctx.camera_E(cam), float))
        out["size_hw"] = [int(x) for x in ctx.sim.camera_size(cam)]
    except SimulatorError:
        out.update(available=False, K=None, E=None, size_hw=None, read_failures=1)
    out["note"] = ("fixed camera: calibration is constant" if cam == "head_camera" else
                   "wrist camera: E changes whenever the arm moves; each observation carries its own snapshot")
    return ToolOutput(payload=out)


# ==============================================================================================
# arm and gripper readback
# ==============================================================================================
def _arm_pose_block(ctx: RobotContext, arm: str) -> dict:
    try:
        ee, tcp = ctx.ee_pose(arm), ctx.tcp_pose(arm)
        return {"ee_pose": pose_block(ee), "tcp_pose": pose_block(tcp), "orientation": orientation_block(tcp[3:]),
                "read_failures": 0}
    except SimulatorError:
        return {"ee_pose": None, "tcp_pose": None, "orientation": None, "read_failures": 1}


class GetArmPoseArgs(Args):
    arm: Arm = Field(description="Arm to read: 'left' (at -x) or 'right' (at +x).")


@tool(group="observation", kind="read")
def get_arm_pose(ctx: RobotContext, args: GetArmPoseArgs) -> ToolOutput:
    """Measured flange (ee_pose) and TCP pose of one arm, world frame [x,y,z,qw,qx,qy,qz], with an orientation
    block: approach_axis_world (gripper +x), opening_axis_world (gripper +y) and plain-text readings such as
    'approach points down (-z)'."""
    ctx.arm(args.arm)
    out = {"arm": args.arm, **_arm_pose_block(ctx, args.arm), "tick": ctx.tick,
           "note": "measured; tcp_pose is the nominal grasp centre, ee_pose the flange behind it"}
    return ToolOutput(payload=out)


def _gripper_block(ctx: RobotContext, arm: str) -> dict:
    spec = ctx.arm(arm).gripper
    val = float(ctx.gripper_cmd.get(arm, 1.0))
    try:
        gap, fails = rnd(ctx.finger_gap(arm)), 0
    except SimulatorError:
        gap, fails = None, 1
    return {"opening_m": rnd(val * spec.max_opening_m), "finger_gap_m": gap, "gripper_val": rnd(val, 4),
            "drive_commanded_closed": val < DRIVE_CLOSED_BELOW, "read_failures": fails}


class GetGripperStateArgs(Args):
    arm: Arm = Field(description="Arm whose gripper to read: 'left' or 'right'.")


@tool(group="observation", kind="read")
def get_gripper_state(ctx: RobotContext, args: GetGripperStateArgs) -> ToolOutput:
    """Gripper readback of one arm: gripper_val (the last command, 1 = open, 0 = closed), opening_m = command x
    0.08 m, finger_gap_m (physical distance between finger-link origins from forward kinematics, metres) and
    drive_commanded_closed (command < 0.2). A closed command with a gap above the empty-close gap suggests
    something between the fingers."""
    b = _gripper_block(ctx, args.arm)
    empty = ctx.arm(args.arm).gripper.empty_close_gap_m
    out = {"arm": args.arm, **b, "tick": ctx.tick,
           "note": (f"gripper_val and opening_m track the last command; finger_gap_m is measured (FK). A closed command "
                    f"with finger_gap_m well above the empty-close gap ({empty} m) suggests something between the fingers.")}
    return ToolOutput(payload=out)


# ==============================================================================================
# contact
# ==============================================================================================
def _is_robot(name: str) -> bool:
    return name == ROBOT or name.startswith(ROBOT + "/")


def _finger_of(name: str, fingers: tuple[str, ...]) -> str | None:
    for f in fingers:
        if name == f"{ROBOT}/{f}" or name == f:
            return f
    return None


def finger_contacts(ctx: RobotContext, arm: str) -> dict:
    """Anonymous finger<->non-robot contact of one arm during the last physics step."""
    fingers = tuple(ctx.arm(arm).gripper.finger_links)
    per: dict[str, float] = {f: 0.0 for f in fingers}
    pts: dict[str, list] = {f: [] for f in fingers}
    try:
        contacts = ctx.sim.get_contacts()
    except SimulatorError:
        return {"available": False, "read_failures": 1, "per_finger": None, "fingers_in_contact": None,
                "total_impulse": None, "points": None}
    for c in contacts:
        for mine, other in ((c.a, c.b), (c.b, c.a)):
            f = _finger_of(mine, fingers)
            if f is None or _is_robot(other):
                continue  # not this arm's finger, or finger<->robot (self / other arm / finger-finger)
            per[f] += float(abs(c.impulse))
            if c.point is not None:
                pts[f].append((float(abs(c.impulse)), np.asarray(c.point, float)))
    in_contact = [f for f in fingers if per[f] >= CONTACT_IMPULSE_THRESHOLD]
    return {"available": True, "read_failures": 0, "per_finger": per, "fingers_in_contact": in_contact,
            "total_impulse": float(sum(per[f] for f in in_contact)), "points": pts}


def _contact_summary(ctx: RobotContext, arm: str) -> dict:
    c = finger_contacts(ctx, arm)
    return {"available": c["available"], "fingers_in_contact": c["fingers_in_contact"],
            "total_impulse": rnd(c["total_impulse"], 8), "unit": "N*s", "threshold": CONTACT_IMPULSE_THRESHOLD}


class GetGraspContactArgs(Args):
    arm: Arm = Field(description="Arm whose finger contacts to read: 'left' or 'right'.")


@tool(group="observation", kind="read")
def get_grasp_contact(ctx: RobotContext, args: GetGraspContactArgs) -> ToolOutput:
    """Anonymous contact between one arm's fingers and anything that is not the robot, during the last physics
    step: total and per-finger impulse (N*s, threshold 1e-4), fingers_in_contact, and the world pose of each
    contacting finger link. Finger-finger and robot self-contact are excluded; the touched body is never
    named."""
    arm = args.arm
    c = finger_contacts(ctx, arm)
    out: dict[str, Any] = {"available": c["available"], "read_failures": c["read_failures"],
                           "contact_impulse_unit": "N*s", "threshold": CONTACT_IMPULSE_THRESHOLD,
                           "arm": arm, "tick": ctx.tick,
                           "note": ("contact between this arm's fingers and anything that is not the robot, during the "
                                    "last physics step; the touched body is never named. Finger-finger and robot "
                                    "self-contact are excluded.")}
    if not c["available"]:
        out.update(total_impulse=None, fingers_in_contact=None, per_finger=None, contacting_finger_pose=None,
                   contact_localization=None)
        return ToolOutput(payload=out)
    out["total_impulse"] = rnd(c["total_impulse"], 8)
    out["fingers_in_contact"] = c["fingers_in_contact"]
    out["per_finger"] = {f: rnd(v, 8) for f, v in c["per_finger"].items()}
    poses, loc = {}, {}
    link_poses = ctx.finger_link_poses(arm) if c["fingers_in_contact"] else {}
    for f in c["fingers_in_contact"]:
        p = np.asarray(link_poses[f], float)
        poses[f] = {"xyz": rnd(p[:3]), "quat_wxyz": rnd(p[3:]), "axes": orientation_block(p[3:])}
        if c["points"][f]:
            w = np.array([x[0] for x in c["points"][f]])
            q = np.array([x[1] for x in c["points"][f]])
            loc[f] = {"point_world": rnd((w[:, None] * q).sum(0) / max(w.sum(), 1e-12))}
    out["contacting_finger_pose"] = poses
    out["contact_localization"] = {"available": bool(loc), "per_finger": loc,
                                   "note": "impulse-weighted mean contact point on each contacting finger, world m"}
    return ToolOutput(payload=out)


# ==============================================================================================
# get_robot_state
# ==============================================================================================
def _joint_state(ctx: RobotContext, arm: str) -> dict:
    spec = ctx.arm(arm)
    names = list(spec.joints) + list(spec.gripper.joints)
    types = ["revolute"] * len(spec.joints) + ["prismatic"] * len(spec.gripper.joints)
    try:
        all_names = ctx.sim.joint_names
        q, v = np.asarray(ctx.sim.get_qpos(), float), np.asarray(ctx.sim.get_qvel(), float)
        idx = [all_names.index(n) for n in names]
        pos, vel, fails = rnd(q[idx]), rnd(v[idx]), 0
    except (SimulatorError, ValueError):
        pos, vel, fails = None, None, 1
    return {"names": names, "types": types, "positions": pos, "velocities": vel,
            "units": {"revolute": ["rad", "rad/s"], "prismatic": ["m", "m/s"]}, "read_failures": fails}


def _both_arms() -> list[Arm]:
    return ["left", "right"]


class GetRobotStateArgs(Args):
    arms: list[Arm] = Field(
        default_factory=_both_arms, min_length=1, max_length=2,
        description="Arms to include, 1 or 2 distinct names from 'left'/'right'; default both.")

    @model_validator(mode="after")
    def _unique(self):
        if len(set(self.arms)) != len(self.arms):
            raise ValueError("arms must not repeat a name")
        return self


@tool(group="observation", kind="read")
def get_robot_state(ctx: RobotContext, args: GetRobotStateArgs) -> ToolOutput:
    """Combined state of one or both arms: flange and TCP poses with orientation blocks, gripper readback,
    anonymous finger contact summary and joint_state (names, types, positions in rad or m, velocities in
    rad/s or m/s). The only tool that returns joint positions and velocities. World frame: metres, +x
    robot-right, +y forward, +z up; poses [x,y,z,qw,qx,qy,qz]."""
    arms = {}
    for arm in args.arms:
        pose = _arm_pose_block(ctx, arm)
        grip = _gripper_block(ctx, arm)
        arms[arm] = {"ee_pose": pose["ee_pose"], "tcp_pose": pose["tcp_pose"], "orientation": pose["orientation"],
                     **{k: grip[k] for k in ("opening_m", "finger_gap_m", "gripper_val", "drive_commanded_closed")},
                     "contact": _contact_summary(ctx, arm),
                     "read_failures": pose["read_failures"] + grip["read_failures"],
                     "joint_state": _joint_state(ctx, arm)}
    return ToolOutput(payload={
        "tick": ctx.tick, "frame": "world: +x robot right, +y forward, +z up",
        "pose_format": "[x, y, z, qw, qx, qy, qz]", "linear_unit": "m", "angular_unit": "rad",
        "contact_impulse_unit": "N*s", "arms": arms})


# ==============================================================================================
# captures
# ==============================================================================================
class CaptureHeadArgs(Args):
    """No arguments."""


@tool(group="observation", kind="read", result=ObservationSummary, renders=True)
def capture_head(ctx: RobotContext, args: CaptureHeadArgs) -> ToolOutput:
    """Captures the fixed head camera (RGB, 640x480 in the benchmark) and returns the image with its obs_id,
    tick and calibration snapshot (K, E, size). No depth."""
    return observation_output(ctx.capture("head_camera"))


def _observation_set(ctx: RobotContext, shots: list[tuple[str, str]]) -> ToolOutput:
    """Capture (role, camera) pairs at the current tick, in order, as one ObservationSet."""
    obs: list[tuple[str, Observation]] = [(role, ctx.capture(cam)) for role, cam in shots]
    ids = [o.obs_id for _, o in obs]
    roles: dict[str, str] = {}
    for role, o in obs:
        roles[role] = o.obs_id
    payload = {"set_id": "set_" + ids[0].removeprefix("obs_"), "observations": [o.summary() for _, o in obs],
               "roles": roles, "tick": ctx.tick, "obs_ids": ids, "images": ids}
    return ToolOutput(payload=payload, obs_ids=ids)


class ObservationSet(Result):
    set_id: str = Field(description="Identifier of this set.")
    observations: list[ObservationSummary] = Field(description="The captured observations, same tick.")
    roles: dict[str, str] = Field(description="Role (active/opposite or view name) -> obs_id.")
    tick: int = Field(description="Actuation tick of all images.")
    obs_ids: list[str] = Field(description="All obs_ids in order.")
    images: list[str] = Field(description="obs_ids whose images are attached, in order.")


class CaptureWristArgs(Args):
    active_arm: Literal["left", "right", "none"] = Field(
        description="Arm whose wrist camera is the 'active' view; 'none' only with views='both' "
                    "(both wrists, no roles).")
    views: Literal["active", "both"] = Field(
        default="active",
        description="'active': the active arm's wrist image only; 'both': also the opposite wrist.")

    @model_validator(mode="after")
    def _none_needs_both(self):
        if self.active_arm == "none" and self.views != "both":
            raise ValueError("active_arm='none' has no active wrist: pass views='both' or name an arm")
        return self


@tool(group="observation", kind="read", result=ObservationSet, renders=True)
def capture_wrist(ctx: RobotContext, args: CaptureWristArgs) -> ToolOutput:
    """Captures wrist-camera RGB (320x240): the active arm's wrist, or with views='both' also the opposite wrist
    (roles active/opposite). active_arm='none' with views='both' captures both wrists without roles. Each
    image has its obs_id and calibration snapshot."""
    if args.active_arm == "none":
        shots = [(f"{a}_wrist", f"{a}_camera") for a in sorted(ctx.emb.arms)]
    else:
        ctx.arm(args.active_arm)
        shots = [("active", f"{args.active_arm}_camera")]
        if args.views == "both":
            other = next(a for a in sorted(ctx.emb.arms) if a != args.active_arm)
            shots.append(("opposite", f"{other}_camera"))
    return _observation_set(ctx, shots)


def _all_views() -> list[EvidenceView]:
    return ["overview", "left_wrist", "right_wrist"]


class CaptureEvidenceViewsArgs(Args):
    active_arm: Arm | None = Field(
        default=None,
        description="Optional arm whose wrist view is also labelled role 'active' (the other 'opposite').")
    views: list[EvidenceView] = Field(
        default_factory=_all_views, min_length=1, max_length=3,
        description="Unique, non-empty subset of 'overview' (head camera), 'left_wrist', 'right_wrist'; "
                    "captured at the same tick in the given order. Default all three.")

    @model_validator(mode="after")
    def _unique(self):
        if len(set(self.views)) != len(self.views):
            raise ValueError("views must be unique")
        return self


@tool(group="observation", kind="read", result=ObservationSet, renders=True)
def capture_evidence_views(ctx: RobotContext, args: CaptureEvidenceViewsArgs) -> ToolOutput:
    """Captures several views at the same tick: 'overview' (head camera), 'left_wrist', 'right_wrist' (default
    all three, in that order), each with obs_id and calibration. Use it to check a state from several angles."""
    out = _observation_set(ctx, [(v, _VIEW_CAMERA[v]) for v in args.views])
    if args.active_arm is not None:
        roles = out.payload["roles"]
        for arm in ctx.emb.arms:
            view = f"{arm}_wrist"
            if view in roles:
                roles["active" if arm == args.active_arm else "opposite"] = roles[view]
    return out
