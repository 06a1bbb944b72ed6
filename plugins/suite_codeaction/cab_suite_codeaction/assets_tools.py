"""Generated assets of the tool-use tasks: the desk bell (click_bell), the stapler (press_stapler),
the handheld barcode scanner and the tea box (scan_object).

Every object is built from primitives and a few revolved trimesh meshes, written into the asset
cache by :func:`~cab_core.kits.assets.mesh_asset` / :func:`~cab_core.kits.assets.urdf_asset`.
Frames: metres, +z up while the object stands (or lies) in its resting pose on the table, origin on
the table plane unless said otherwise. Variant counts follow upstream's model ids (bell {0, 1},
stapler 0-6, scanner 0-4, tea box 0-5); sizes are plausible real-world ones (upstream's meshes are
not public).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from cab_core.contracts.scene import Box, Cylinder, Shape
from cab_core.geometry import axis_angle_quat, quat_to_mat
from cab_core.kits.assets import box_inertia, hinged_urdf, mesh_shape, urdf_asset, urdf_inertial, urdf_part
from cab_core.kits.scene import body_pose, material, srgb

# x-axis primitives (SAPIEN cylinders) stood upright: local x -> world z
X_TO_Z = tuple(float(v) for v in axis_angle_quat([0.0, 1.0, 0.0], -np.pi / 2))
# a functional frame whose +z is the body's +x (the scanner's beam)
Z_TO_X = tuple(float(v) for v in axis_angle_quat([0.0, 1.0, 0.0], np.pi / 2))


_mat = partial(material, roughness=0.5)  # this module's default finish


def _revolved(profile: Sequence[Sequence[float]], sections: int = 40) -> Any:
    """A closed solid of revolution about z from (radius, z) points that start and end on the axis."""
    import trimesh

    return trimesh.creation.revolve(np.asarray(profile, dtype=float), sections=sections)


# =================================================================================================
# desk bell (click_bell)
# =================================================================================================
@dataclass(frozen=True)
class BellVariant:
    base_radius: float  # round foot
    base_height: float
    dome_radius: float  # hemispherical bell, resting on the foot
    dome_rgb: tuple[float, float, float]
    base_rgb: tuple[float, float, float]
    knob_rgb: tuple[float, float, float]


BELL_VARIANTS = (
    # chrome service bell on a black foot (8.6 cm wide, 7.6 cm tall)
    BellVariant(0.043, 0.013, 0.039, (0.80, 0.81, 0.83), (0.07, 0.07, 0.08), (0.85, 0.86, 0.88)),
    # brass bell on a dark wooden foot (10 cm wide, 8.8 cm tall)
    BellVariant(0.050, 0.018, 0.045, (0.85, 0.66, 0.28), (0.30, 0.17, 0.08), (0.88, 0.72, 0.35)),
)
BELL_ROD_RADIUS = 0.0035
BELL_ROD_LENGTH = 0.010  # plunger between the dome's top and the knob
BELL_KNOB_RADIUS = 0.009
BELL_KNOB_HEIGHT = 0.008


def bell_geometry(v: BellVariant) -> dict[str, float]:
    dome_base = v.base_height
    dome_top = dome_base + v.dome_radius
    knob_bottom = dome_top + BELL_ROD_LENGTH - 0.002  # the rod sinks 2 mm into the dome
    knob_top = knob_bottom + BELL_KNOB_HEIGHT
    return {"dome_base_z": dome_base, "dome_top_z": dome_top, "knob_bottom_z": knob_bottom, "knob_top_z": knob_top,
            "height": knob_top, "radius": v.base_radius}


def bell_shapes(model_id: int) -> list[Shape]:
    """A static desk bell: round foot, hemispherical dome (convex mesh), plunger rod, round knob.
    Body frame: origin at the centre of the foot's bottom, +z up."""
    v = BELL_VARIANTS[model_id]
    g = bell_geometry(v)
    dome = _mat(v.dome_rgb, roughness=0.15, metallic=0.95)
    foot = _mat(v.base_rgb, roughness=0.6)
    knob = _mat(v.knob_rgb, roughness=0.2, metallic=0.9)
    r = v.dome_radius
    arc = [(r * np.cos(a), g["dome_base_z"] + r * np.sin(a)) for a in np.linspace(0.0, np.pi / 2, 12)]
    dome_mesh = _revolved([(0.0, g["dome_base_z"]), *arc[:-1], (0.0, g["dome_top_z"])])
    foot_h = v.base_height
    rim = 0.004  # a bevelled rim under the dome
    return [
        Shape(Cylinder(v.base_radius, foot_h / 2), pose=body_pose((0, 0, foot_h / 2), X_TO_Z), material=foot),
        Shape(Cylinder(r + 0.002, rim / 2), pose=body_pose((0, 0, foot_h + rim / 2 - 0.001), X_TO_Z), material=dome,
              collision=False),
        mesh_shape(f"bell{model_id}_dome", dome_mesh, material=dome),
        Shape(Cylinder(BELL_ROD_RADIUS, BELL_ROD_LENGTH / 2),
              pose=body_pose((0, 0, g["dome_top_z"] + BELL_ROD_LENGTH / 2 - 0.002), X_TO_Z), material=knob),
        Shape(Cylinder(BELL_KNOB_RADIUS, BELL_KNOB_HEIGHT / 2),
              pose=body_pose((0, 0, g["knob_bottom_z"] + BELL_KNOB_HEIGHT / 2), X_TO_Z), material=knob),
    ]


# =================================================================================================
# stapler (press_stapler)
# =================================================================================================
@dataclass(frozen=True)
class StaplerVariant:
    length: float  # x, base plate
    width: float  # y
    arm_rgb: tuple[float, float, float]
    base_rgb: tuple[float, float, float]


STAPLER_VARIANTS = (
    StaplerVariant(0.160, 0.040, (0.10, 0.10, 0.11), (0.10, 0.10, 0.11)),  # black office stapler
    StaplerVariant(0.150, 0.038, (0.78, 0.08, 0.08), (0.12, 0.12, 0.13)),  # red top, black base
    StaplerVariant(0.170, 0.042, (0.62, 0.64, 0.67), (0.20, 0.20, 0.22)),  # metal
    StaplerVariant(0.140, 0.036, (0.10, 0.30, 0.75), (0.85, 0.86, 0.88)),  # blue on white
    StaplerVariant(0.155, 0.040, (0.92, 0.92, 0.90), (0.55, 0.57, 0.60)),  # white on grey
    StaplerVariant(0.130, 0.034, (0.10, 0.55, 0.25), (0.12, 0.12, 0.13)),  # green mini
    StaplerVariant(0.165, 0.044, (0.95, 0.60, 0.10), (0.15, 0.15, 0.16)),  # orange
)
STAPLER_BASE_T = 0.008  # base plate thickness
STAPLER_GAP = 0.007  # paper gap between the arm's bottom and the base plate at rest (front)
STAPLER_ARM_T = 0.026  # magazine + cover thickness
STAPLER_HINGE_BACK = 0.015  # hinge axis in front of the base plate's back end
STAPLER_FRONT_OVERHANG = 0.014  # the arm's nose stops this far behind the base plate's front
STAPLER_PRESS_FROM_FRONT = 0.035  # press point: on the cover, this far behind the arm's nose
STAPLER_ARM_MASS = 0.25  # kg
# The return spring: the arm's centre of mass sits this far behind the hinge axis, so gravity holds
# the arm up against its stop (0.25 kg x 9.81 x 0.025 m ~ 0.06 N m: about 0.5 N at the press point
# starts the press; released, the arm springs back).
STAPLER_COM_BEHIND_HINGE = 0.025
STAPLER_JOINT_DAMPING = 0.02
STAPLER_PRESS_TRAVEL = 0.06  # rad: the arm's nose comes down onto the anvil


def stapler_geometry(v: StaplerVariant) -> dict[str, Any]:
    """Base frame: origin at the base plate's bottom centre, +x toward the stapler's front (where
    the staple comes out), +z up. Arm frame: origin on the hinge axis, axes equal to the base
    frame's at rest (qpos 0); the joint turns about +y, positive closes (the nose goes down)."""
    L = v.length
    hinge_z = STAPLER_BASE_T + STAPLER_GAP + STAPLER_ARM_T / 2
    hinge = (-L / 2 + STAPLER_HINGE_BACK, 0.0, hinge_z)
    arm_len = L - STAPLER_HINGE_BACK - STAPLER_FRONT_OVERHANG + 0.010  # 1 cm behind the hinge too
    nose_x = arm_len - 0.010  # arm frame
    cover_t = 0.006
    top_z = STAPLER_ARM_T / 2 + cover_t  # arm frame
    press = (nose_x - STAPLER_PRESS_FROM_FRONT, 0.0, top_z)
    return {"hinge": hinge, "arm_length": arm_len, "nose_x": nose_x, "cover_t": cover_t, "top_z_arm": top_z,
            "press_point_arm": press, "height": hinge_z + top_z,
            # three contact points (arm frame), as upstream's annotation: 0 nose, 1 hinge top, 2 press
            "contact_points_arm": [(nose_x, 0.0, top_z - 0.008), (0.0, 0.0, top_z), press]}


def stapler_urdf(model_id: int) -> str:
    """Two links: ``base`` (plate, anvil, rear hinge block) and ``arm`` (magazine and cover) on the
    revolute ``hinge`` joint about +y (positive presses the nose down), range [0, 0.06] rad."""
    v = STAPLER_VARIANTS[model_id]
    g = stapler_geometry(v)
    L, W = v.length, v.width
    base_rgba = srgb(*v.base_rgb)
    arm_rgba = srgb(*v.arm_rgb)
    steel = srgb(0.72, 0.73, 0.75)
    dark = srgb(0.05, 0.05, 0.06)
    hx, _, hz = g["hinge"]
    bparts = [
        urdf_part("box", (L - W / 2, W, STAPLER_BASE_T), (-W / 4, 0, STAPLER_BASE_T / 2), rgba=base_rgba,
                  material="base"),
        # rounded front end of the base plate
        urdf_part("cylinder", (W / 2, STAPLER_BASE_T), (L / 2 - W / 2, 0, STAPLER_BASE_T / 2), rgba=base_rgba,
                  material="base"),
        # anvil plate under the nose (visual)
        urdf_part("box", (0.03, W * 0.6, 0.001), (L / 2 - STAPLER_FRONT_OVERHANG - 0.02, 0, STAPLER_BASE_T + 0.0005),
                  rgba=steel, material="anvil", collision=False),
        # rear block carrying the hinge pin
        urdf_part("box", (0.03, W, hz - STAPLER_BASE_T),
                  (-L / 2 + 0.015, 0, STAPLER_BASE_T + (hz - STAPLER_BASE_T) / 2),
                  rgba=base_rgba, material="base"),
        urdf_part("cylinder", (0.004, W + 0.004), (hx, 0, hz), rpy=(np.pi / 2, 0, 0), rgba=steel, material="pin",
                  collision=False),
    ]
    arm_len, nose = g["arm_length"], g["nose_x"]
    ct = g["cover_t"]
    aparts = [
        # magazine channel (slightly narrower than the cover)
        urdf_part("box", (arm_len - 0.012, W * 0.8, STAPLER_ARM_T), (arm_len / 2 - 0.010 - 0.006, 0, 0),
                  rgba=dark, material="magazine"),
        # cover on top, over the whole length
        urdf_part("box", (arm_len, W, ct), (arm_len / 2 - 0.010, 0, STAPLER_ARM_T / 2 + ct / 2), rgba=arm_rgba,
                  material="cover"),
        # rounded nose
        urdf_part("cylinder", (STAPLER_ARM_T / 2 + ct / 2, W), (nose - STAPLER_ARM_T / 2 - ct / 2, 0, ct / 2),
                  rpy=(np.pi / 2, 0, 0),
                  rgba=arm_rgba, material="cover"),
        # side skirts of the cover (visual)
        urdf_part("box", (arm_len * 0.85, 0.002, STAPLER_ARM_T * 0.7), (arm_len * 0.45, W / 2 - 0.001, 0.004),
                  rgba=arm_rgba, material="cover", collision=False),
        urdf_part("box", (arm_len * 0.85, 0.002, STAPLER_ARM_T * 0.7), (arm_len * 0.45, -W / 2 + 0.001, 0.004),
                  rgba=arm_rgba, material="cover", collision=False),
        # raised spine on the cover's rear part (the classic stapler's hump)
        urdf_part("box", (g["press_point_arm"][0] - 0.02, W * 0.7, 0.005),
                  ((g["press_point_arm"][0] - 0.02) / 2 - 0.006, 0, STAPLER_ARM_T / 2 + ct + 0.0025), rgba=arm_rgba,
                  material="cover"),
        # steel strip over the nose (visual)
        urdf_part("box", (0.012, W + 0.001, STAPLER_ARM_T * 0.8), (nose - 0.012, 0, 0), rgba=steel,
                  material="strip", collision=False),
        # press pad: a slightly darker oval on the cover where a thumb would go (visual)
        urdf_part("cylinder", (0.012, 0.001), (g["press_point_arm"][0], 0, g["top_z_arm"] + 0.0005),
                  rgba=srgb(*(0.6 * c for c in v.arm_rgb)), material="pad", collision=False),
    ]
    base_inertial = urdf_inertial(0.3, (0, 0, STAPLER_BASE_T), box_inertia(0.3, (L, W, STAPLER_BASE_T * 2)))
    arm_inertial = urdf_inertial(STAPLER_ARM_MASS, (-STAPLER_COM_BEHIND_HINGE, 0, 0),
                                 box_inertia(STAPLER_ARM_MASS, (arm_len, W, STAPLER_ARM_T)))
    return hinged_urdf(f"stapler{model_id}", base_inertial=base_inertial, base_parts=bparts, child="arm",
                       child_inertial=arm_inertial, child_parts=aparts, joint="hinge", origin=(hx, 0, hz),
                       axis="0 1 0", upper=STAPLER_PRESS_TRAVEL, velocity=5, damping=STAPLER_JOINT_DAMPING,
                       friction=0)


def stapler_asset(model_id: int) -> str:
    return urdf_asset(f"stapler{model_id}", stapler_urdf(model_id))


def stapler_arm_point(v: StaplerVariant, q: float, p_arm: Sequence[float]) -> np.ndarray:
    """An arm-frame point in the base frame with the hinge at ``q``."""
    g = stapler_geometry(v)
    c, s = np.cos(q), np.sin(q)
    ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return np.asarray(g["hinge"], float) + ry @ np.asarray(p_arm, float)


# =================================================================================================
# handheld barcode scanner (scan_object)
# =================================================================================================
@dataclass(frozen=True)
class ScannerVariant:
    head_length: float  # x, behind the nose
    head_width: float  # y (in the gun's plane)
    thickness: float  # z while lying on its side (the window's long side)
    handle_length: float
    handle_width: float  # across the handle, in the gun's plane: what the fingers close on
    handle_angle_deg: float  # handle rake, from the gun's "down" (-y) toward the back (-x)
    body_rgb: tuple[float, float, float]
    grip_rgb: tuple[float, float, float]


SCANNER_VARIANTS = (
    ScannerVariant(0.080, 0.044, 0.044, 0.105, 0.032, 18.0, (0.12, 0.12, 0.13), (0.20, 0.20, 0.22)),  # black
    ScannerVariant(0.075, 0.046, 0.046, 0.100, 0.033, 15.0, (0.95, 0.75, 0.10), (0.10, 0.10, 0.10)),  # yellow/black
    ScannerVariant(0.085, 0.042, 0.042, 0.110, 0.030, 20.0, (0.85, 0.86, 0.88), (0.35, 0.37, 0.40)),  # white/grey
    ScannerVariant(0.078, 0.045, 0.045, 0.100, 0.034, 12.0, (0.15, 0.35, 0.75), (0.12, 0.12, 0.13)),  # blue
    ScannerVariant(0.082, 0.044, 0.043, 0.108, 0.031, 22.0, (0.30, 0.31, 0.33), (0.85, 0.40, 0.08)),  # grey/orange
)
SCANNER_NOSE_LEN = 0.016
SCANNER_NOSE_FLARE = 0.005  # the nose is this much wider than the head on each side
SCANNER_MASS = 0.16
SCANNER_FRICTION = 0.9  # rubberised grip
SCANNER_HANDLE_ROOT_IN = 0.010  # the handle's axis starts this far inside the head's -y side
SCANNER_GRASP_ALONG = 0.060  # grasp point: this far along the handle's axis from the head's side
SCANNER_TRIGGER_ALONG = 0.022  # trigger centre along the handle axis from the head's side


def scanner_geometry(v: ScannerVariant) -> dict[str, Any]:
    """Body frame (the scanner lying on its side): origin on the table at the centre of the
    footprint's bounding box; +x the beam direction, +z up; the head (nose and window at its +x
    end) runs along x, the handle leaves the head's -y side, raked back toward -x by
    ``handle_angle_deg``. The window is the nose's front face.

    Returned points are in the body frame; ``rects`` is the footprint as (centre xy, half size xy,
    yaw) rectangles."""
    a = np.radians(v.handle_angle_deg)
    d = np.array([-np.sin(a), -np.cos(a), 0.0])  # handle axis, away from the head
    front = np.array([np.cos(a), -np.sin(a), 0.0])  # across the handle, toward the trigger side (+x)
    T = v.thickness
    ht = T - 0.006
    # first in a nose frame: x = 0 at the window, y = 0 on the head's centre line
    head = ((-SCANNER_NOSE_LEN - v.head_length + (-SCANNER_NOSE_LEN)) / 2, 0.0)
    head_half = (v.head_length / 2, v.head_width / 2)
    nose = (-SCANNER_NOSE_LEN / 2, 0.0)
    nose_half = (SCANNER_NOSE_LEN / 2, v.head_width / 2 + SCANNER_NOSE_FLARE)
    root = np.array([-SCANNER_NOSE_LEN - v.head_length + 0.032, -v.head_width / 2 + SCANNER_HANDLE_ROOT_IN, 0.0])
    side = root + d * (SCANNER_HANDLE_ROOT_IN / np.cos(a))  # where the axis leaves the head
    handle_c = root + d * (v.handle_length / 2)
    yaw_h = float(np.arctan2(d[1], d[0]))
    rects = [(head, head_half, 0.0), (nose, nose_half, 0.0), ((handle_c[0], handle_c[1]),
                                                                (v.handle_length / 2, v.handle_width / 2), yaw_h)]
    pts = []
    for (cx, cy), (hx, hy), yaw in rects:
        c, s = np.cos(yaw), np.sin(yaw)
        for sx in (-1, 1):
            for sy in (-1, 1):
                pts.append((cx + c * sx * hx - s * sy * hy, cy + s * sx * hx + c * sy * hy))
    pts = np.asarray(pts)
    off = np.r_[(pts.min(axis=0) + pts.max(axis=0)) / 2, 0.0]

    def sh(p):
        return np.asarray(p, float) - off

    grasp = side + d * SCANNER_GRASP_ALONG
    grasp[2] = ht / 2
    trigger = side + d * SCANNER_TRIGGER_ALONG + front * (v.handle_width / 2 + 0.005)
    return {
        "thickness": T, "handle_thickness": ht, "handle_axis": d, "handle_front": front, "handle_yaw": yaw_h,
        "head_centre": sh((*head, T / 2)), "head_half": (*head_half, T / 2),
        "nose_centre": sh((*nose, T / 2)), "nose_half": (*nose_half, T / 2),
        "handle_centre": sh((handle_c[0], handle_c[1], ht / 2)),
        "handle_half": (v.handle_length / 2, v.handle_width / 2, ht / 2),
        "trigger_centre": sh((trigger[0], trigger[1], ht / 2)),
        "grasp_point": sh(grasp),
        "window_point": sh((0.0, 0.0, T / 2)),
        "rects": [((float(cx - off[0]), float(cy - off[1])), hh, yaw) for (cx, cy), hh, yaw in rects],
        "extent": tuple(float(v) for v in pts.max(axis=0) - pts.min(axis=0)),
    }


def scanner_shapes(model_id: int) -> list[Shape]:
    v = SCANNER_VARIANTS[model_id]
    g = scanner_geometry(v)
    body = _mat(v.body_rgb, roughness=0.45, friction=SCANNER_FRICTION)
    grip = _mat(v.grip_rgb, roughness=0.8, friction=SCANNER_FRICTION)
    glass = _mat((0.60, 0.05, 0.05), roughness=0.1, metallic=0.2)
    qh = tuple(float(c) for c in axis_angle_quat([0.0, 0.0, 1.0], g["handle_yaw"]))
    w = g["window_point"]
    nh = g["nose_half"]
    return [
        Shape(Box(g["head_half"]), pose=body_pose(g["head_centre"]), material=body),
        Shape(Box(nh), pose=body_pose(g["nose_centre"]), material=body),
        # the window (red exit glass) on the nose's front face
        Shape(Box((0.001, nh[1] - 0.004, nh[2] - 0.006)), pose=body_pose((w[0] + 0.0005, w[1], w[2])), material=glass,
              collision=False),
        Shape(Box(g["handle_half"]), pose=body_pose(g["handle_centre"], qh), material=grip),
        # trigger on the handle's front side, next to the head
        Shape(Box((0.009, 0.006, g["handle_half"][2] - 0.005)), pose=body_pose(g["trigger_centre"], qh), material=grip),
    ]


def footprint_distance(rects_a, pose_a, rects_b, pose_b) -> float:
    """A lower bound on the planar distance between two footprints (lists of rectangles in body
    frames, placed by world poses): the smallest distance from a corner or edge midpoint of one to
    a rectangle of the other, both ways (0 when they overlap)."""
    def world_rects(rects, pose):
        yaw0 = float(np.arctan2(quat_to_mat(pose[3:])[1, 0], quat_to_mat(pose[3:])[0, 0]))
        c0, s0 = np.cos(yaw0), np.sin(yaw0)
        out = []
        for (cx, cy), (hx, hy), yaw in rects:
            out.append(((pose[0] + c0 * cx - s0 * cy, pose[1] + s0 * cx + c0 * cy), (hx, hy), yaw + yaw0))
        return out

    def samples(r):
        (cx, cy), (hx, hy), yaw = r
        c, s = np.cos(yaw), np.sin(yaw)
        for u, v in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1), (0, 0)):
            yield np.array([cx + c * u * hx - s * v * hy, cy + s * u * hx + c * v * hy])

    def dist(p, r):
        (cx, cy), (hx, hy), yaw = r
        c, s = np.cos(yaw), np.sin(yaw)
        q = np.array([c * (p[0] - cx) + s * (p[1] - cy), -s * (p[0] - cx) + c * (p[1] - cy)])
        return float(np.hypot(max(abs(q[0]) - hx, 0.0), max(abs(q[1]) - hy, 0.0)))

    ra, rb = world_rects(rects_a, pose_a), world_rects(rects_b, pose_b)
    best = np.inf
    for x, y in ((ra, rb), (rb, ra)):
        for r in x:
            for p in samples(r):
                best = min(best, min(dist(p, q) for q in y))
    return best


# =================================================================================================
# tea box (scan_object)
# =================================================================================================
@dataclass(frozen=True)
class TeaBoxVariant:
    size: tuple[float, float, float]  # x (the long side of the footprint), y (what a grasp spans), z
    rgb: tuple[float, float, float]
    band_rgb: tuple[float, float, float]


TEABOX_VARIANTS = (
    TeaBoxVariant((0.085, 0.060, 0.120), (0.15, 0.45, 0.20), (0.90, 0.80, 0.30)),  # green tea
    TeaBoxVariant((0.078, 0.056, 0.110), (0.70, 0.10, 0.12), (0.95, 0.90, 0.80)),  # red (black tea)
    TeaBoxVariant((0.090, 0.064, 0.105), (0.95, 0.78, 0.20), (0.35, 0.20, 0.10)),  # yellow (chamomile)
    TeaBoxVariant((0.080, 0.052, 0.125), (0.15, 0.25, 0.60), (0.92, 0.92, 0.92)),  # blue (earl grey)
    TeaBoxVariant((0.072, 0.058, 0.115), (0.45, 0.28, 0.15), (0.90, 0.75, 0.45)),  # brown (rooibos)
    TeaBoxVariant((0.088, 0.062, 0.118), (0.45, 0.20, 0.50), (0.95, 0.85, 0.95)),  # purple (berry)
)
TEABOX_MASS = 0.12
TEABOX_FRICTION = 0.8


def teabox_shapes(model_id: int) -> list[Shape]:
    """A cardboard tea box standing upright. Body frame: origin at the box's centre, +x along its
    long side, +z up. A lid band and a label on the two large faces (visual)."""
    v = TEABOX_VARIANTS[model_id]
    sx, sy, sz = v.size
    card = _mat(v.rgb, roughness=0.7, friction=TEABOX_FRICTION)
    band = _mat(v.band_rgb, roughness=0.6)
    label = _mat((0.97, 0.96, 0.92), roughness=0.8)
    e = 0.0008
    return [
        Shape(Box((sx / 2, sy / 2, sz / 2)), material=card),
        # the lid: a band of another colour round the top (1 mm proud of the box, no z-fighting)
        Shape(Box((sx / 2 + e, sy / 2 + e, 0.0125)), pose=body_pose((0, 0, sz / 2 - 0.012)), material=band,
              collision=False),
        Shape(Box((sx * 0.32, e, sz * 0.18)), pose=body_pose((0, sy / 2 + e / 2, -sz * 0.08)), material=label,
              collision=False),
        Shape(Box((sx * 0.32, e, sz * 0.18)), pose=body_pose((0, -sy / 2 - e / 2, -sz * 0.08)), material=label,
              collision=False),
    ]


# =================================================================================================
# contact attribution shared by the tasks
# =================================================================================================
def gripper_bodies(embodiment: Any) -> dict[str, list[str]] | None:
    """Per arm, the robot bodies that count as its gripper (the gripper housing, i.e. the
    embodiment's ee link, and both fingers), as contact names; None without an embodiment."""
    if embodiment is None or not getattr(embodiment, "arms", None):
        return None
    return {a: [f"robot/{s.ee_link}", *(f"robot/{link}" for link in s.gripper.finger_links)]
            for a, s in sorted(embodiment.arms.items())}


def is_gripper(name: str, bodies: dict[str, list[str]] | None) -> bool:
    if bodies is None:  # built without an embodiment: any robot body
        return name.startswith("robot/")
    return any(name in v for v in bodies.values())
