"""Geometry tools: rays, projections, plane intersection, triangulation, scale references,
grasp-orientation conversion, camera aiming and gripper previews.

Everything here works from the calibration snapshot of an observation (K, E at capture) or from
the robot's own forward kinematics; nothing reads object state. Estimates follow one shape:
``{value, kind, uncertainty, coarse, valid, frame, units, failure, provenance}``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field, Strict, model_validator

from cab_core.errors import ToolArgumentError
from cab_core.geometry import (
    MIN_DEPTH_M,
    back_project,
    camera_to_world,
    degenerate_direction,
    extrinsic_from_pose,
    mat_to_quat,
    orientation_block,
    pixel_ray,
    pose_block,
    pose_inv,
    pose_mul,
    pose_to_mat,
    project_points,
    quat_angle,
    quat_to_mat,
    rnd,
    world_to_camera,
)
from cab_core.tools.models import (
    WORKSPACE,
    Args,
    Arm,
    CameraName,
    Direction3,
    ObservationSummary,
    ObsId,
    Pixel,
    PixelCoord,
    QuatWXYZ,
    Result,
    Vec3,
    WristCamera,
    bounded,
)
from cab_core.tools.overlay import AXIS_COLOURS, PALETTE, Canvas, convex_hull, in_frame
from cab_core.tools.registry import ToolOutput, observation_output, tool

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.tools.context import Observation, RobotContext

_PAR_TOL = 1e-6  # |cos| below which a ray counts as parallel to a plane
MIN_BOX_EXTENT_PX = 1.0  # scale_from_object_size: a box extent below one pixel carries no scale
MIN_ESTIMATE_DEPTH_M = 0.01  # a depth estimate nearer than this to the camera is degenerate
MAX_MARKS = 12  # draw_marks: points (and labels) per call
ORTHOGONALITY_TOL = 1e-6  # grasp_quat_candidates: |dot| of the normalised approach and opening axes
FINGER_GAP_RANGE_M = (0.048, 0.142)  # preview_tcp_pose, compare_tcp_poses: FK distance between finger-link origins

_D_GAP = "Finger-link origin gap to draw, metres (0.048-0.142); default the arm's live FK gap."
_D_QUAT = "Proposed TCP orientation, world quaternion [w, x, y, z] (normalised internally)."
_D_TCP = "Proposed TCP (nominal grasp centre) position, world metres."


# ==============================================================================================
# the shape of an estimate, and what it was computed from
# ==============================================================================================
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
    uncertainty: dict[str, Any] | None = Field(
        description="Propagated 1-sigma terms from your declared sigmas; null when none applies.")
    coarse: bool = Field(
        description="True when the estimate rests on an assumption (a plane, a size prior) and needs checking.")
    valid: bool = Field(description="False when value is null or its preconditions do not hold.")
    frame: str = Field(description="Frame of value: 'world', 'image:<obs_id>' or 'camera:<obs_id>'.")
    units: str = Field(description="Units of value: m or px.")
    failure: EstimateFailure | None = Field(default=None, description="Why value is null or invalid.")
    provenance: dict[str, Any] = Field(
        description="Inputs and intermediate quantities (rays, ranges, angles, Jacobians).")


def estimate(value: Any, kind: str, *, frame: str, units: str, provenance: dict, uncertainty: dict | None = None,
             coarse: bool = False, valid: bool = True, failure: tuple[str, str] | None = None) -> dict:
    return {
        "value": value,
        "kind": kind,
        "uncertainty": uncertainty,
        "coarse": bool(coarse),
        "valid": bool(valid and failure is None and value is not None),
        "frame": frame,
        "units": units,
        "failure": None if failure is None else {"code": failure[0], "message": failure[1]},
        "provenance": provenance,
    }


def outside_workspace(X: np.ndarray) -> str | None:
    """Why a world point lies outside the declared workspace envelope (None when inside)."""
    out = [f"{ax}={float(X[i]):.3g}" for i, ax in enumerate("xyz")
           if not WORKSPACE[ax][0] <= float(X[i]) <= WORKSPACE[ax][1]]
    if not out:
        return None
    return (f"the point lies outside the workspace envelope (x, y in [-0.8, 0.8] m, z in [0.4, 1.5] m): "
            f"{', '.join(out)}; nothing on the table is there")


def _frame_of(obs: Observation) -> str:
    return f"image:{obs.obs_id}"


def _obs_prov(obs: Observation) -> dict:
    return {"obs_id": obs.obs_id, "camera": obs.camera, "tick": obs.tick, "image_size_hw": obs.size_hw,
            "calibration": "the observation's cam_pose_snapshot (K, E at capture)"}


def require_current(ctx: RobotContext, obs: Observation) -> None:
    if obs.tick != ctx.tick:
        raise ToolArgumentError(
            f"{obs.obs_id} is from tick {obs.tick} but the robot is now at tick {ctx.tick}; capture a fresh "
            "observation and pass its obs_id")


# ==============================================================================================
# project / ray / plane_intersect
# ==============================================================================================
class ProjectArgs(Args):
    obs_id: ObsId = Field(description="Observation whose calibration snapshot (K, E) to project into.")
    xyz: Vec3 = Field(description="World point [x, y, z] in metres.")


@tool(group="geometry", kind="read", result=Estimate)
def project(ctx: RobotContext, args: ProjectArgs) -> ToolOutput:
    """Projects a world point (m) into an observation's image with its calibration snapshot: value [u, v] in
    pixels, or null when the point is behind the camera; also its camera depth (m) and whether it falls in
    frame. Use it to check a 3D estimate against the image."""
    obs = ctx.obs.get(args.obs_id)
    uv, z = project_points(obs.K, obs.E, np.array(args.xyz))
    behind = not z[0] > MIN_DEPTH_M
    px = None if behind else rnd(uv[0], 3)
    prov = {**_obs_prov(obs), "xyz_world": rnd(args.xyz), "camera_depth_m": rnd(z[0]),
            "in_frame": in_frame(px, obs.size_hw), "method": "pinhole projection u = K (R x + t)",
            "uncertainty_note": "0 px: the transform is exact; any error comes from the 3D point you gave"}
    return ToolOutput(payload=estimate(
        px, "pixel_point", frame=_frame_of(obs), units="px", provenance=prov,
        uncertainty={"sigma_px": 0.0, "basis": "transform_only"},
        failure=("BEHIND_CAMERA", "the point is behind the camera (camera depth <= 0)") if behind else None))


class RayArgs(Args):
    obs_id: ObsId = Field(description="Observation whose calibration snapshot (K, E) defines the ray.")
    px: Pixel = Field(description="Pixel [u, v] in that observation's image (u right, v down, zero-based).")


@tool(group="geometry", kind="read", result=Estimate)
def ray(ctx: RobotContext, args: RayArgs) -> ToolOutput:
    """Back-projects a pixel of an observation into a world-frame viewing ray: origin = camera centre (m), dir =
    unit direction. Direction only: an RGB pixel carries no depth. Uses the observation's calibration
    snapshot. Pixels are [u, v] in that observation's image (top-left origin, u right, v down)."""
    obs = ctx.obs.get(args.obs_id)
    origin, d = pixel_ray(obs.K, obs.E, args.px)
    prov = {**_obs_prov(obs), "px": rnd(args.px, 3), "pixel_in_frame": in_frame(args.px, obs.size_hw),
            "method": "back-projection d = R^T K^-1 [u, v, 1]; origin = camera centre",
            "note": "direction only: an RGB pixel carries no depth"}
    bad = ("DEGENERATE_GEOMETRY", "this pixel gives no usable ray direction") if degenerate_direction(d) else None
    return ToolOutput(payload=estimate(None if bad else {"origin": rnd(origin), "dir": rnd(d, 8)}, "ray",
                                       frame="world", units="m", provenance=prov, uncertainty=None, failure=bad))


def _ray_plane(C, d, p0, n) -> float:
    return float(np.dot(n, p0 - C) / np.dot(n, d))


class PlaneIntersectArgs(Args):
    obs_id: ObsId = Field(description="Observation whose calibration snapshot defines the viewing ray.")
    px: Pixel = Field(description="Pixel [u, v] in that observation's image.")
    plane_point_xyz: Vec3 = Field(description="Any world point on the plane [x, y, z], metres.")
    plane_normal_xyz: Direction3 = Field(
        description="Plane normal in world coordinates (non-zero; normalised internally).")
    plane_offset_sigma_m: Annotated[float, bounded(0.0, 10.0)] = Field(
        description="Your 1-sigma uncertainty of the plane's position along its normal, metres (>= 0).")
    pixel_sigma_px: Annotated[float, bounded(0.0, 100.0)] = Field(
        default=2.0,
        description="Your 1-sigma uncertainty of the pixel location, pixels (default 2.0).")


@tool(group="geometry", kind="read", result=Estimate)
def plane_intersect(ctx: RobotContext, args: PlaneIntersectArgs) -> ToolOutput:
    """Intersects a pixel's viewing ray with a plane you specify (point and normal, world m) and returns the 3D
    point with propagated 1-sigma uncertainty from your pixel and plane-offset sigmas, amplified by obliquity
    (1/|cos| of the ray-normal angle) and range. Always coarse: it is only as good as your plane. Fails with
    value null when the ray is parallel to the plane or the hit is behind the camera; a hit outside the
    workspace envelope is returned with valid=false (OUTSIDE_WORKSPACE)."""
    obs = ctx.obs.get(args.obs_id)
    C, d = pixel_ray(obs.K, obs.E, args.px)
    p0 = np.asarray(args.plane_point_xyz, float)
    n = np.asarray(args.plane_normal_xyz, float)
    n = n / np.linalg.norm(n)
    cos = float(np.dot(n, d))
    prov: dict[str, Any] = {**_obs_prov(obs), "px": rnd(args.px, 3), "pixel_in_frame": in_frame(args.px, obs.size_hw),
                            "ray": {"origin": rnd(C), "dir": rnd(d, 8)}, "plane": {"point": rnd(p0), "normal": rnd(n)},
                            "pixel_sigma_px": args.pixel_sigma_px, "plane_offset_sigma_m": args.plane_offset_sigma_m,
                            "ray_normal_angle_deg": rnd(math.degrees(math.acos(min(1.0, abs(cos)))), 3),
                            "method": "ray-plane intersection; uncertainty by first-order propagation"}

    def fail(code: str, msg: str) -> ToolOutput:
        return ToolOutput(payload=estimate(None, "world_point", frame="world", units="m", provenance=prov,
                                           coarse=True, failure=(code, msg)))

    if degenerate_direction(d):
        return fail("DEGENERATE_GEOMETRY", "this pixel gives no usable ray direction")
    if abs(cos) < _PAR_TOL:
        return fail("RAY_PARALLEL_TO_PLANE", "the viewing ray is parallel to the plane")
    s = _ray_plane(C, d, p0, n)
    if not math.isfinite(s):
        return fail("DEGENERATE_GEOMETRY", "the intersection is not finite")
    if s <= 0:
        prov["range_m"] = rnd(s)
        return fail("BEHIND_CAMERA", "the plane is hit behind the camera along this ray")
    X = C + s * d

    # first-order propagation: pixel Jacobian by central differences, plane offset along n.
    h = 0.5
    J = np.zeros((3, 2))
    for k in range(2):
        hit = []
        for sgn in (1, -1):
            q = np.array(args.px, float)
            q[k] += sgn * h
            Ck, dk = pixel_ray(obs.K, obs.E, q)
            hit.append(Ck + _ray_plane(Ck, dk, p0, n) * dk)
        J[:, k] = (hit[0] - hit[1]) / (2 * h)
    if not np.all(np.isfinite(J)):
        return fail("DEGENERATE_GEOMETRY", "the intersection is unstable around this pixel (grazing ray)")
    amp = 1.0 / abs(cos)
    d_offset = d / cos  # dX / d(plane offset along n)
    sp, so = args.pixel_sigma_px, args.plane_offset_sigma_m
    cov = sp ** 2 * J @ J.T + so ** 2 * np.outer(d_offset, d_offset)
    pixel_m = sp * float(np.linalg.norm(J))
    offset_m = so * amp
    unc = {"sigma_m": rnd(math.hypot(pixel_m, offset_m)),
           "sigma_xyz_m": rnd(np.sqrt(np.clip(np.diag(cov), 0, None))),
           "terms": {"pixel_m": rnd(pixel_m), "plane_offset_m": rnd(offset_m)},
           "covariance_m2": rnd(cov, 9),
           "basis": "1-sigma from your pixel_sigma_px and plane_offset_sigma_m; excludes any error of the plane's normal"}
    prov.update({
        "range_m": rnd(s), "camera_depth_m": rnd(float(world_to_camera(obs.E, X)[2])),
        "obliquity_amplification": rnd(amp, 4),
        "pixel_jacobian_m_per_px": {"d_du": rnd(J[:, 0]), "d_dv": rnd(J[:, 1])},
        "sensitivities": {"m_per_px": rnd(float(np.linalg.norm(J) / math.sqrt(2))),
                          "dxyz_d_plane_offset": rnd(d_offset)},
    })
    if amp > 5:
        prov["warning"] = "grazing view: small plane or pixel errors move the point a lot"
    far = outside_workspace(X)
    return ToolOutput(payload=estimate(rnd(X), "world_point", frame="world", units="m", provenance=prov,
                                       uncertainty=unc, coarse=True,
                                       failure=("OUTSIDE_WORKSPACE", far) if far else None))


# ==============================================================================================
# triangulate_correspondence
# ==============================================================================================
def _midpoint(C1, d1, C2, d2):
    """Two-ray midpoint: closest points C1 + s d1 and C2 + t d2 (unit d). None if parallel."""
    b = float(np.dot(d1, d2))
    w0 = C1 - C2
    dd, e = float(np.dot(d1, w0)), float(np.dot(d2, w0))
    den = 1.0 - b * b
    if den < 1e-12:
        return None
    s = (b * e - dd) / den
    t = (e - b * dd) / den
    P1, P2 = C1 + s * d1, C2 + t * d2
    return (P1 + P2) / 2, s, t, P1, P2


def _triangulate_px(ob: Observation, oa: Observation, pb, pa):
    C1, d1 = pixel_ray(ob.K, ob.E, pb)
    C2, d2 = pixel_ray(oa.K, oa.E, pa)
    return _midpoint(C1, d1, C2, d2), (C1, d1, C2, d2)


class TriangulateCorrespondenceArgs(Args):
    pair_id: Annotated[str, Strict(), Field(min_length=1, max_length=64)] = Field(
        description="pair_id returned by capture_motion_pair.")
    px_before: Pixel = Field(description="Pixel [u, v] of the scene point in the pair's 'before' image.")
    px_after: Pixel = Field(description="Pixel [u, v] of the same scene point in the pair's 'after' image.")
    pixel_sigma_px: Annotated[float, bounded(0.0, 100.0)] = Field(
        default=2.0,
        description="Your 1-sigma pixel uncertainty for both points, pixels (default 2.0).")


@tool(group="geometry", kind="read", result=Estimate)
def triangulate_correspondence(ctx: RobotContext, args: TriangulateCorrespondenceArgs) -> ToolOutput:
    """Triangulates one scene point from a motion pair: you give the pixel of the same point in the 'before' and
    'after' images; the two viewing rays from the measured camera poses are intersected by the two-ray
    midpoint method. Returns the world point (m) with 1-sigma uncertainty from your pixel sigma, the ray gap,
    the triangulation angle and depths. The correspondence itself is not verified: a large ray gap means the
    pixels do not match."""
    pair = ctx.pairs.get(args.pair_id)
    if pair is None:
        raise ToolArgumentError(f"unknown pair_id {args.pair_id!r} (use a pair_id returned by capture_motion_pair)")
    ob, oa = ctx.obs.get(pair["before"]), ctx.obs.get(pair["after"])
    validity = dict(pair.get("valid", pair.get("validity", {})) or {})
    pb, pa = np.asarray(args.px_before, float), np.asarray(args.px_after, float)
    prov: dict[str, Any] = {
        "pair_id": args.pair_id, "before_obs_id": ob.obs_id, "after_obs_id": oa.obs_id,
        "px_before": rnd(pb, 3), "px_after": rnd(pa, 3),
        "px_in_frame": {"before": in_frame(pb, ob.size_hw), "after": in_frame(pa, oa.size_hw)},
        "pair_validity": validity, "correspondence_verified": False, "method": "two-ray midpoint",
        "pixel_sigma_px": args.pixel_sigma_px,
    }
    res, (C1, d1, C2, d2) = _triangulate_px(ob, oa, pb, pa)
    baseline = float(np.linalg.norm(C2 - C1))
    angle = math.degrees(math.acos(min(1.0, abs(float(np.dot(d1, d2))))))
    prov.update({"camera_baseline_m": rnd(baseline), "triangulation_angle_deg": rnd(angle, 4),
                 "rays": {"before": {"origin": rnd(C1), "dir": rnd(d1, 8)}, "after": {"origin": rnd(C2), "dir": rnd(d2, 8)}}})

    def fail(code: str, msg: str) -> ToolOutput:
        return ToolOutput(payload=estimate(None, "world_point", frame="world", units="m", provenance=prov,
                                           failure=(code, msg)))

    if res is None or baseline < 1e-6:
        return fail("DEGENERATE_GEOMETRY", "the two rays are parallel or the cameras did not move")
    X, s, t, P1, P2 = res
    prov.update({"ray_gap_m": rnd(float(np.linalg.norm(P1 - P2))),
                 "depths": {"before_range_m": rnd(s), "after_range_m": rnd(t),
                            "before_camera_z_m": rnd(float(world_to_camera(ob.E, X)[2])),
                            "after_camera_z_m": rnd(float(world_to_camera(oa.E, X)[2]))}})
    if s <= 0 or t <= 0:
        return fail("BEHIND_CAMERA", "the rays meet behind one of the cameras: the pixels do not correspond")

    # pixel uncertainty: Jacobian of the midpoint wrt the four pixel coordinates.
    h = 0.5
    J = np.zeros((3, 4))
    for k in range(4):
        out = []
        for sgn in (1, -1):
            q = np.concatenate([pb, pa])
            q[k] += sgn * h
            r, _ = _triangulate_px(ob, oa, q[:2], q[2:])
            out.append(r[0] if r is not None else np.full(3, np.nan))
        J[:, k] = (out[0] - out[1]) / (2 * h)
    sp = args.pixel_sigma_px
    cov = sp ** 2 * J @ J.T
    mean_dir = (d1 + d2) / np.linalg.norm(d1 + d2)
    unc = {"sigma_m": rnd(sp * float(np.linalg.norm(J))),
           "sigma_xyz_m": rnd(np.sqrt(np.clip(np.diag(cov), 0, None))),
           "sigma_along_view_m": rnd(float(math.sqrt(max(0.0, mean_dir @ cov @ mean_dir)))),
           "covariance_m2": rnd(cov, 9),
           "basis": "1-sigma from pixel_sigma_px on both pixels; camera poses are measured (assumed exact); "
                    "a wrong correspondence is not covered"}
    reproj = {}
    for key, o, p in (("before", ob, pb), ("after", oa, pa)):
        uv, _ = project_points(o.K, o.E, X)
        reproj[key] = rnd(float(np.linalg.norm(uv[0] - p)), 3)
    prov["reprojection_error_px"] = reproj
    warnings = [f"pair flag {k} is false" for k, v in validity.items() if v is False]
    if angle < 2.0:
        warnings.append("small triangulation angle: depth is poorly constrained")
    if prov["ray_gap_m"] is not None and prov["ray_gap_m"] > max(0.01, 3 * (unc["sigma_m"] or 0)):
        warnings.append("large ray gap: the two pixels probably do not show the same point")
    if warnings:
        prov["warnings"] = warnings
    ok = all(v is not False for v in validity.values())
    far = outside_workspace(X)
    return ToolOutput(payload=estimate(rnd(X), "world_point", frame="world", units="m", provenance=prov,
                                       uncertainty=unc, valid=ok, failure=("OUTSIDE_WORKSPACE", far) if far else None))


# ==============================================================================================
# scale_from_object_size
# ==============================================================================================
class ScaleFromObjectSizeArgs(Args):
    obs_id: ObsId = Field(description="Observation in which the object's bounding box was read.")
    bbox: Annotated[list[PixelCoord], Field(min_length=4, max_length=4)] = Field(
        description="Object bounding box [x1, y1, x2, y2] in pixels of that image (x1 < x2, y1 < y2).")
    extent_axis: Literal["width", "height", "diagonal"] = Field(
        description="Which box extent matches the known size: 'width' (u), 'height' (v) or 'diagonal'.")
    known_extent_m: Annotated[float, bounded(1e-6, 10.0)] = Field(
        description="Your prior for the object's physical extent along that axis, metres.")
    known_extent_sigma_m: Annotated[float, bounded(0.0, 10.0)] | None = Field(
        default=None,
        description="Optional 1-sigma uncertainty of that prior, metres; without it the uncertainty is null.")

    @model_validator(mode="after")
    def _ordered(self):
        x1, y1, x2, y2 = self.bbox
        if not (x2 > x1 and y2 > y1):
            raise ValueError("bbox must be [x1, y1, x2, y2] with x1 < x2 and y1 < y2")
        return self


@tool(group="geometry", kind="read", result=Estimate)
def scale_from_object_size(ctx: RobotContext, args: ScaleFromObjectSizeArgs) -> ToolOutput:
    """Coarse camera depth (m, along the optical axis) of an object from its pixel bounding box and your prior
    of its physical extent: Z = f * known_extent / pixel_extent. Assumes the extent is roughly parallel to
    the image plane. Uncertainty is null unless you give known_extent_sigma_m. Also reports the implied world
    point at the box centre."""
    obs = ctx.obs.get(args.obs_id)
    x1, y1, x2, y2 = args.bbox
    fx, fy = float(obs.K[0, 0]), float(obs.K[1, 1])
    w_px, h_px = x2 - x1, y2 - y1
    if args.extent_axis == "width":
        pix, norm = w_px, w_px / fx
    elif args.extent_axis == "height":
        pix, norm = h_px, h_px / fy
    else:
        pix, norm = math.hypot(w_px, h_px), math.hypot(w_px / fx, h_px / fy)
    Z = args.known_extent_m / norm
    centre = [(x1 + x2) / 2, (y1 + y2) / 2]
    point = camera_to_world(obs.E, Z * back_project(obs.K, centre))
    unc = None
    if args.known_extent_sigma_m is not None:
        rel = args.known_extent_sigma_m / args.known_extent_m
        unc = {"sigma_m": rnd(Z * rel), "relative": rnd(rel), "terms": {"extent_prior_m": rnd(Z * rel)},
               "basis": "1-sigma from known_extent_sigma_m only; box placement and foreshortening are not included"}
    prov = {**_obs_prov(obs), "bbox": rnd(args.bbox, 3), "extent_axis": args.extent_axis, "pixel_extent_px": rnd(pix, 3),
            "normalized_extent": rnd(norm, 8), "focal_px": [rnd(fx, 4), rnd(fy, 4)],
            "known_extent_m": args.known_extent_m, "bbox_center_px": rnd(centre, 3),
            "bbox_in_frame": in_frame((x1, y1), obs.size_hw) and in_frame((x2 - 1e-9, y2 - 1e-9), obs.size_hw),
            "implied_point_at_bbox_center_world": rnd(point),
            "method": "Z = known_extent / (pixel_extent / f): pinhole similar triangles",
            "assumption": "the measured extent is parallel to the image plane at the object's depth; a tilted or "
                          "partly hidden extent biases Z"}
    failure: tuple[str, str] | None
    if pix < MIN_BOX_EXTENT_PX:
        failure = ("DEGENERATE_GEOMETRY", f"the box spans {pix:.3g} px along that extent (under {MIN_BOX_EXTENT_PX:g} px): "
                                          "no scale can be read from it")
    elif Z < MIN_ESTIMATE_DEPTH_M:
        failure = ("DEGENERATE_GEOMETRY", f"the implied depth {Z:.3g} m is under {MIN_ESTIMATE_DEPTH_M:g} m: the size "
                                          "prior and the box do not describe a visible object")
    else:
        far = outside_workspace(point)
        failure = ("OUTSIDE_WORKSPACE", far) if far else None
    return ToolOutput(payload=estimate(rnd(Z), "depth", frame=f"camera:{obs.obs_id}", units="m", provenance=prov,
                                       uncertainty=unc, coarse=True, failure=failure))


# ==============================================================================================
# gripper geometry (from the embodiment's public numbers)
# ==============================================================================================
@dataclass(frozen=True)
class GripperGeometry:
    """Finger geometry in the TCP frame (+x approach, +y opening line), from public numbers."""
    tip_ahead_m: float  # fingertip plane ahead of the TCP along approach
    link_behind_m: float  # finger-link origin behind the TCP
    inner_m: float  # finger-link origin -> inner (contact) face, toward the gripper centre
    outer_m: float  # finger-link origin -> outer side face
    half_height_m: float  # finger half extent along the TCP z axis
    flange_behind_m: float  # flange (EE) behind the TCP

    @classmethod
    def of(cls, ctx: RobotContext, arm: str) -> GripperGeometry:
        """Read the embodiment's declared finger facts (``facts["gripper"]``), with the FACTS §A.4
        numbers as fallbacks."""
        spec = ctx.arm(arm).gripper
        facts = ctx.emb.facts or {}
        g: dict[str, Any] = facts["gripper"] if isinstance(facts.get("gripper"), dict) else {}

        def num(*keys: str, default: float) -> float:
            for k in keys:
                for src in (g, facts):
                    if isinstance(src.get(k), (int, float)):
                        return float(src[k])
            return default

        return cls(tip_ahead_m=float(spec.tip_ahead_of_tcp_m),
                   link_behind_m=num("finger_origin_behind_tcp_m", "finger_link_origin_behind_tcp_m", default=0.0354),
                   inner_m=num("finger_origin_to_inner_pad_face_m", "finger_link_origin_to_side_face_m", default=0.010),
                   outer_m=num("finger_origin_to_outer_side_face_m", default=0.010),
                   half_height_m=num("finger_half_height_m", "pad_half_height_m", default=0.013),
                   flange_behind_m=float(ctx.emb.tcp_offset_m))

    def finger_corners_local(self, y: float, sign: float) -> np.ndarray:
        """8 corners (TCP frame) of the box of a finger whose link origin is at lateral offset
        ``y`` on the ``sign`` side (+1: +y side) of the gripper centre."""
        xs = (-self.link_behind_m, self.tip_ahead_m)
        ys = (y - sign * self.inner_m, y + sign * self.outer_m)
        zs = (-self.half_height_m, self.half_height_m)
        return np.array([[x, yy, z] for x in xs for yy in ys for z in zs])

    def inner_tip_local(self, y: float, sign: float) -> np.ndarray:
        """The fingertip point on the inner (contact) face of that finger."""
        return np.array([self.tip_ahead_m, y - sign * self.inner_m, 0.0])


def _to_world(pose_mat: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ pose_mat[:3, :3].T + pose_mat[:3, 3]


def _bbox(uv: np.ndarray) -> list | None:
    if uv.size == 0 or not np.all(np.isfinite(uv)):
        return None
    return rnd([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()], 1)


def _inner_tips_fk(ctx: RobotContext, arm: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """World inner-fingertip points of an arm from live FK, plus the TCP pose and finger links."""
    geo = GripperGeometry.of(ctx, arm)
    tcp = np.asarray(ctx.tcp_pose(arm), float)
    T = pose_to_mat(tcp)
    o = T[:3, 1]
    links = list(ctx.arm(arm).gripper.finger_links)
    poses = ctx.finger_link_poses(arm)
    ys = np.array([float(np.dot(np.asarray(poses[link], float)[:3] - tcp[:3], o)) for link in links])
    mean = float(ys.mean())
    tips = np.array([_to_world(T, geo.inner_tip_local(y, 1.0 if y >= mean else -1.0)[None])[0] for y in ys])
    return tips, tcp, links


# ==============================================================================================
# scale_from_gripper
# ==============================================================================================
class ScaleFromGripperArgs(Args):
    camera: CameraName = Field(
        description="Camera in which to measure the fingertips (a fresh image is captured).")
    arm: Arm = Field(description="Arm whose fingertips serve as the metric reference.")


@tool(group="geometry", kind="read", result=ObservationSummary, renders=True)
def scale_from_gripper(ctx: RobotContext, args: ScaleFromGripperArgs) -> ToolOutput:
    """Captures a fresh image and marks the two inner fingertip points of an arm (from forward kinematics) in
    it: their true distance (m), pixel endpoints, in-frame flags, pixel span, camera depths and metres per
    pixel along the segment. A metric scale reference valid near the fingertips' depth. Does not move the
    robot."""
    tips, tcp, links = _inner_tips_fk(ctx, args.arm)
    opening = quat_to_mat(tcp[3:])[:, 1]
    true_dist = float(np.linalg.norm(tips[0] - tips[1]))

    def paint(c: Canvas, K, E) -> dict:
        uv, z = project_points(K, E, tips)
        inf = [in_frame(None if not np.all(np.isfinite(p)) else p, c.size_hw) for p in uv]
        span = float(np.linalg.norm(uv[0] - uv[1])) if np.all(np.isfinite(uv)) else None
        failure = None
        if not all(inf):
            failure = "endpoint_out_of_frame"
        elif span is None or span < 2.0:
            failure = "degenerate_projected_span"
        colour = PALETTE[1][1] if failure is None else PALETTE[0][1]
        if np.all(np.isfinite(uv)):
            c.line(uv[0], uv[1], colour, width=2)
        for i, p in enumerate(uv):
            if np.all(np.isfinite(p)):
                c.circle(p, 5, colour, fill=True)
                w, h = c.text_size(str(i + 1))
                c.text((p[0] - w / 2, p[1] - h - 7), str(i + 1), colour)  # endpoint number above its dot
        mpp = true_dist / span if span else None
        if np.all(np.isfinite(uv)):
            mid = (uv[0] + uv[1]) / 2
            label = f"{true_dist * 100:.1f} cm"
            w, _ = c.text_size(label)
            c.text((mid[0] - w / 2, max(uv[0][1], uv[1][1]) + 9), label, colour)
        return {
            "tool": "scale_from_gripper", "arm": args.arm,
            "endpoints_world": rnd(tips), "endpoint_links": links,
            "true_dist_m": rnd(true_dist), "endpoints_px": rnd(uv, 2),
            "endpoint_in_frame": inf, "span_px": rnd(span, 3),
            "camera_depths_m": rnd(z), "meters_per_pixel_along_segment": rnd(mpp, 8),
            "valid_metric_reference": failure is None, "failure_reason": failure,
            "opening_axis_world": rnd(opening),
            "transfer_limit": ("metres per pixel holds only near the fingertips' camera depth "
                               f"(about {float(np.mean(z)):.3f} m) and for segments roughly parallel to this one; "
                               "it scales with depth elsewhere"),
            "source": "inner fingertip points from forward kinematics; the robot did not move",
        }

    obs = ctx.capture_annotated(args.camera, paint)
    return observation_output(obs)


# ==============================================================================================
# draw_marks
# ==============================================================================================
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


@tool(group="observation", kind="read", result=ObservationSummary)
def draw_marks(ctx: RobotContext, args: DrawMarksArgs) -> ToolOutput:
    """Draws 1-12 numbered, coloured markers with your labels at pixels of an existing observation and returns a
    new annotated observation (same camera, tick and calibration). Reports for each mark its colour, whether
    it is in frame and its label box. Pixels are [u, v] in that observation's image (top-left origin, u
    right, v down)."""
    src = ctx.obs.get(args.obs_id)

    def paint(c: Canvas) -> dict:
        marks = []
        for i, (px, label) in enumerate(zip(args.pixels, args.labels)):
            name, rgb = PALETTE[i % len(PALETTE)]
            box = c.numbered_marker(px, i + 1, label, rgb)
            marks.append({"index": i + 1, "px": rnd(px, 2), "label": label, "color": name,
                          "in_frame": in_frame(px, src.size_hw), "label_bbox_px": box})
        return {"tool": "draw_marks", "marks": marks,
                "note": "numbered markers drawn on a copy; pixel coordinates refer to the source image"}

    return observation_output(ctx.annotated_copy(src, paint))


# ==============================================================================================
# grasp_quat_candidates
# ==============================================================================================
def grasp_quats(approach, opening) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The two wxyz quaternions with +x = approach and +y = +/-opening (opening re-orthogonalised)."""
    a = np.asarray(approach, float)
    a = a / np.linalg.norm(a)
    o = np.asarray(opening, float)
    o = o - np.dot(o, a) * a
    o = o / np.linalg.norm(o)
    z = np.cross(a, o)
    q1 = mat_to_quat(np.stack([a, o, z], axis=1))
    q2 = mat_to_quat(np.stack([a, -o, -z], axis=1))
    return q1, q2, a, o


def _unit(v: list[float]) -> list[float]:
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


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


@tool(group="geometry", kind="read")
def grasp_quat_candidates(ctx: RobotContext | None, args: GraspQuatCandidatesArgs) -> ToolOutput:
    """Converts a gripper approach axis (wrist toward fingertips) and opening axis (finger line), both in world
    coordinates and orthogonal, into the two wxyz quaternions with TCP +x = approach and +y = +/- opening;
    they differ by a 180 degree roll about the approach axis. Pure conversion: unranked, no reachability
    check."""
    q1, q2, a, o = grasp_quats(args.approach_axis_world, args.opening_axis_world)
    cands = []
    for label, q, sign in (("A", q1, 1.0), ("B", q2, -1.0)):
        cands.append({"label": label, "quat_wxyz": rnd(q, 8), "approach_axis_world": rnd(a, 8),
                      "opening_axis_world": rnd(sign * o, 8), "orientation": orientation_block(q)})
    return ToolOutput(payload={
        "candidates": cands,
        "input_axes": {"approach_axis_world": rnd(a, 8), "opening_axis_world": rnd(o, 8)},
        "opening_axis_input_is_unoriented_line": True,
        "reachability_evaluated": False,
        "note": ("TCP +x = approach, +y = opening. A and B differ by a 180 deg roll about the approach axis and "
                 "close along the same line; they are unranked. Check reachability before moving."),
    })


# ==============================================================================================
# camera_aim_pose
# ==============================================================================================
def _rot_y(th: float) -> np.ndarray:
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_z(th: float) -> np.ndarray:
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def camera_arm(ctx: RobotContext, camera: str) -> str:
    for name in ctx.emb.arms:
        if camera.startswith(name):
            return name
    raise ToolArgumentError(f"no arm carries camera {camera!r}")


class CameraAimPoseArgs(Args):
    camera: WristCamera = Field(
        description="Wrist camera to aim: 'left_camera' (left arm) or 'right_camera' (right arm).")
    target_xyz: Vec3 = Field(description="World point [x, y, z] (metres) the camera should look at.")
    pitch: Annotated[float, bounded(60.0, 90.0)] = Field(
        default=80.0,
        description="Approach tilt below horizontal, degrees (60-90, default 80; 90 = approach straight down, "
                    "the top-down family); a rotation about world Y applied before the heading.")
    standoff: Annotated[float, bounded(0.05, 1.0)] = Field(
        default=0.28,
        description="Height of the TCP above the target's z, metres (default 0.28).")


@tool(group="geometry", kind="read")
def camera_aim_pose(ctx: RobotContext, args: CameraAimPoseArgs) -> ToolOutput:
    """Pure geometry: computes a TCP pose that points a wrist camera at a world target from a given pitch
    (degrees; 90 = approach straight down) with the TCP `standoff` metres above the target, using the
    calibrated camera mount. Returns the target TCP pose and the target's predicted pixel and depth in that
    camera. No planning, no motion; check reachability before moving."""
    arm = camera_arm(ctx, args.camera)
    spec = ctx.arm(arm)
    target = np.asarray(args.target_xyz, float)
    tcp_now = np.asarray(ctx.tcp_pose(arm), float)
    cam_now = np.asarray(ctx.sim.camera_pose(args.camera), float)
    mount = pose_mul(pose_inv(tcp_now), cam_now)  # camera pose in the TCP frame (fixed)
    Rm, tm = quat_to_mat(mount[3:]), mount[:3]

    # heading: horizontal direction from the arm's base toward the target (stable across calls)
    base = np.asarray(ctx.sim.get_link_pose(spec.base_link), float)[:3]
    hd = target[:2] - base[:2]
    if np.linalg.norm(hd) < 1e-3:
        hd = np.array([0.0, 1.0])
    yaw = math.atan2(hd[1], hd[0])
    R0 = _rot_z(yaw) @ _rot_y(math.radians(args.pitch))
    # of the two rolls about the approach axis, keep the one nearer the current wrist orientation
    options = [R0, R0 @ np.diag([1.0, -1.0, -1.0])]
    R = min(options, key=lambda r: quat_angle(mat_to_quat(r), tcp_now[3:]))
    q = mat_to_quat(R)
    zc = R @ Rm[:, 2]  # optical axis in world
    reason = None
    pos = None
    lam = None
    if zc[2] > -1e-3:
        reason = "at this pitch the camera would not look downward at the target; use a larger pitch"
    else:
        lam = -(args.standoff + float((R @ tm)[2])) / float(zc[2])
        if lam <= 0.05:
            reason = "the standoff is too small for this camera mount: the target would be behind or too near the camera"
        pos = target - lam * zc - R @ tm
    out: dict[str, Any] = {
        "valid": False, "camera": args.camera, "arm": arm, "target_xyz": rnd(target),
        "target_provenance": "caller_supplied_world_xyz", "pitch_deg": args.pitch, "standoff_m": args.standoff,
        "source_tick": ctx.tick, "current_tcp_pose_world": pose_block(tcp_now),
        "target_tcp_pose_world": None, "predicted_projection": None, "reason": reason,
        "note": ("pure geometry from the calibrated camera mount: no planning, no motion, no collision check. "
                 "Run check_tcp_pose_reachability before reach_tcp."),
    }
    if pos is not None:
        pose = np.concatenate([pos, q])
        cam_pose = pose_mul(pose, mount)
        E = extrinsic_from_pose(cam_pose)
        K = np.asarray(ctx.camera_K(args.camera), float)
        uv, z = project_points(K, E, target)
        h, w = ctx.sim.camera_size(args.camera)
        ok_px = bool(np.all(np.isfinite(uv[0])))
        out["target_tcp_pose_world"] = pose_block(pose)
        out["target_orientation"] = orientation_block(q)
        out["predicted_camera_pose_world"] = pose_block(cam_pose)
        out["predicted_projection"] = {
            "pixel_uv": rnd(uv[0], 2) if ok_px else None, "depth_m": rnd(z[0]),
            "projected_point_in_frame": in_frame(uv[0] if ok_px else None, (h, w)),
            "center_error_px": rnd(float(np.linalg.norm(uv[0] - [w / 2, h / 2])), 3) if ok_px else None}
        outside = [ax for i, ax in enumerate("xyz") if not WORKSPACE[ax][0] <= pos[i] <= WORKSPACE[ax][1]]
        if reason is None and outside:
            reason = f"target TCP outside the workspace envelope along {', '.join(outside)}"
        out["reason"] = reason
        out["valid"] = reason is None
    return ToolOutput(payload=out)


# ==============================================================================================
# preview_tcp_pose / compare_tcp_poses
# ==============================================================================================
@dataclass
class _Drawn:
    """A proposed gripper pose projected into an observation."""
    arm: str
    pose: np.ndarray
    gap: float
    gap_source: str
    T: np.ndarray
    fingers_world: list[np.ndarray]  # (8,3) corners per finger, sides (+opening, -opening)
    tips_world: np.ndarray  # (2,3)
    fingers_uv: list[np.ndarray]
    fingers_z: list[np.ndarray]
    tips_uv: np.ndarray
    centre_uv: np.ndarray
    centre_z: float
    geo: GripperGeometry


_SIDES = ("plus_opening", "minus_opening")


def _gripper_at(ctx: RobotContext, obs: Observation, arm: str, xyz, quat, gap: float | None) -> _Drawn:
    geo = GripperGeometry.of(ctx, arm)
    src = "argument"
    if gap is None:
        gap, src = float(ctx.finger_gap(arm)), "live_fk"
    pose = np.concatenate([np.asarray(xyz, float), np.asarray(quat, float)])
    T = pose_to_mat(pose)
    fingers: list[np.ndarray] = []
    tip_points: list[np.ndarray] = []
    for sign in (1.0, -1.0):
        y = sign * gap / 2
        fingers.append(_to_world(T, geo.finger_corners_local(y, sign)))
        tip_points.append(_to_world(T, geo.inner_tip_local(y, sign)[None])[0])
    tips = np.array(tip_points)
    fuv, fz = zip(*(project_points(obs.K, obs.E, f) for f in fingers))
    tuv, _ = project_points(obs.K, obs.E, tips)
    cuv, cz = project_points(obs.K, obs.E, pose[:3])
    return _Drawn(arm, pose, float(gap), src, T, fingers, tips, list(fuv), list(fz), tuv, cuv[0], float(cz[0]), geo)


def _paint_gripper(c: Canvas, g: _Drawn, obs: Observation, colour, tag: str | None = None) -> dict:
    K, E = obs.K, obs.E
    hw = obs.size_hw
    fingers = []
    for side, uv, z in zip(_SIDES, g.fingers_uv, g.fingers_z):
        front = bool(np.all(z > MIN_DEPTH_M))
        if front:
            c.polygon(convex_hull(uv), colour, fill_alpha=80)
        fingers.append({"side": side, "bbox_px": _bbox(uv) if front else None,
                        "fully_in_frame": front and all(in_frame(p, hw) for p in uv),
                        "partly_in_frame": front and any(in_frame(p, hw) for p in uv)})
    tips = []
    for side, p, w in zip(_SIDES, g.tips_uv, g.tips_world):
        ok = bool(np.all(np.isfinite(p)))
        if ok:
            c.circle(p, 4, (255, 255, 255), fill=True)
        tips.append({"side": side, "xyz": rnd(w), "px": rnd(p, 2) if ok else None, "in_frame": ok and in_frame(p, hw)})
    a = g.T[:3, 0]
    p0 = g.pose[:3]
    # approach arrow from the flange to the fingertip plane, with 1 cm ticks from the TCP
    seg = np.array([p0 - g.geo.flange_behind_m * a, p0 + g.geo.tip_ahead_m * a])
    suv, sz = project_points(K, E, seg)
    arrow = None
    if np.all(sz > MIN_DEPTH_M):
        c.arrow(suv[0], suv[1], colour, width=2)
        arrow = {"from_px": rnd(suv[0], 2), "to_px": rnd(suv[1], 2), "from": "flange", "to": "fingertip plane"}
        n_ticks = int(g.geo.flange_behind_m / 0.01)
        ticks = np.array([p0 - k * 0.01 * a for k in range(1, n_ticks + 1)])
        tuv, tz = project_points(K, E, ticks)
        d = suv[1] - suv[0]
        nd = float(np.linalg.norm(d))
        if nd > 1e-6:
            perp = np.array([-d[1], d[0]]) / nd * 4
            for q, zz in zip(tuv, tz):
                if zz > MIN_DEPTH_M:
                    c.line(q - perp, q + perp, colour, width=1)
        arrow["tick_spacing_m"] = 0.01
    axes_px = {}
    for k, name in enumerate(("approach", "opening", "normal")):
        tip = p0 + 0.04 * g.T[:3, k]
        uv, z = project_points(K, E, np.array([p0, tip]))
        if np.all(z > MIN_DEPTH_M):
            c.line(uv[0], uv[1], AXIS_COLOURS["xyz"[k]], width=2)
            axes_px[name] = rnd(uv, 2)
    centre_ok = bool(np.all(np.isfinite(g.centre_uv)))
    if centre_ok:
        c.cross(g.centre_uv, 6, (255, 255, 255), width=2)
        if tag:
            c.text((g.centre_uv[0] + 8, g.centre_uv[1] + 8), tag, colour)
    return {
        "arm": g.arm, "tcp_pose": pose_block(g.pose), "finger_gap_m": rnd(g.gap), "finger_gap_source": g.gap_source,
        "grasp_center": {"xyz": rnd(p0), "px": rnd(g.centre_uv, 2) if centre_ok else None,
                         "camera_depth_m": rnd(g.centre_z), "in_frame": centre_ok and in_frame(g.centre_uv, hw)},
        "inner_tips": tips, "fingers": fingers, "approach_arrow": arrow, "axes_px": axes_px,
        "orientation": orientation_block(g.pose[3:]),
        "in_view": {"grasp_center": centre_ok and in_frame(g.centre_uv, hw),
                    "any_finger": any(f["partly_in_frame"] for f in fingers),
                    "all_fingers": all(f["fully_in_frame"] for f in fingers)},
    }


def _silhouette_bbox(g: _Drawn) -> list | None:
    if not all(np.all(z > MIN_DEPTH_M) for z in g.fingers_z):
        return None
    return _bbox(np.vstack(g.fingers_uv))


_GRIPPER_NOTE = ("finger silhouettes are boxes from the embodiment's public finger dimensions (approximate collision "
                 "geometry); white dots = inner fingertips, white cross = grasp centre (TCP), arrow = flange to "
                 "fingertip plane with 1 cm ticks, axes red = approach, green = opening, blue = normal (4 cm). No "
                 "collision or reachability verdict.")


class PreviewTcpPoseArgs(Args):
    obs_id: ObsId = Field(
        description="Observation to draw into; it must be from the current tick (capture a fresh one after "
                    "any motion).")
    arm: Arm = Field(description="Arm whose gripper geometry to draw.")
    tcp_xyz: Vec3 = Field(description=_D_TCP)
    quat_wxyz: QuatWXYZ = Field(description=_D_QUAT)
    finger_gap_m: Annotated[float, bounded(*FINGER_GAP_RANGE_M)] | None = Field(default=None, description=_D_GAP)
    reference_px: Pixel | None = Field(
        default=None, description="Optional pixel [u, v] to report offsets to; exclusive with reference_xyz_world.")
    reference_xyz_world: Vec3 | None = Field(
        default=None, description="Optional world point [x, y, z] (m) to report offsets to; exclusive with "
                                  "reference_px.")

    @model_validator(mode="after")
    def _one_reference(self):
        if self.reference_px is not None and self.reference_xyz_world is not None:
            raise ValueError("give reference_px or reference_xyz_world, not both")
        return self


@tool(group="geometry", kind="read", result=ObservationSummary)
def preview_tcp_pose(ctx: RobotContext, args: PreviewTcpPoseArgs) -> ToolOutput:
    """Draws the gripper at a proposed TCP pose (world m, wxyz) into a current-tick observation: finger
    silhouettes, inner-tip markers, grasp centre, approach arrow with 1 cm ticks and axes, and returns a new
    annotated observation with pixel positions, per-finger boxes, in-view flags and optional offsets to a
    reference pixel or world point. No collision or reachability verdict."""
    src = ctx.obs.get(args.obs_id)
    require_current(ctx, src)
    g = _gripper_at(ctx, src, args.arm, args.tcp_xyz, args.quat_wxyz, args.finger_gap_m)

    def paint(c: Canvas) -> dict:
        colour = PALETTE[5][1] if args.arm == "left" else PALETTE[3][1]
        ann = {"tool": "preview_tcp_pose", **_paint_gripper(c, g, src, colour)}
        ref = None
        if args.reference_px is not None:
            rp = np.asarray(args.reference_px, float)
            C, d = pixel_ray(src.K, src.E, rp)
            closest = C + max(0.0, float(np.dot(g.pose[:3] - C, d))) * d
            seen = bool(np.all(np.isfinite(g.centre_uv)))
            ref = {"px": rnd(rp, 2), "in_frame": in_frame(rp, src.size_hw),
                   "delta_px_from_grasp_center": rnd(rp - g.centre_uv, 2) if seen else None,
                   "distance_px": rnd(float(np.linalg.norm(rp - g.centre_uv)), 2) if seen else None,
                   "grasp_center_to_ray_m": rnd(float(np.linalg.norm(g.pose[:3] - closest))),
                   "ray_point_nearest_grasp_center": rnd(closest)}
            c.circle(rp, 7, PALETTE[4][1], width=2)
        elif args.reference_xyz_world is not None:
            rw = np.asarray(args.reference_xyz_world, float)
            dw = rw - g.pose[:3]
            uv, z = project_points(src.K, src.E, rw)
            ok = bool(np.all(np.isfinite(uv[0])))
            ref = {"xyz": rnd(rw), "delta_world_m": rnd(dw), "distance_m": rnd(float(np.linalg.norm(dw))),
                   "delta_gripper_m": {"approach": rnd(float(dw @ g.T[:3, 0])), "opening": rnd(float(dw @ g.T[:3, 1])),
                                       "normal": rnd(float(dw @ g.T[:3, 2]))},
                   "px": rnd(uv[0], 2) if ok else None, "in_frame": ok and in_frame(uv[0], src.size_hw)}
            if ok:
                c.circle(uv[0], 7, PALETTE[4][1], width=2)
        ann["reference"] = ref
        ann["note"] = _GRIPPER_NOTE
        return ann

    return observation_output(ctx.annotated_copy(src, paint))


def _aabb(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return pts.min(axis=0), pts.max(axis=0)


def _iou(a: list | None, b: list | None) -> float | None:
    if a is None or b is None:
        return None
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


class TcpCandidate(Args):
    arm: Arm = Field(description="Arm this TCP pose is for.")
    tcp_xyz: Vec3 = Field(description=_D_TCP)
    quat_wxyz: QuatWXYZ = Field(description=_D_QUAT)
    finger_gap_m: Annotated[float, bounded(*FINGER_GAP_RANGE_M)] | None = Field(default=None, description=_D_GAP)


class CompareTcpPosesArgs(Args):
    obs_id: ObsId = Field(description="Observation to draw into; it must be from the current tick.")
    candidates: list[TcpCandidate] = Field(
        min_length=2, max_length=4, description="2-4 proposed TCP poses, drawn and numbered 1..n in this order.")


@tool(group="geometry", kind="read", result=ObservationSummary)
def compare_tcp_poses(ctx: RobotContext, args: CompareTcpPosesArgs) -> ToolOutput:
    """Draws 2-4 proposed TCP poses (numbered) into a current-tick observation and compares them pairwise: grasp
    centre offset and distance (m), approach angle (deg), finger-box overlap and separation for different
    arms, projected overlap and which is nearer to the camera. No collision or reachability verdict."""
    src = ctx.obs.get(args.obs_id)
    require_current(ctx, src)
    gs = [_gripper_at(ctx, src, c.arm, c.tcp_xyz, c.quat_wxyz, c.finger_gap_m) for c in args.candidates]

    def paint(c: Canvas) -> dict:
        cands = []
        for i, g in enumerate(gs):
            name, rgb = PALETTE[i]
            d = _paint_gripper(c, g, src, rgb, tag=str(i + 1))
            cands.append({"index": i + 1, "color": name, "arm": g.arm, "tcp_pose": d["tcp_pose"],
                          "finger_gap_m": d["finger_gap_m"], "finger_gap_source": d["finger_gap_source"],
                          "grasp_center_px": d["grasp_center"]["px"], "camera_depth_m": d["grasp_center"]["camera_depth_m"],
                          "in_view": d["in_view"], "orientation": d["orientation"], "axes_px": d["axes_px"],
                          "silhouette_bbox_px": _silhouette_bbox(g), "fingers": d["fingers"]})
        pairs = []
        for i in range(len(gs)):
            for j in range(i + 1, len(gs)):
                a, b = gs[i], gs[j]
                delta = b.pose[:3] - a.pose[:3]
                ang = math.degrees(math.acos(float(np.clip(a.T[:3, 0] @ b.T[:3, 0], -1, 1))))
                overlap = sep = None
                if a.arm != b.arm:
                    (lo1, hi1), (lo2, hi2) = _aabb(np.vstack(a.fingers_world)), _aabb(np.vstack(b.fingers_world))
                    gapv = np.maximum(0.0, np.maximum(lo1 - hi2, lo2 - hi1))
                    sep = float(np.linalg.norm(gapv))
                    overlap = bool(sep == 0.0)
                pairs.append({
                    "pair": [i + 1, j + 1], "same_arm": a.arm == b.arm,
                    "grasp_center_delta_m": rnd(delta), "grasp_center_distance_m": rnd(float(np.linalg.norm(delta))),
                    "approach_angle_deg": rnd(ang, 3),
                    "finger_bbox_overlap": overlap, "finger_separation_m": rnd(sep),
                    "projected_bbox_overlap": rnd(_iou(cands[i]["silhouette_bbox_px"], cands[j]["silhouette_bbox_px"]), 4),
                    "nearer_to_camera": (i + 1) if a.centre_z <= b.centre_z else (j + 1),
                })
        return {"tool": "compare_tcp_poses", "candidates": cands, "pairs": pairs,
                "note": _GRIPPER_NOTE + " finger_bbox_overlap/finger_separation_m use world axis-aligned boxes around "
                        "both fingers (different arms only); projected_bbox_overlap is the image IoU of the silhouettes."}

    return observation_output(ctx.annotated_copy(src, paint))
