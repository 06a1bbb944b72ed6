"""Pydantic argument and result models for the 29 robot tools plus ``run_code`` and ``done``.

The JSON Schemas generated from these models are what a model reads, so every field says its
units and frame. Conventions shared by all tools (FACTS §A.4):

- one right-handed world frame in metres: +x robot-right, +y forward (away from the robot), +z up;
- poses ``[x, y, z, qw, qx, qy, qz]``, quaternions wxyz;
- gripper-local axes: +x approach (wrist toward fingertips), +y finger-opening line, +z completes;
- pixels ``[u, v]`` in the observation's own image: top-left origin, zero-based, u right, v down.

Argument models forbid extra fields. Cross-field rules (mutually exclusive references,
orthogonal axes, equal-length lists) are ``model_validator``s whose messages say how to fix the
call. Result models document payloads; they allow extra keys so handlers can add diagnostics.
"""
from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Optional, get_args

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict, model_validator

# -- shared vocabularies ------------------------------------------------------------------------
Arm = Literal["left", "right"]
CameraName = Literal["head_camera", "left_camera", "right_camera"]
WristCamera = Literal["left_camera", "right_camera"]
EvidenceView = Literal["overview", "left_wrist", "right_wrist"]
CAMERAS: tuple[str, ...] = get_args(CameraName)  # head_camera, left_camera, right_camera

WORKSPACE = {"x": (-0.8, 0.8), "y": (-0.8, 0.8), "z": (0.4, 1.5)}  # FACTS §A.5 envelope, metres
CONTACT_IMPULSE_THRESHOLD = 1e-4  # N*s, sensor floor of finger contact (FACTS §A.5)

ORTHOGONALITY_TOL = 1e-6  # |dot| of the normalised approach and opening axes
FINGER_GAP_RANGE_M = (0.048, 0.142)  # FK distance between finger-link origins
MAX_MARKS = 12

# Declared ranges of every numeric argument (the schema shows them as minimum/maximum). They are far
# wider than any useful value, so they refuse only nonsense (1e308, overflow), never a real request.
COORD_LIMIT_M = 10.0  # world coordinates of points, metres (the table scene spans about 1.6 m)
DELTA_LIMIT_M = 10.0  # components of displacements, metres (motion tools clamp the norm to 0.30 m)
PIXEL_LIMIT_PX = 10_000.0  # pixel coordinates: points well outside the image are still meaningful
AXIS_LIMIT = 1_000.0  # components of directions and quaternions, which are normalised internally


def _norm(v: list[float]) -> float:
    return math.sqrt(sum(x * x for x in v))


def _nonzero_vector(v: list[float]) -> list[float]:
    n = _norm(v)
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError("must be a non-zero vector")
    return v


def _unit_quaternion(q: list[float]) -> list[float]:
    n = _norm(q)
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError("quaternion must be non-zero (order w, x, y, z)")
    return [x / n for x in q]


def _unit(v: list[float]) -> list[float]:
    n = _norm(v)
    return [x / n for x in v]


def Num(lo: float, hi: float, *, lo_open: bool = False) -> Any:
    """A finite number within [lo, hi] (or (lo, hi] with ``lo_open``): a JSON integer is accepted,
    a string, a boolean or null is refused (strict, never coerced)."""
    low = {"gt": lo} if lo_open else {"ge": lo}
    return Annotated[float, Strict(), Field(allow_inf_nan=False, le=hi, **low)]


Coord = Num(-COORD_LIMIT_M, COORD_LIMIT_M)
Delta = Num(-DELTA_LIMIT_M, DELTA_LIMIT_M)
PixelCoord = Num(-PIXEL_LIMIT_PX, PIXEL_LIMIT_PX)
AxisComponent = Num(-AXIS_LIMIT, AXIS_LIMIT)

Vec3 = Annotated[list[Coord], Field(min_length=3, max_length=3)]
Delta3 = Annotated[list[Delta], Field(min_length=3, max_length=3)]
Direction3 = Annotated[list[AxisComponent], Field(min_length=3, max_length=3), AfterValidator(_nonzero_vector)]
QuatWXYZ = Annotated[list[AxisComponent], Field(min_length=4, max_length=4), AfterValidator(_unit_quaternion)]
Pixel = Annotated[list[PixelCoord], Field(min_length=2, max_length=2)]
ObsId = Annotated[str, Strict(), Field(min_length=1, max_length=64)]

_D_GAP = "Finger-link origin gap to draw, metres (0.048-0.142); default the arm's live FK gap."
_D_QUAT = "Proposed TCP orientation, world quaternion [w, x, y, z] (normalised internally)."
_D_TCP = "Proposed TCP (nominal grasp centre) position, world metres."


class Args(BaseModel):
    """Base of every argument model: unknown fields are errors."""
    model_config = ConfigDict(extra="forbid")


# -- observation -------------------------------------------------------------------------------
class GetWorldFrameArgs(Args):
    """No arguments."""


class GetEmbodimentArgs(Args):
    """No arguments."""


class GetCameraInfoArgs(Args):
    camera: CameraName = Field(description="Camera to describe: the fixed head camera or a wrist camera.")


class GetArmPoseArgs(Args):
    arm: Arm = Field(description="Arm to read: 'left' (at -x) or 'right' (at +x).")


class GetGripperStateArgs(Args):
    arm: Arm = Field(description="Arm whose gripper to read: 'left' or 'right'.")


class GetRobotStateArgs(Args):
    arms: list[Arm] = Field(
        default_factory=lambda: ["left", "right"], min_length=1, max_length=2,
        description="Arms to include, 1 or 2 distinct names from 'left'/'right'; default both.")

    @model_validator(mode="after")
    def _unique(self):
        if len(set(self.arms)) != len(self.arms):
            raise ValueError("arms must not repeat a name")
        return self


class GetGraspContactArgs(Args):
    arm: Arm = Field(description="Arm whose finger contacts to read: 'left' or 'right'.")


class CaptureHeadArgs(Args):
    """No arguments."""


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


class CaptureEvidenceViewsArgs(Args):
    active_arm: Optional[Arm] = Field(
        default=None,
        description="Optional arm whose wrist view is also labelled role 'active' (the other 'opposite').")
    views: list[EvidenceView] = Field(
        default_factory=lambda: ["overview", "left_wrist", "right_wrist"], min_length=1, max_length=3,
        description="Unique, non-empty subset of 'overview' (head camera), 'left_wrist', 'right_wrist'; "
                    "captured at the same tick in the given order. Default all three.")

    @model_validator(mode="after")
    def _unique(self):
        if len(set(self.views)) != len(self.views):
            raise ValueError("views must be unique")
        return self


class DrawMarksArgs(Args):
    obs_id: ObsId = Field(
        description="Observation to annotate (an obs_id from a capture tool). It is not modified; a new "
                    "observation is returned.")
    pixels: list[Pixel] = Field(
        min_length=1, max_length=MAX_MARKS,
        description="1-12 pixel points [u, v] in that observation's image (u right, v down, zero-based).")
    labels: list[Annotated[str, Strict(), Field(max_length=40)]] = Field(
        min_length=1, max_length=MAX_MARKS,
        description="One short text label per pixel (same count as pixels, at most 40 characters each).")

    @model_validator(mode="after")
    def _same_length(self):
        if len(self.pixels) != len(self.labels):
            raise ValueError(f"labels must have one entry per pixel "
                             f"(got {len(self.pixels)} pixels, {len(self.labels)} labels)")
        return self


# -- geometry ----------------------------------------------------------------------------------
class RayArgs(Args):
    obs_id: ObsId = Field(description="Observation whose calibration snapshot (K, E) defines the ray.")
    px: Pixel = Field(description="Pixel [u, v] in that observation's image (u right, v down, zero-based).")


class ProjectArgs(Args):
    obs_id: ObsId = Field(description="Observation whose calibration snapshot (K, E) to project into.")
    xyz: Vec3 = Field(description="World point [x, y, z] in metres.")


class PlaneIntersectArgs(Args):
    obs_id: ObsId = Field(description="Observation whose calibration snapshot defines the viewing ray.")
    px: Pixel = Field(description="Pixel [u, v] in that observation's image.")
    plane_point_xyz: Vec3 = Field(description="Any world point on the plane [x, y, z], metres.")
    plane_normal_xyz: Direction3 = Field(
        description="Plane normal in world coordinates (non-zero; normalised internally).")
    plane_offset_sigma_m: Num(0.0, 10.0) = Field(
        description="Your 1-sigma uncertainty of the plane's position along its normal, metres (>= 0).")
    pixel_sigma_px: Num(0.0, 100.0) = Field(
        default=2.0,
        description="Your 1-sigma uncertainty of the pixel location, pixels (default 2.0).")


class CaptureMotionPairArgs(Args):
    arm: Arm = Field(description="Arm to move; its wrist camera takes the before/after images.")
    dx: Delta = Field(description="World-frame displacement along +x (robot right), metres.")
    dy: Delta = Field(description="World-frame displacement along +y (forward), metres.")
    dz: Delta = Field(description="World-frame displacement along +z (up), metres.")


class TriangulateCorrespondenceArgs(Args):
    pair_id: Annotated[str, Strict(), Field(min_length=1, max_length=64)] = Field(
        description="pair_id returned by capture_motion_pair.")
    px_before: Pixel = Field(description="Pixel [u, v] of the scene point in the pair's 'before' image.")
    px_after: Pixel = Field(description="Pixel [u, v] of the same scene point in the pair's 'after' image.")
    pixel_sigma_px: Num(0.0, 100.0) = Field(
        default=2.0,
        description="Your 1-sigma pixel uncertainty for both points, pixels (default 2.0).")


class ScaleFromObjectSizeArgs(Args):
    obs_id: ObsId = Field(description="Observation in which the object's bounding box was read.")
    bbox: Annotated[list[PixelCoord], Field(min_length=4, max_length=4)] = Field(
        description="Object bounding box [x1, y1, x2, y2] in pixels of that image (x1 < x2, y1 < y2).")
    extent_axis: Literal["width", "height", "diagonal"] = Field(
        description="Which box extent matches the known size: 'width' (u), 'height' (v) or 'diagonal'.")
    known_extent_m: Num(1e-6, 10.0) = Field(
        description="Your prior for the object's physical extent along that axis, metres.")
    known_extent_sigma_m: Optional[Num(0.0, 10.0)] = Field(
        default=None,
        description="Optional 1-sigma uncertainty of that prior, metres; without it the uncertainty is null.")

    @model_validator(mode="after")
    def _ordered(self):
        x1, y1, x2, y2 = self.bbox
        if not (x2 > x1 and y2 > y1):
            raise ValueError("bbox must be [x1, y1, x2, y2] with x1 < x2 and y1 < y2")
        return self


class ScaleFromGripperArgs(Args):
    camera: CameraName = Field(
        description="Camera in which to measure the fingertips (a fresh image is captured).")
    arm: Arm = Field(description="Arm whose fingertips serve as the metric reference.")


class GraspQuatCandidatesArgs(Args):
    approach_axis_world: Direction3 = Field(
        description="World direction from the wrist toward the fingertips (gripper +x); normalised internally.")
    opening_axis_world: Direction3 = Field(
        description="World direction of the line along which the fingers open and close (gripper +y); "
                    "normalised internally; must be orthogonal to the approach axis (|dot| <= 1e-6).")

    @model_validator(mode="after")
    def _orthogonal(self):
        a, o = _unit(self.approach_axis_world), _unit(self.opening_axis_world)
        d = abs(sum(x * y for x, y in zip(a, o)))
        if d > ORTHOGONALITY_TOL:
            raise ValueError(f"approach and opening axes must be orthogonal "
                             f"(|dot| after normalising is {d:.3g} > 1e-6)")
        return self


class CameraAimPoseArgs(Args):
    camera: WristCamera = Field(
        description="Wrist camera to aim: 'left_camera' (left arm) or 'right_camera' (right arm).")
    target_xyz: Vec3 = Field(description="World point [x, y, z] (metres) the camera should look at.")
    pitch: Num(60.0, 90.0) = Field(
        default=80.0,
        description="Approach tilt below horizontal, degrees (60-90, default 80; 90 = approach straight down, "
                    "the top-down family); a rotation about world Y applied before the heading.")
    standoff: Num(0.05, 1.0) = Field(
        default=0.28,
        description="Height of the TCP above the target's z, metres (default 0.28).")


class TcpCandidate(Args):
    arm: Arm = Field(description="Arm this TCP pose is for.")
    tcp_xyz: Vec3 = Field(description=_D_TCP)
    quat_wxyz: QuatWXYZ = Field(description=_D_QUAT)
    finger_gap_m: Optional[Num(*FINGER_GAP_RANGE_M)] = Field(default=None, description=_D_GAP)


class PreviewTcpPoseArgs(Args):
    obs_id: ObsId = Field(
        description="Observation to draw into; it must be from the current tick (capture a fresh one after "
                    "any motion).")
    arm: Arm = Field(description="Arm whose gripper geometry to draw.")
    tcp_xyz: Vec3 = Field(description=_D_TCP)
    quat_wxyz: QuatWXYZ = Field(description=_D_QUAT)
    finger_gap_m: Optional[Num(*FINGER_GAP_RANGE_M)] = Field(default=None, description=_D_GAP)
    reference_px: Optional[Pixel] = Field(
        default=None, description="Optional pixel [u, v] to report offsets to; exclusive with reference_xyz_world.")
    reference_xyz_world: Optional[Vec3] = Field(
        default=None, description="Optional world point [x, y, z] (m) to report offsets to; exclusive with "
                                  "reference_px.")

    @model_validator(mode="after")
    def _one_reference(self):
        if self.reference_px is not None and self.reference_xyz_world is not None:
            raise ValueError("give reference_px or reference_xyz_world, not both")
        return self


class CompareTcpPosesArgs(Args):
    obs_id: ObsId = Field(description="Observation to draw into; it must be from the current tick.")
    candidates: list[TcpCandidate] = Field(
        min_length=2, max_length=4, description="2-4 proposed TCP poses, drawn and numbered 1..n in this order.")


class CheckTcpPoseReachabilityArgs(Args):
    arm: Arm = Field(description="Arm to plan for.")
    target_xyz: Vec3 = Field(description="Target TCP position, world metres.")
    target_quat: Optional[QuatWXYZ] = Field(
        default=None,
        description="Target TCP orientation, world quaternion [w, x, y, z]; default keeps the current one.")


# -- motion ------------------------------------------------------------------------------------
class MoveDeltaArgs(Args):
    arm: Arm = Field(description="Arm to move.")
    dx: Delta = Field(default=0.0, description="TCP displacement along world +x (robot right), metres.")
    dy: Delta = Field(default=0.0, description="TCP displacement along world +y (forward), metres.")
    dz: Delta = Field(default=0.0, description="TCP displacement along world +z (up), metres.")
    path: Literal["waypoint_legs", "single_plan"] = Field(
        default="waypoint_legs",
        description="'waypoint_legs': guarded legs of at most contact_leg_m (0.03 m), each re-aimed from the "
                    "measured TCP; 'single_plan': one planned trajectory.")


class MoveBothDeltaArgs(Args):
    left_delta: Delta3 = Field(description="Left TCP displacement [dx, dy, dz], world metres.")
    right_delta: Delta3 = Field(description="Right TCP displacement [dx, dy, dz], world metres.")


class ReachTcpArgs(Args):
    arm: Arm = Field(description="Arm to move.")
    target_xyz: Vec3 = Field(
        description="Target TCP position, world metres (workspace x, y in [-0.8, 0.8], z in [0.4, 1.5]).")
    target_quat: Optional[QuatWXYZ] = Field(
        default=None,
        description="Target TCP orientation, world quaternion [w, x, y, z]; default keeps the call-start one.")


class ReachBothTcpArgs(Args):
    left_xyz: Vec3 = Field(description="Left arm target TCP position, world metres.")
    right_xyz: Vec3 = Field(description="Right arm target TCP position, world metres.")
    left_quat: Optional[QuatWXYZ] = Field(
        default=None, description="Left target orientation [w, x, y, z]; default keeps the current one.")
    right_quat: Optional[QuatWXYZ] = Field(
        default=None, description="Right target orientation [w, x, y, z]; default keeps the current one.")


class ProbeContactAlongArgs(Args):
    arm: Arm = Field(description="Arm to move.")
    direction_xyz: Direction3 = Field(description="World direction of travel (non-zero; normalised internally).")
    distance_m: Num(0.0, DELTA_LIMIT_M, lo_open=True) = Field(
        description="Maximum travel, metres (> 0; clamped to 0.30).")
    step_m: Num(0.002, DELTA_LIMIT_M) = Field(
        description="Step between contact checks, metres (>= 0.002; clamped to 0.03).")


class SetGripperArgs(Args):
    arm: Arm = Field(description="Arm whose gripper to actuate.")
    pos: Num(0.0, 1.0) = Field(
        description="Normalised opening command: 1 = fully open, 0 = fully closed.")


# -- composition and control -------------------------------------------------------------------
class RunCodeArgs(Args):
    code: Annotated[str, Strict()] = Field(
        min_length=1, max_length=200_000,
        description="Python source run in the persistent sandbox (numpy as np, math, load_image and every "
                    "robot tool as a keyword-only function); assign `result` to return a value.")


class DoneArgs(Args):
    report: Annotated[str, Strict()] = Field(
        max_length=20_000, description="Your account of what you did and the final state.")
    success_claim: Optional[Annotated[bool, Strict()]] = Field(
        default=None, description="Whether you judge the task accomplished (true/false).")


# -- result models (documentation of payloads) ---------------------------------------------------
class Result(BaseModel):
    """Base of documented result payloads; handlers may add keys."""
    model_config = ConfigDict(extra="allow")


class Failure(Result):
    stage: Optional[str] = Field(
        default=None, description="Where it failed, e.g. planner_query, execution, workspace_prefilter.")
    code: str = Field(description="Stable failure code, e.g. goal_pose_unreachable, stalled, RAY_PARALLEL_TO_PLANE.")
    category: Optional[str] = Field(
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
    abort_reason: Optional[str] = Field(
        default=None, description="stalled / trajectory_deviation / leg_budget / arm_lock, when ABORTED.")
    commanded: dict[str, Any] = Field(description="What was asked, after clamping (delta, target, path mode).")
    achieved: dict[str, Any] = Field(
        description="Measured outcome: guard, contact, stall evidence, planner status, mode details.")
    resulting_pose: dict[str, Any] = Field(
        description="Measured TCP pose(s) after the action: {tcp} or {left_tcp, right_tcp}.")
    planning: Planning = Field(description="Planner outcome.")
    execution: Execution = Field(description="Execution outcome.")
    failure: Optional[Failure] = Field(default=None, description="Why it failed or aborted; null on SUCCESS.")
    observed_before: dict[str, Any] = Field(description="Two-arm robot snapshot before the action.")
    observed_after: dict[str, Any] = Field(description="Two-arm robot snapshot after the action.")
    tick: int = Field(description="Actuation tick after the action.")
    call_status: Literal["OK"] = Field(default="OK", description="The call itself was dispatched.")


class EstimateFailure(Result):
    code: Literal["RAY_PARALLEL_TO_PLANE", "BEHIND_CAMERA", "DEGENERATE_GEOMETRY", "OUTSIDE_WORKSPACE",
                  "ESTIMATE_UNAVAILABLE"] = Field(
        description="Failure code. OUTSIDE_WORKSPACE: a point was computed (value kept) but lies outside the "
                    "workspace envelope, so it cannot be on the table.")
    message: str = Field(description="What went wrong.")


class Estimate(Result):
    """A geometric estimate: value plus its uncertainty and how it was obtained."""
    value: Any = Field(
        description="The estimate (pixel [u, v], ray {origin, dir}, world point [x, y, z] or depth), or null "
                    "on failure.")
    kind: Literal["pixel_point", "ray", "world_point", "depth"] = Field(description="What value is.")
    uncertainty: Optional[dict[str, Any]] = Field(
        description="Propagated 1-sigma terms from your declared sigmas; null when none applies.")
    coarse: bool = Field(
        description="True when the estimate rests on an assumption (a plane, a size prior) and needs checking.")
    valid: bool = Field(description="False when value is null or its preconditions do not hold.")
    frame: str = Field(description="Frame of value: 'world', 'image:<obs_id>' or 'camera:<obs_id>'.")
    units: str = Field(description="Units of value: m or px.")
    failure: Optional[EstimateFailure] = Field(default=None, description="Why value is null or invalid.")
    provenance: dict[str, Any] = Field(
        description="Inputs and intermediate quantities (rays, ranges, angles, Jacobians).")


class CamPoseSnapshot(Result):
    available: bool = Field(description="Calibration was read.")
    K: list[list[float]] = Field(description="3x3 pinhole intrinsics, pixels, no distortion.")
    E: list[list[float]] = Field(description="3x4 world->camera [R|t]: p_cam = R p_world + t.")
    size_hw: list[int] = Field(description="[H, W] of the image, pixels.")
    freshness: str = Field(description="'captured_at_tick': the snapshot matches the image.")
    read_failures: int = Field(description="Calibration read failures.")
    convention: str = Field(description="Camera axes: +x right, +y down, +z forward.")


class ObservationSummary(Result):
    """JSON part of an Observation; the RGB image is attached separately."""
    obs_id: str = Field(description="Identifier to pass to geometry tools.")
    camera: str = Field(description="head_camera, left_camera or right_camera.")
    tick: int = Field(description="Actuation tick at capture.")
    cam_pose_snapshot: CamPoseSnapshot = Field(description="Calibration at capture.")
    image: dict[str, Any] = Field(description="{attached, size_hw}.")
    annotation: Optional[dict[str, Any]] = Field(default=None, description="Tool-specific overlay data.")
    source_obs_id: Optional[str] = Field(default=None, description="For annotated copies: the observation drawn on.")


class ObservationSet(Result):
    set_id: str = Field(description="Identifier of this set.")
    observations: list[ObservationSummary] = Field(description="The captured observations, same tick.")
    roles: dict[str, str] = Field(description="Role (active/opposite or view name) -> obs_id.")
    tick: int = Field(description="Actuation tick of all images.")
    obs_ids: list[str] = Field(description="All obs_ids in order.")
    images: list[str] = Field(description="obs_ids whose images are attached, in order.")


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


class TraceEntry(Result):
    index: int = Field(description="Order of the internal call.")
    tool: str = Field(description="Tool name.")
    ok: bool = Field(description="The call returned without error.")
    status: Optional[str] = Field(default=None, description="Action status if an action.")
    action_id: Optional[str] = Field(default=None, description="Action id if an action.")
    tick: Optional[int] = Field(default=None, description="Tick after the call.")
    abort_reason: Optional[str] = Field(default=None, description="Abort reason if ABORTED.")
    obs_ids: list[str] = Field(default_factory=list, description="Observations produced.")
    error: Optional[str] = Field(default=None, description="Error text if the call failed.")


class CodeResult(Result):
    ok: bool = Field(description="The program ran to completion without an exception.")
    error: Optional[str] = Field(default=None, description="Exception text, if any.")
    stdout: str = Field(default="", description="Captured print output (capped at 8000 characters).")
    value: Any = Field(default=None, description="The value assigned to `result`, JSON-encoded.")
    result_assigned: bool = Field(default=False, description="Whether the program assigned `result`.")
    tool_calls: int = Field(default=0, description="Internal tool calls made (not charged individually).")
    obs_ids: list[str] = Field(default_factory=list, description="Observations produced by the program.")
    internal_trace: list[TraceEntry] = Field(default_factory=list, description="One entry per internal tool call.")
    filesystem_policy: str = Field(default="structurally_denied", description="Programs cannot reach a filesystem.")
    namespace_reset: bool = Field(
        default=False, description="True when a timeout or an aborted action reset the program state.")


class DoneResult(Result):
    ok: bool = Field(description="Always true.")
    note: str = Field(description="'episode ended; attempt recorded.' No verdict is returned.")
