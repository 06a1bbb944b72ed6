"""Small rigid-body helpers over numpy. Poses are [x, y, z, qw, qx, qy, qz]; quaternions are wxyz."""
from __future__ import annotations

import math

import numpy as np


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
    q = quat_normalize(q)
    return q if q[0] >= 0 else -q


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
