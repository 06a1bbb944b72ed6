"""Generate the aloha_agilex URDF and SRDF text from :class:`AlohaParams` (deterministic).

Only URDF primitives (box, cylinder) are used, so SAPIEN, PyBullet, MuJoCo and mplib (urdfdom +
FCL) all read the same file. Collision shapes equal the visual shapes except for decorations
(wheels, head-camera housing, lenses), which are visual only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cab_core.geometry import euler_quat, pose_inv, quat_to_mat, transform_point

from .kinematics import joint_frames, mount_offset
from .params import ARM_PREFIX, AlohaParams

HALF_PI = float(np.pi / 2)

# linear RGBA
BODY = (0.18, 0.19, 0.21, 1.0)
BODY_LIGHT = (0.55, 0.57, 0.60, 1.0)
JOINT = (0.05, 0.05, 0.06, 1.0)
ARM_SHELL = (0.80, 0.81, 0.83, 1.0)
GRIPPER = (0.12, 0.12, 0.13, 1.0)
FINGER = (0.62, 0.64, 0.68, 1.0)
PAD = (0.03, 0.03, 0.03, 1.0)
LENS = (0.02, 0.02, 0.10, 1.0)
ACCENT = (0.10, 0.35, 0.75, 1.0)


@dataclass(frozen=True)
class Prim:
    kind: str  # "box" (size = full extents) or "cyl" (size = (radius, length))
    size: tuple[float, ...]
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float, float] = ARM_SHELL
    collision: bool = True


def _f(v: float) -> str:
    s = f"{float(v):.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _v(vals) -> str:
    return " ".join(_f(v) for v in vals)


def _cyl(axis: str, radius: float, length: float, xyz=(0.0, 0.0, 0.0), color=JOINT,
         collision: bool = True) -> Prim:
    rpy = {"x": (0.0, HALF_PI, 0.0), "y": (HALF_PI, 0.0, 0.0), "z": (0.0, 0.0, 0.0)}[axis]
    return Prim("cyl", (radius, length), tuple(xyz), rpy, color, collision)


def _box_span(x0, x1, y0, y1, z0, z1, color=ARM_SHELL, collision: bool = True) -> Prim:
    return Prim("box", (x1 - x0, y1 - y0, z1 - z0), ((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2),
                (0.0, 0.0, 0.0), color, collision)


def mat_to_rpy(m) -> tuple[float, float, float]:
    """URDF rpy (fixed-axis x, then y, then z) of a rotation matrix."""
    m = np.asarray(m, dtype=float)
    pitch = float(np.arcsin(-np.clip(m[2, 0], -1.0, 1.0)))
    if abs(np.cos(pitch)) > 1e-9:
        roll = float(np.arctan2(m[2, 1], m[2, 2]))
        yaw = float(np.arctan2(m[1, 0], m[0, 0]))
    else:  # gimbal lock
        roll = float(np.arctan2(-m[1, 2], m[1, 1]))
        yaw = 0.0
    return roll, pitch, yaw


def wrist_camera_rotation(p: AlohaParams) -> np.ndarray:
    """Columns = OpenCV camera axes (x right, y down, z forward) in the flange frame."""
    a = np.deg2rad(p.wrist_cam_pitch_deg)
    z = np.array([np.cos(a), 0.0, -np.sin(a)])
    x = np.array([0.0, -1.0, 0.0])
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


# ------------------------------------------------------------------------------------------
# link geometry


def _body_prims(p: AlohaParams) -> list[Prim]:
    """Wheeled chassis, a column, a spine running forward to a transverse shoulder beam that
    carries both arm mounts, and a post holding the head camera."""
    zt = p.shoulder_z
    sx = p.shoulder_x
    span = p.shoulder_y + 0.06
    cam = _head_cam_robot(p)
    return [
        _box_span(-0.36, 0.26, -0.26, 0.26, 0.06, 0.30, BODY),  # mobile chassis
        _box_span(-0.30, 0.20, -0.24, 0.24, 0.30, 0.33, BODY_LIGHT),  # top deck
        *[_cyl("y", 0.075, 0.06, (x, y, 0.075), JOINT, collision=False)
          for x in (-0.24, 0.16) for y in (-0.27, 0.27)],  # wheels
        _box_span(-0.14, 0.02, -0.14, 0.14, 0.33, zt - 0.05, BODY),  # column
        _box_span(0.02, 0.026, -0.10, 0.10, zt - 0.36, zt - 0.16, ACCENT, collision=False),  # badge
        _box_span(-0.14, sx + 0.05, -0.06, 0.06, zt - 0.05, zt, BODY_LIGHT),  # spine
        _box_span(sx - 0.05, sx + 0.05, -span, span, zt - 0.05, zt, BODY_LIGHT),  # shoulder beam
        _box_span(sx - 0.02, sx + 0.02, -0.02, 0.02, zt, cam[2] + 0.035, BODY),  # camera post
        _box_span(sx + 0.02, cam[0] - 0.05, -0.02, cam[1] + 0.02, cam[2] + 0.005, cam[2] + 0.035,
                  BODY),  # camera boom
        _box_span(cam[0] - 0.05, cam[0] - 0.006, cam[1] - 0.05, cam[1] + 0.05, cam[2] - 0.005,
                  cam[2] + 0.035, GRIPPER, collision=False),  # head-camera housing
    ]


def _head_cam_robot(p: AlohaParams) -> np.ndarray:
    return transform_point(pose_inv(p.base_pose), p.head_cam_pos)


def _arm_prims(p: AlohaParams) -> dict[str, list[Prim]]:
    """Geometry of each arm link, keyed by the link suffix (frames as documented in params)."""
    fx = p.finger_tip_length
    cam = np.asarray(p.wrist_cam_pos)
    return {
        "base_link": [_cyl("z", 0.052, p.h_base, (0, 0, p.h_base / 2), JOINT)],
        "link1": [_cyl("z", 0.05, 0.025, (0, 0, 0.0125), JOINT)],
        "link2": [
            _cyl("y", 0.042, 0.09, (0, 0, 0), JOINT),
            _box_span(-0.03, 0.03, -0.03, 0.03, 0.04, p.upper_arm - 0.04, ARM_SHELL),
            _cyl("y", 0.038, 0.085, (0, 0, p.upper_arm), JOINT),
        ],
        "link3": [_box_span(0.04, p.forearm - 0.05, -0.025, 0.025, -0.025, 0.025, ARM_SHELL)],
        "link4": [
            _cyl("y", 0.03, 0.062, (0, 0, 0), JOINT),
            _box_span(0.025, p.wrist1 - 0.02, -0.018, 0.018, -0.018, 0.018, ARM_SHELL),
        ],
        "link5": [
            _cyl("z", 0.028, 0.056, (0, 0, 0), JOINT),
            _box_span(0.0, p.wrist2, -0.018, 0.018, -0.018, 0.018, ARM_SHELL),
        ],
        "link6": [
            _cyl("x", 0.036, 0.02, (0.01, 0, 0), JOINT),
            _box_span(0.02, 0.072, -0.045, 0.045, -0.03, 0.03, GRIPPER),  # gripper housing
            _box_span(0.06, 0.074, -0.085, 0.085, -0.012, 0.012, GRIPPER),  # finger rail
            # wrist camera: body, an L bracket (plate on the housing, post behind the camera), lens
            _box_span(cam[0] - 0.024, cam[0], -0.04, 0.04, cam[2] - 0.012, cam[2] + 0.012, GRIPPER),
            _box_span(cam[0] - 0.024, 0.05, -0.015, 0.015, 0.03, 0.04, GRIPPER),
            _box_span(cam[0] - 0.024, cam[0] - 0.004, -0.015, 0.015, 0.04, cam[2] - 0.012, GRIPPER),
            _cyl("x", 0.008, 0.004, (cam[0] + 0.001, 0, cam[2]), LENS, collision=False),
        ],
        # finger +y (link7); link8 is its mirror image in y
        "finger": [
            _box_span(-0.01, 0.016, -0.015, p.finger_side_face, -0.015, 0.015, FINGER),
            _box_span(0.012, fx, -p.pad_inner_offset, -p.pad_inner_offset + p.pad_thickness,
                      -p.pad_half_height, p.pad_half_height, PAD),
        ],
    }


def _mirror_y(prims: list[Prim]) -> list[Prim]:
    return [Prim(q.kind, q.size, (q.xyz[0], -q.xyz[1], q.xyz[2]), q.rpy, q.color, q.collision)
            for q in prims]


def _inertial(prims: list[Prim], mass: float) -> tuple[tuple[float, float, float], tuple[float, ...]]:
    """COM and diagonal inertia of a solid box spanning the bounding box of ``prims``."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for q in prims:
        if q.kind == "box":
            half = np.asarray(q.size) / 2
        else:
            r, length = q.size
            half = np.abs(quat_to_mat(euler_quat(*q.rpy))) @ np.array([r, r, length / 2])
        lo = np.minimum(lo, np.asarray(q.xyz) - half)
        hi = np.maximum(hi, np.asarray(q.xyz) + half)
    d = hi - lo
    com = tuple(float(v) for v in (lo + hi) / 2)
    ixx = mass * (d[1] ** 2 + d[2] ** 2) / 12
    iyy = mass * (d[0] ** 2 + d[2] ** 2) / 12
    izz = mass * (d[0] ** 2 + d[1] ** 2) / 12
    return com, (ixx, iyy, izz)


# ------------------------------------------------------------------------------------------
# XML writer


class _Writer:
    def __init__(self, name: str):
        self.lines = ['<?xml version="1.0"?>',
                      "<!-- generated by cab_embodiment_aloha; do not edit -->",
                      f'<robot name="{name}">']
        self._materials: dict[tuple, str] = {}

    def _mat(self, color) -> str:
        key = tuple(round(c, 4) for c in color)
        if key not in self._materials:
            self._materials[key] = f"c{len(self._materials)}"
            name = self._materials[key]
            self.lines.append(f'  <material name="{name}"><color rgba="{_v(key)}"/></material>')
        return self._materials[key]

    def link(self, name: str, prims: list[Prim], mass: float, inertial=None):
        mats = [self._mat(q.color) for q in prims]
        out = [f'  <link name="{name}">']
        if prims:
            com, diag = inertial or _inertial(prims, mass)
        else:
            com, diag = (0.0, 0.0, 0.0), (1e-6, 1e-6, 1e-6)
        out += [
            "    <inertial>",
            f'      <origin xyz="{_v(com)}" rpy="0 0 0"/>',
            f'      <mass value="{_f(mass)}"/>',
            f'      <inertia ixx="{_f(diag[0])}" ixy="0" ixz="0" iyy="{_f(diag[1])}" iyz="0" '
            f'izz="{_f(diag[2])}"/>',
            "    </inertial>",
        ]
        for q, m in zip(prims, mats):
            geom = (f'<box size="{_v(q.size)}"/>' if q.kind == "box"
                    else f'<cylinder radius="{_f(q.size[0])}" length="{_f(q.size[1])}"/>')
            origin = f'<origin xyz="{_v(q.xyz)}" rpy="{_v(q.rpy)}"/>'
            out.append(f"    <visual>{origin}<geometry>{geom}</geometry><material name=\"{m}\"/></visual>")
            if q.collision:
                out.append(f"    <collision>{origin}<geometry>{geom}</geometry></collision>")
        out.append("  </link>")
        self.lines += out

    def joint(self, name: str, kind: str, parent: str, child: str, xyz, rpy=(0.0, 0.0, 0.0),
              axis=None, limit=None, effort: float = 0.0, velocity: float = 0.0):
        out = [f'  <joint name="{name}" type="{kind}">',
               f'    <parent link="{parent}"/>', f'    <child link="{child}"/>',
               f'    <origin xyz="{_v(xyz)}" rpy="{_v(rpy)}"/>']
        if axis is not None:
            out.append(f'    <axis xyz="{_v(axis)}"/>')
        if limit is not None:
            out.append(f'    <limit lower="{_f(limit[0])}" upper="{_f(limit[1])}" '
                       f'effort="{_f(effort)}" velocity="{_f(velocity)}"/>')
        out.append("  </joint>")
        self.lines += out

    def text(self) -> str:
        return "\n".join(self.lines + ["</robot>", ""])


AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def adjacent_pairs() -> list[tuple[str, str]]:
    """Parent-child link pairs that carry collision geometry (always allowed to touch)."""
    pairs = []
    for arm in ("left", "right"):
        x = ARM_PREFIX[arm]
        chain = ["base_link", f"{x}_base_link"] + [f"{x}_link{i}" for i in range(1, 7)]
        pairs += list(zip(chain[:-1], chain[1:]))
        pairs += [(f"{x}_link6", f"{x}_link7"), (f"{x}_link6", f"{x}_link8")]
    return pairs


def build_urdf(p: AlohaParams, name: str = "aloha_agilex") -> str:
    w = _Writer(name)
    w.link("base_link", _body_prims(p), 30.0)
    geo = _arm_prims(p)
    masses = p.link_masses
    for arm in ("left", "right"):
        x = ARM_PREFIX[arm]
        w.link(f"{x}_base_link", geo["base_link"], 0.5)
        w.joint(f"{x}_base_joint", "fixed", "base_link", f"{x}_base_link", mount_offset(p, arm))
        parent = f"{x}_base_link"
        for i, ((off, pitch, axis), lim) in enumerate(zip(joint_frames(p, arm), p.limits), start=1):
            child = f"{x}_link{i}"
            w.link(child, geo[f"link{i}"], masses[i - 1])
            w.joint(f"{x}_joint{i}", "revolute", parent, child, off, rpy=(0.0, pitch, 0.0),
                    axis=AXES[axis], limit=lim,
                    effort=p.joint_effort, velocity=p.joint_velocity)
            parent = child
        # gripper fingers: independent prismatic joints, +y and -y
        fx = p.tcp_offset - p.finger_origin_behind_tcp
        half = p.gap_at_zero / 2
        for j, sign in ((7, 1.0), (8, -1.0)):
            prims = geo["finger"] if sign > 0 else _mirror_y(geo["finger"])
            w.link(f"{x}_link{j}", prims, p.finger_mass)
            w.joint(f"{x}_joint{j}", "prismatic", f"{x}_link6", f"{x}_link{j}", (fx, sign * half, 0.0),
                    axis=(0.0, sign, 0.0), limit=(0.0, p.finger_travel), effort=100.0, velocity=0.5)
        # fixed frames: TCP and wrist camera (OpenCV axes)
        w.link(f"{x}_tcp", [], 0.01)
        w.joint(f"{x}_tcp_joint", "fixed", f"{x}_link6", f"{x}_tcp", (p.tcp_offset, 0.0, 0.0))
        w.link(f"{x}_camera", [], 0.01)
        w.joint(f"{x}_camera_joint", "fixed", f"{x}_link6", f"{x}_camera", p.wrist_cam_pos,
                rpy=mat_to_rpy(wrist_camera_rotation(p)))
    return w.text()


def build_srdf(p: AlohaParams, name: str = "aloha_agilex") -> str:
    """Disabled collision pairs. ``Adjacent`` pairs are parent-child (every simulator already
    ignores them; mplib needs them listed). No other pair is disabled: the geometry leaves
    clearance between non-adjacent links at rest."""
    lines = ['<?xml version="1.0"?>', "<!-- generated by cab_embodiment_aloha; do not edit -->",
             f'<robot name="{name}">']
    for arm in ("left", "right"):
        x = ARM_PREFIX[arm]
        lines.append(f'  <group name="{arm}_arm"><chain base_link="{x}_base_link" '
                     f'tip_link="{x}_tcp"/></group>')
    for a, b in adjacent_pairs():
        lines.append(f'  <disable_collisions link1="{a}" link2="{b}" reason="Adjacent"/>')
    lines += ["</robot>", ""]
    return "\n".join(lines)
