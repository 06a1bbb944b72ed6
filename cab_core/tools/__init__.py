"""The tool contract: the 29 robot tools of the paper plus ``run_code`` and ``done``.

``TOOLS`` (built on first access by :func:`build_registry`, then cached) maps each name to its
:class:`~cab_core.tools.registry.ToolDef`, in the order of the catalog. Schemas come from the
pydantic models in :mod:`cab_core.tools.models`; registration refuses an argument without a
description. :func:`validate_args` turns raw JSON arguments into the model or raises
:class:`~cab_core.errors.ToolArgumentError` with a short message a model can act on.
"""
from __future__ import annotations

import functools
import types
import typing
from typing import Any

from pydantic import BaseModel, ValidationError

from cab_core.errors import PluginError, ToolArgumentError
from cab_core.tools import models as m
from cab_core.tools.registry import ToolDef, ToolOutput

__all__ = ["TOOLS", "ToolDef", "ToolOutput", "build_registry", "schemas", "validate_args", "tool_names"]

_OBSERVE = "cab_core.tools.observe"
_GEOM = "cab_core.tools.estimate"
_MOTION = "cab_core.tools.motion"
_EPISODE = "cab_core.attempt.episode"

_FRAME = "World frame: metres, +x robot-right, +y forward, +z up; poses [x,y,z,qw,qx,qy,qz]."
_PIXELS = "Pixels are [u, v] in that observation's image (top-left origin, u right, v down)."

# (name, group, args model, handler module, kind, description, result model), in catalog order.
# kind: "read" (read-only), "plan" (read-only planner query), "act" (moves the robot: destructive),
# "code" (run_code: may move the robot, so destructive), "done" (free). The catalog's group
# "termination" is the registry's "control".
_SPECS: list[tuple[str, str, type[BaseModel], str, str, str, type[BaseModel] | None]] = [
    ("get_world_frame", "observation", m.GetWorldFrameArgs, _OBSERVE, "read",
     "Captures a fresh head-camera image with a display-only legend glyph in a screen corner and returns the world "
     "conventions: +x robot-right (left arm at -x, right arm at +x), +y forward away from the robot, +z up, metres, "
     "seconds, radians, wxyz quaternions, pixel convention. The legend is a schematic: it gives no pixel-to-world "
     "correspondence.", m.ObservationSummary),
    ("get_embodiment", "observation", m.GetEmbodimentArgs, _OBSERVE, "read",
     "Describes the robot: arms and their sides, gripper geometry (max opening 0.08 m, finger-gap range, empty-close "
     "gap), the TCP convention (nominal grasp centre; flange behind it along the approach axis, fingertip plane "
     "ahead), gripper-local axes (+x approach, +y opening line), cameras (qualitatively), reachability notes and "
     "motion limits (max single displacement 0.30 m, guarded leg 0.03 m). No scene facts and no preferred grasp.", None),
    ("get_camera_info", "observation", m.GetCameraInfoArgs, _OBSERVE, "read",
     "Returns the current calibration of one camera: 3x3 pinhole K (pixels, no distortion), 3x4 extrinsic E = [R|t] "
     "mapping world to camera (p_cam = R p_world + t; camera +x right, +y down, +z forward) and image size [H, W]. "
     "Wrist cameras move with their arm, so E changes after motion. A read failure returns available=false with "
     "null fields.", None),
    ("get_arm_pose", "observation", m.GetArmPoseArgs, _OBSERVE, "read",
     "Measured flange (ee_pose) and TCP pose of one arm, world frame [x,y,z,qw,qx,qy,qz], with an orientation block: "
     "approach_axis_world (gripper +x), opening_axis_world (gripper +y) and plain-text readings such as "
     "'approach points down (-z)'.", None),
    ("get_gripper_state", "observation", m.GetGripperStateArgs, _OBSERVE, "read",
     "Gripper readback of one arm: gripper_val (the last command, 1 = open, 0 = closed), opening_m = command x 0.08 m, "
     "finger_gap_m (physical distance between finger-link origins from forward kinematics, metres) and "
     "drive_commanded_closed (command < 0.2). A closed command with a gap above the empty-close gap suggests "
     "something between the fingers.", None),
    ("get_robot_state", "observation", m.GetRobotStateArgs, _OBSERVE, "read",
     "Combined state of one or both arms: flange and TCP poses with orientation blocks, gripper readback, anonymous "
     "finger contact summary and joint_state (names, types, positions in rad or m, velocities in rad/s or m/s). "
     "The only tool that returns joint positions and velocities. " + _FRAME, None),
    ("get_grasp_contact", "observation", m.GetGraspContactArgs, _OBSERVE, "read",
     "Anonymous contact between one arm's fingers and anything that is not the robot, during the last physics step: "
     "total and per-finger impulse (N*s, threshold 1e-4), fingers_in_contact, and the world pose of each contacting "
     "finger link. Finger-finger and robot self-contact are excluded; the touched body is never named.", None),
    ("capture_head", "observation", m.CaptureHeadArgs, _OBSERVE, "read",
     "Captures the fixed head camera (RGB, 640x480 in the benchmark) and returns the image with its obs_id, tick and "
     "calibration snapshot (K, E, size). No depth.", m.ObservationSummary),
    ("capture_wrist", "observation", m.CaptureWristArgs, _OBSERVE, "read",
     "Captures wrist-camera RGB (320x240): the active arm's wrist, or with views='both' also the opposite wrist "
     "(roles active/opposite). active_arm='none' with views='both' captures both wrists without roles. Each image "
     "has its obs_id and calibration snapshot.", m.ObservationSet),
    ("capture_evidence_views", "observation", m.CaptureEvidenceViewsArgs, _OBSERVE, "read",
     "Captures several views at the same tick: 'overview' (head camera), 'left_wrist', 'right_wrist' (default all "
     "three, in that order), each with obs_id and calibration. Use it to check a state from several angles.",
     m.ObservationSet),
    ("draw_marks", "observation", m.DrawMarksArgs, _GEOM, "read",
     "Draws 1-12 numbered, coloured markers with your labels at pixels of an existing observation and returns a new "
     "annotated observation (same camera, tick and calibration). Reports for each mark its colour, whether it is "
     "in frame and its label box. " + _PIXELS, m.ObservationSummary),
    ("ray", "geometry", m.RayArgs, _GEOM, "read",
     "Back-projects a pixel of an observation into a world-frame viewing ray: origin = camera centre (m), dir = "
     "unit direction. Direction only: an RGB pixel carries no depth. Uses the observation's calibration snapshot. "
     + _PIXELS, m.Estimate),
    ("project", "geometry", m.ProjectArgs, _GEOM, "read",
     "Projects a world point (m) into an observation's image with its calibration snapshot: value [u, v] in pixels, "
     "or null when the point is behind the camera; also its camera depth (m) and whether it falls in frame. Use it "
     "to check a 3D estimate against the image.", m.Estimate),
    ("plane_intersect", "geometry", m.PlaneIntersectArgs, _GEOM, "read",
     "Intersects a pixel's viewing ray with a plane you specify (point and normal, world m) and returns the 3D point "
     "with propagated 1-sigma uncertainty from your pixel and plane-offset sigmas, amplified by obliquity (1/|cos| of "
     "the ray-normal angle) and range. Always coarse: it is only as good as your plane. Fails with value null when "
     "the ray is parallel to the plane or the hit is behind the camera; a hit outside the workspace envelope is "
     "returned with valid=false (OUTSIDE_WORKSPACE).", m.Estimate),
    ("capture_motion_pair", "geometry", m.CaptureMotionPairArgs, _MOTION, "act",
     "Moves one arm by a small world-frame displacement (dx, dy, dz in m) as a real guarded motion, capturing its "
     "wrist RGB before and after. Returns both observations, the motion's ActionResult, the measured camera "
     "translation and rotation, contact evidence and validity flags, and a pair_id for "
     "triangulate_correspondence. Consumes simulated time.", m.ObservationPair),
    ("triangulate_correspondence", "geometry", m.TriangulateCorrespondenceArgs, _GEOM, "read",
     "Triangulates one scene point from a motion pair: you give the pixel of the same point in the 'before' and "
     "'after' images; the two viewing rays from the measured camera poses are intersected by the two-ray midpoint "
     "method. Returns the world point (m) with 1-sigma uncertainty from your pixel sigma, the ray gap, the "
     "triangulation angle and depths. The correspondence itself is not verified: a large ray gap means the pixels "
     "do not match.", m.Estimate),
    ("scale_from_object_size", "geometry", m.ScaleFromObjectSizeArgs, _GEOM, "read",
     "Coarse camera depth (m, along the optical axis) of an object from its pixel bounding box and your prior of its "
     "physical extent: Z = f * known_extent / pixel_extent. Assumes the extent is roughly parallel to the image "
     "plane. Uncertainty is null unless you give known_extent_sigma_m. Also reports the implied world point at the "
     "box centre.", m.Estimate),
    ("scale_from_gripper", "geometry", m.ScaleFromGripperArgs, _GEOM, "read",
     "Captures a fresh image and marks the two inner fingertip points of an arm (from forward kinematics) in it: "
     "their true distance (m), pixel endpoints, in-frame flags, pixel span, camera depths and metres per pixel along "
     "the segment. A metric scale reference valid near the fingertips' depth. Does not move the robot.",
     m.ObservationSummary),
    ("grasp_quat_candidates", "geometry", m.GraspQuatCandidatesArgs, _GEOM, "read",
     "Converts a gripper approach axis (wrist toward fingertips) and opening axis (finger line), both in world "
     "coordinates and orthogonal, into the two wxyz quaternions with TCP +x = approach and +y = +/- opening; they "
     "differ by a 180 degree roll about the approach axis. Pure conversion: unranked, no reachability check.", None),
    ("camera_aim_pose", "geometry", m.CameraAimPoseArgs, _GEOM, "read",
     "Pure geometry: computes a TCP pose that points a wrist camera at a world target from a given pitch (degrees; 90 "
     "= approach straight down) with the TCP `standoff` metres above the target, using the calibrated camera mount. "
     "Returns the target TCP pose and the target's predicted pixel and depth in that camera. No planning, no "
     "motion; check reachability before moving.", None),
    ("preview_tcp_pose", "geometry", m.PreviewTcpPoseArgs, _GEOM, "read",
     "Draws the gripper at a proposed TCP pose (world m, wxyz) into a current-tick observation: finger silhouettes, "
     "inner-tip markers, grasp centre, approach arrow with 1 cm ticks and axes, and returns a new annotated "
     "observation with pixel positions, per-finger boxes, in-view flags and optional offsets to a reference pixel "
     "or world point. No collision or reachability verdict.", m.ObservationSummary),
    ("compare_tcp_poses", "geometry", m.CompareTcpPosesArgs, _GEOM, "read",
     "Draws 2-4 proposed TCP poses (numbered) into a current-tick observation and compares them pairwise: grasp "
     "centre offset and distance (m), approach angle (deg), finger-box overlap and separation for different arms, "
     "projected overlap and which is nearer to the camera. No collision or reachability verdict.",
     m.ObservationSummary),
    ("check_tcp_pose_reachability", "geometry", m.CheckTcpPoseReachabilityArgs, _MOTION, "plan",
     "Asks the motion planner for a trajectory from the current arm configuration to a TCP pose without moving: "
     "whether one was found, planner status and diagnostics. Only robot self-collision is modelled (no table, "
     "objects or other arm).", None),
    ("reach_tcp", "motion", m.ReachTcpArgs, _MOTION, "act",
     "Moves one arm's TCP to an absolute world position (m) and optional orientation (wxyz; default keeps the "
     "call-start orientation): one full plan, then a guarded waypoint fallback and up to 2 correction plans. "
     "Returns an ActionResult; compare commanded with observed_after. Consumes simulated time.", m.ActionResult),
    ("reach_both_tcp", "motion", m.ReachBothTcpArgs, _MOTION, "act",
     "Moves both TCPs to absolute world positions (m) with optional orientations, planned and executed together. "
     "A FAILED result may still mean one arm moved (execution.partial). Consumes simulated time.", m.ActionResult),
    ("move_delta", "motion", m.MoveDeltaArgs, _MOTION, "act",
     "Moves one arm's TCP by a world-frame displacement (m), holding the call-start orientation. The norm is clamped "
     "to 0.30 m (direction kept); by default it runs as guarded legs of at most 0.03 m that stop on stall or "
     "deviation. Returns an ActionResult. Consumes simulated time.", m.ActionResult),
    ("move_both_delta", "motion", m.MoveBothDeltaArgs, _MOTION, "act",
     "Moves both TCPs by world-frame displacements (m) together. A FAILED result may still mean one arm moved "
     "(execution.partial). Returns an ActionResult with a sync block. Consumes simulated time.", m.ActionResult),
    ("probe_contact_along", "motion", m.ProbeContactAlongArgs, _MOTION, "act",
     "Moves one arm's TCP along a world direction in small steps until the set of fingers in contact changes or the "
     "distance is used up (distance clamped to 0.30 m, step to 0.03 m). SUCCESS means only that contact changed; the "
     "result reports the stop reason, transition and finger poses. Consumes simulated time.", m.ActionResult),
    ("set_gripper", "motion", m.SetGripperArgs, _MOTION, "act",
     "Drives one gripper to a normalised opening (1 = open, 0 = closed) over about 0.8 s. SUCCESS means the "
     "actuation completed, not that something is held: read finger_gap_m and contact in the result. Consumes "
     "simulated time.", m.ActionResult),
    ("run_code", "composition", m.RunCodeArgs, _EPISODE, "code",
     "Runs a Python program in a confined, persistent sandbox: numpy as np, math, load_image(obs_id) and every robot "
     "tool as a keyword-only function returning plain dicts. Variables persist across calls; a timeout or an "
     "ABORTED action resets them. Returns stdout, the value of `result`, a trace of internal tool calls and up to 6 "
     "images. Costs one call; robot actions inside still consume simulated time.", m.CodeResult),
    ("done", "control", m.DoneArgs, _EPISODE, "done",
     "Ends the attempt with your report and your judgement of success. The verifier's outcome is never returned. "
     "Free, usable once.", m.DoneResult),
]

# Each handler is the function of the tool's own name in the module given in _SPECS.
_ADVANCES_PHYSICS = {"capture_motion_pair", "move_delta", "move_both_delta", "reach_tcp", "reach_both_tcp",
                     "probe_contact_along", "set_gripper"}


def _model_types(annotation: Any) -> list[type[BaseModel]]:
    """Pydantic models nested anywhere in a type annotation."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    out: list[type[BaseModel]] = []
    for a in typing.get_args(annotation):
        out += _model_types(a)
    return out


def check_documented(model: type[BaseModel], _seen: set | None = None) -> None:
    """Raise PluginError if any field of ``model`` (or of a model nested in it) lacks a description."""
    seen = _seen if _seen is not None else set()
    if model in seen:
        return
    seen.add(model)
    for name, f in model.model_fields.items():
        if not (f.description or "").strip():
            raise PluginError(f"tool argument {model.__name__}.{name} has no description")
        for sub in _model_types(f.annotation):
            check_documented(sub, seen)


def make_tool(name: str, group: str, args: type[BaseModel], module: str, kind: str, description: str,
              result: type[BaseModel] | None = None) -> ToolDef:
    """One ToolDef, refusing undocumented arguments."""
    check_documented(args)
    if args.model_config.get("extra") != "forbid":
        raise PluginError(f"tool {name}: argument model {args.__name__} must forbid extra fields")
    return ToolDef(name=name, group=group, args=args, handler=f"{module}:{name}",  # type: ignore[arg-type]
                   description=description, read_only=kind in ("read", "plan"),
                   destructive=kind in ("act", "code"), advances_physics=name in _ADVANCES_PHYSICS,
                   charged=kind != "done", result=result)


def build_registry() -> dict[str, ToolDef]:
    """Build the registry from the specs above (in catalog order); refuse duplicates."""
    tools: dict[str, ToolDef] = {}
    for spec in _SPECS:
        td = make_tool(*spec)
        if td.name in tools:
            raise PluginError(f"duplicate tool {td.name!r}")
        tools[td.name] = td
    return tools


@functools.cache
def _tools() -> types.MappingProxyType:
    return types.MappingProxyType(build_registry())


def __getattr__(name: str):  # lazily built module attribute TOOLS
    if name == "TOOLS":
        return _tools()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def tool_names() -> list[str]:
    return list(_tools())


def _fmt_loc(loc: tuple) -> str:
    return ".".join(str(p) for p in loc) or "arguments"


def _short(v: Any, n: int = 60) -> str:
    r = repr(v)
    return r if len(r) <= n else r[: n - 3] + "..."


def _fmt_error(e: dict) -> str:
    loc = _fmt_loc(e.get("loc", ()))
    typ = e.get("type", "")
    if typ == "missing":
        return f"missing required argument '{loc}'"
    if typ == "extra_forbidden":
        return f"unknown argument '{loc}'"
    msg = e.get("msg", "invalid")
    msg = msg.removeprefix("Value error, ")
    if typ == "literal_error" or typ.endswith("_type") or typ.endswith("_parsing"):
        return f"{loc}: {msg} (got {_short(e.get('input'))})"
    if loc == "arguments" or not e.get("loc"):
        return msg
    return f"{loc}: {msg}"


def format_validation_error(err: ValidationError, limit: int = 4) -> str:
    errs = err.errors(include_url=False)
    parts = [_fmt_error(e) for e in errs[:limit]]
    if len(errs) > limit:
        parts.append(f"and {len(errs) - limit} more")
    return "; ".join(parts)


def validate_args(name: str, raw: Any) -> BaseModel:
    """Validate raw JSON arguments for tool ``name``; raise ToolArgumentError with a short message."""
    tools = _tools()
    if name not in tools:
        raise ToolArgumentError(f"unknown tool: {name}")
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ToolArgumentError(f"bad arguments: arguments must be a JSON object, got {type(raw).__name__}")
    try:
        return tools[name].args.model_validate(raw)
    except ValidationError as e:
        raise ToolArgumentError(f"bad arguments: {format_validation_error(e)}") from None


def schemas() -> list[dict]:
    """Every tool's provider-neutral description, in registry order (printed by ``cab-schemas``)."""
    return [{"name": t.name, "description": t.description, "group": t.group, "read_only": t.read_only,
             "destructive": t.destructive, "advances_physics": t.advances_physics, "charged": t.charged,
             "parameters": t.json_schema()} for t in _tools().values()]
