"""Small rigid-body helpers over numpy, the pinhole camera model, and how poses and orientations
read in a tool result.

Poses are [x, y, z, qw, qx, qy, qz]; quaternions are wxyz. Cameras follow OpenCV: a pinhole K
(pixels, no distortion) and a 3x4 extrinsic E = [R|t] mapping world to camera
(p_cam = R p_world + t; camera +x right, +y down, +z forward). This is the one home of the camera
math the tools and the hosts use. Imports nothing else of cab_core.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, TypeAlias

import numpy as np

# a vector or a pose given by its numbers: a list or tuple of floats, or a numpy array
Vector: TypeAlias = Sequence[float] | np.ndarray


def quat_normalize(q) -> np.ndarray:
    q = np.ascontiguousarray(q, dtype=float)
    # np.linalg.norm of a vector is sqrt(x.dot(x)) of its contiguous copy: the same number, faster
    n = math.sqrt(q.dot(q)) if q.ndim == 1 else float(np.linalg.norm(q))
    if not math.isfinite(n) or n < 1e-12:
        raise ValueError(f"degenerate quaternion {q!r}")
    return q / n


def quat_mul(a, b) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def quat_conj(q) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]], dtype=float)


def quat_to_mat(q) -> np.ndarray:
    w, x, y, z = quat_normalize(q).tolist()  # Python floats: the same IEEE arithmetic as numpy scalars, faster
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def mat_to_quat(m) -> np.ndarray:
    m = np.asarray(m, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    unit = quat_normalize(q)
    return unit if unit[0] >= 0 else -unit


def axis_angle_quat(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def euler_quat(roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """Extrinsic x-y-z (roll about world x, then pitch about world y, then yaw about world z)."""
    qx = axis_angle_quat([1, 0, 0], roll)
    qy = axis_angle_quat([0, 1, 0], pitch)
    qz = axis_angle_quat([0, 0, 1], yaw)
    return quat_mul(qz, quat_mul(qy, qx))


def quat_angle(a, b) -> float:
    """Smallest rotation angle between two orientations (radians)."""
    d = abs(float(np.dot(quat_normalize(a), quat_normalize(b))))
    return float(2 * np.arccos(min(1.0, d)))


def pose_to_mat(pose) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    t = np.eye(4)
    t[:3, :3] = quat_to_mat(pose[3:7])
    t[:3, 3] = pose[:3]
    return t


def mat_to_pose(t) -> np.ndarray:
    t = np.asarray(t, dtype=float)
    return np.concatenate([t[:3, 3], mat_to_quat(t[:3, :3])])


def pose_mul(a, b) -> np.ndarray:
    return mat_to_pose(pose_to_mat(a) @ pose_to_mat(b))


def pose_inv(p) -> np.ndarray:
    return mat_to_pose(np.linalg.inv(pose_to_mat(p)))


def transform_point(pose, p) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    return quat_to_mat(pose[3:7]) @ np.asarray(p, dtype=float) + pose[:3]


def look_at_cv(position, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World pose of an OpenCV camera (x right, y down, z forward) at ``position`` looking at ``target``."""
    position = np.asarray(position, dtype=float)
    z = np.asarray(target, dtype=float) - position
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.concatenate([position, mat_to_quat(np.stack([x, y, z], axis=1))])


def intrinsics(width: int, height: int, fovy_deg: float) -> np.ndarray:
    """Pinhole K with square pixels from the vertical field of view."""
    f = (height / 2.0) / np.tan(np.deg2rad(fovy_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


# ==============================================================================================
# camera math (pinhole K, world->camera E = [R|t], OpenCV axes)
# ==============================================================================================
MIN_DEPTH_M = 1e-6  # a point is "in front of" a camera when its camera z exceeds this


def extrinsic_from_pose(cam_pose_world) -> np.ndarray:
    """3x4 world->camera matrix E from an OpenCV-convention camera pose in the world."""
    return pose_to_mat(pose_inv(cam_pose_world))[:3, :]


def camera_centre(E) -> np.ndarray:
    """World position of the camera centre: -R^T t."""
    E = np.asarray(E, float)
    return -E[:, :3].T @ E[:, 3]


def world_to_camera(E, p) -> np.ndarray:
    """One world point in camera coordinates: R p + t."""
    E = np.asarray(E, float)
    return E[:, :3] @ p + E[:, 3]


def camera_to_world(E, p_cam) -> np.ndarray:
    """One camera-frame point in world coordinates: R^T (p_cam - t)."""
    E = np.asarray(E, float)
    return E[:, :3].T @ (p_cam - E[:, 3])


def back_project(K, px: Vector) -> np.ndarray:
    """The camera-frame point at depth 1 on the viewing ray of pixel ``px``: K^-1 [u, v, 1]."""
    return np.linalg.solve(np.asarray(K, float), np.array([px[0], px[1], 1.0]))


def project_points(K, E, pts) -> tuple[np.ndarray, np.ndarray]:
    """World points (N,3) -> pixels (N,2) and camera depths (N,). Pixels of points behind the
    camera are NaN."""
    pts = np.atleast_2d(np.asarray(pts, float))
    pc = pts @ np.asarray(E, float)[:, :3].T + np.asarray(E, float)[:, 3]
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uvw = pc @ np.asarray(K, float).T
        uv = uvw[:, :2] / uvw[:, 2:3]
    uv[z <= MIN_DEPTH_M] = np.nan
    return uv, z


def pixel_ray(K, E, px: Vector) -> tuple[np.ndarray, np.ndarray]:
    """World origin (camera centre) and unit direction of the viewing ray through pixel ``px``. A
    ray without a usable direction (non-finite, or no length) has the direction [0, 0, 0]: check it
    with :func:`degenerate_direction`."""
    with np.errstate(all="ignore"):
        d_cam = back_project(K, px)
        d = np.asarray(E, float)[:, :3].T @ d_cam
        n = float(np.linalg.norm(d))
    if not (math.isfinite(n) and n > 1e-12):
        return camera_centre(E), np.zeros(3)
    return camera_centre(E), d / n


def degenerate_direction(d: np.ndarray) -> bool:
    """Whether a direction from :func:`pixel_ray` is unusable (not finite, not of unit length)."""
    return not (np.all(np.isfinite(d)) and abs(float(np.linalg.norm(d)) - 1.0) < 1e-6)


# ==============================================================================================
# how numbers, poses and orientations read in a tool result
# ==============================================================================================
def rnd(x: Any, nd: int = 6) -> Any:
    """JSON-able copy of numbers/arrays rounded to ``nd`` decimals (None and non-finite kept as None)."""
    if x is None:
        return None
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return round(float(x), nd) + 0.0 if math.isfinite(float(x)) else None  # + 0.0: no "-0.0"
    if isinstance(x, np.ndarray):
        return rnd(x.tolist(), nd)
    if isinstance(x, (list, tuple)):
        return [rnd(v, nd) for v in x]
    if isinstance(x, dict):
        return {k: rnd(v, nd) for k, v in x.items()}
    return x


def pose_block(pose: Vector) -> list:
    return rnd(np.asarray(pose, float), 6)


_DIR_NAMES = {(0, 1): "right (+x)", (0, -1): "left (-x)", (1, 1): "forward (+y)", (1, -1): "backward (-y)",
              (2, 1): "up (+z)", (2, -1): "down (-z)"}
_LINE_NAMES = {0: "left-right (x)", 1: "forward-backward (y)", 2: "vertical (z)"}


def describe_direction(direction: Vector) -> str:
    """Plain words for a world direction, e.g. 'down (-z)' or 'mostly forward (+y), tilted 20 deg down (-z)'."""
    v = np.asarray(direction, float)
    v = v / (np.linalg.norm(v) or 1.0)
    order = np.argsort(-np.abs(v))
    i, j = int(order[0]), int(order[1])
    main = _DIR_NAMES[(i, 1 if v[i] > 0 else -1)]
    if abs(v[i]) >= math.cos(math.radians(5)):
        return main
    tilt = math.degrees(math.atan2(abs(v[j]), abs(v[i])))
    return f"mostly {main}, tilted {tilt:.0f} deg toward {_DIR_NAMES[(j, 1 if v[j] > 0 else -1)]}"


def describe_line(direction: Vector) -> str:
    """Plain words for an unoriented line direction."""
    v = np.abs(np.asarray(direction, float))
    i = int(np.argmax(v))
    if v[i] >= math.cos(math.radians(5)):
        return _LINE_NAMES[i]
    return f"mostly {_LINE_NAMES[i]}"


_SNAPSHOT_NAMES = (("+x (robot right)", "-x (robot left)"), ("+y (forward)", "-y (toward robot)"),
                   ("+z (up)", "-z (down)"))


def _snapshot_words(v, line: bool = False) -> str:
    """The snapshot form's words for a direction (or, with ``line``, an unoriented line)."""
    i = int(np.argmax(np.abs(v)))
    s = _SNAPSHOT_NAMES[i][0 if v[i] >= 0 else 1]
    if line:
        s = s.split(" ")[0].lstrip("+-") + "-axis line"
    return f"mostly {s}" if abs(v[i]) < 0.95 else s


def orientation_block(quat_wxyz: Vector, *, snapshot: bool = False) -> dict:
    """The ``orientation`` block that accompanies a reported gripper pose: the gripper's approach
    (+x) and opening (+y) axes in world coordinates, and how they read in words.

    Two forms, both as recorded attempts hold them: the full form of observation and geometry
    results (axes to 6 decimals, the normal axis, the convention) and, with ``snapshot``, the
    compact form of the two-arm robot snapshots inside action results (``observed_before``,
    ``observed_after``: axes to 4 decimals, shorter words)."""
    r = quat_to_mat(quat_wxyz)
    a, o = r[:, 0], r[:, 1]
    if snapshot:
        return {"approach_axis_world": [round(float(x), 4) for x in a],
                "opening_axis_world": [round(float(x), 4) for x in o],
                "reads_as": {"approach": _snapshot_words(a), "opening_line": _snapshot_words(o, line=True)}}
    return {
        "approach_axis_world": rnd(a),
        "opening_axis_world": rnd(o),
        "normal_axis_world": rnd(r[:, 2]),
        "reads_as": {
            "approach": f"approach points {describe_direction(a)}",
            "opening": f"fingers open and close along {describe_line(o)}",
        },
        "convention": "gripper +x = approach (wrist toward fingertips), +y = finger-opening line, +z = x cross y",
    }
