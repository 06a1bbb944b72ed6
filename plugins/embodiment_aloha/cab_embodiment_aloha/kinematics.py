"""Closed-form forward kinematics of the generated arms (numpy only).

Used to solve the home joint values when the robot is generated, and by tests to cross-check a
planner's FK against the generator's own definition of the chain.
"""
from __future__ import annotations

import numpy as np

from cab_core.geometry import mat_to_pose, pose_to_mat

from .params import ARM_SIDE, AlohaParams


def _trans(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def _rot(axis: str, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    t = np.eye(4)
    if axis == "x":
        t[1:3, 1:3] = [[c, -s], [s, c]]
    elif axis == "y":
        t[0, 0], t[0, 2], t[2, 0], t[2, 2] = c, s, -s, c
    else:
        t[:2, :2] = [[c, -s], [s, c]]
    return t


ELBOW_PITCH = -np.pi / 2  # joint 3's fixed origin rotation about y: q3 = 0 is a straight elbow


def joint_frames(p: AlohaParams, arm: str) -> list[tuple[tuple[float, float, float], float, str]]:
    """(origin offset in the parent link frame, fixed origin pitch about y, rotation axis) of
    joints 1..6. Links 3.. extend along their local +x; joint 3's origin is pitched by -90 deg so
    that the forearm continues the upper arm at q3 = 0."""
    return [
        ((0.0, 0.0, p.h_base), 0.0, "z"),
        ((0.0, 0.0, p.h_shoulder), 0.0, "y"),
        ((0.0, 0.0, p.upper_arm), ELBOW_PITCH, "y"),
        ((p.forearm, 0.0, 0.0), 0.0, "y"),
        ((p.wrist1, 0.0, 0.0), 0.0, "z"),
        ((p.wrist2, 0.0, 0.0), 0.0, "x"),
    ]


def mount_offset(p: AlohaParams, arm: str) -> tuple[float, float, float]:
    """The arm's ``<p>_base_link`` origin in the robot (URDF root) frame."""
    return (p.shoulder_x, ARM_SIDE[arm] * p.shoulder_y, p.shoulder_z)


def link_mats_robot(p: AlohaParams, arm: str, q) -> list[np.ndarray]:
    """4x4 robot-frame transforms of ``<p>_base_link, link1..link6, tcp``."""
    q = np.asarray(q, dtype=float)
    t = _trans(*mount_offset(p, arm))
    out = [t]
    for (off, pitch, axis), qi in zip(joint_frames(p, arm), q):
        t = t @ _trans(*off) @ _rot("y", pitch) @ _rot(axis, qi)
        out.append(t)
    out.append(t @ _trans(p.tcp_offset, 0.0, 0.0))
    return out


def tcp_pose_world(p: AlohaParams, arm: str, q) -> np.ndarray:
    """World TCP pose [x, y, z, qw, qx, qy, qz] for arm joint values ``q`` (6,)."""
    return mat_to_pose(pose_to_mat(p.base_pose) @ link_mats_robot(p, arm, q)[-1])


def planar_seeds(p: AlohaParams, arm: str, tcp_xyz_world) -> list[np.ndarray]:
    """Analytic solutions for a TCP at ``tcp_xyz_world`` with the approach along robot +x, treating
    the arm as planar (joint 1 yawed toward the target, joint 5 undoing that yaw, joint 6 = 0).
    Both elbow branches, those within the joint limits first, smallest wrist pitch first."""
    base = pose_to_mat(p.base_pose)
    tcp = (np.linalg.inv(base) @ np.r_[np.asarray(tcp_xyz_world, float), 1.0])[:3]
    reach = p.wrist1 + p.wrist2 + p.tcp_offset
    m = np.asarray(mount_offset(p, arm))
    pivot = m + (0.0, 0.0, p.h_base + p.h_shoulder)
    wrist = tcp - (reach, 0.0, 0.0)
    # yaw joint 1 so the arm plane contains the wrist centre; joint 5 restores the approach
    dxy = wrist[:2] - pivot[:2]
    q1 = float(np.arctan2(dxy[1], dxy[0])) if np.linalg.norm(dxy) > 1e-9 else 0.0
    if abs(q1) > np.pi / 2:  # wrist behind the shoulder: reach backwards in the unrotated plane
        q1 = 0.0
    c1, s1 = np.cos(q1), np.sin(q1)
    u = c1 * dxy[0] + s1 * dxy[1]  # in-plane forward distance
    v = wrist[2] - pivot[2]
    l1, l2 = p.upper_arm, p.forearm
    d = float(np.hypot(u, v))
    if d > l1 + l2 or d < abs(l1 - l2) or d < 1e-9:
        return []
    a = (l1 * l1 - l2 * l2 + d * d) / (2 * d)
    h = float(np.sqrt(max(l1 * l1 - a * a, 0.0)))
    mu, mv = a * u / d, a * v / d
    out = []
    for sgn in (1.0, -1.0):
        eu, ev = mu - sgn * h * v / d, mv + sgn * h * u / d  # elbow
        q2 = float(np.arctan2(eu, ev))
        phi = float(np.arctan2(-(v - ev), u - eu))
        q3 = float(np.angle(np.exp(1j * (phi - q2 - ELBOW_PITCH))))  # wrapped to (-pi, pi]
        out.append(np.array([q1, q2, q3, -phi, -q1, 0.0]))
    lo = np.array([a for a, _ in p.limits])
    hi = np.array([b for _, b in p.limits])
    return sorted(out, key=lambda q: (not np.all((q >= lo) & (q <= hi)), abs(q[3])))


def solve_home(p: AlohaParams, arm: str, tcp_xyz_world, seed=None, iters: int = 200,
               tol_m: float = 0.005, tol_rad: float = 0.01) -> np.ndarray:
    """Joint values putting the TCP at ``tcp_xyz_world`` with the approach axis along robot +x
    (world +y with the default base) and the opening line along robot +y.

    Seeded by :func:`planar_seeds`, refined by damped least squares (deterministic). The result
    is the best iterate; ValueError if it is not within ``tol_m`` / ``tol_rad`` of the target.
    """
    base = pose_to_mat(p.base_pose)
    target = (np.linalg.inv(base) @ np.r_[np.asarray(tcp_xyz_world, float), 1.0])[:3]
    lo = np.array([a for a, _ in p.limits])
    hi = np.array([b for _, b in p.limits])
    seeds = [np.asarray(seed, float)] if seed is not None else planar_seeds(p, arm, tcp_xyz_world)
    if not seeds:
        raise ValueError(f"home TCP {tcp_xyz_world} is out of the {arm} arm's reach")

    def err(qq):
        t = link_mats_robot(p, arm, qq)[-1]
        r = t[:3, :3].T  # goal rotation is the identity
        w = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
        return np.r_[target - t[:3, 3], w]

    best, best_cost = None, np.inf
    for s0 in seeds:
        q = np.clip(np.array(s0, dtype=float), lo, hi)
        for _ in range(iters):
            e = err(q)
            cost = np.linalg.norm(e[:3]) + 0.1 * np.linalg.norm(e[3:])
            if cost < best_cost - 1e-9:
                best, best_cost = q.copy(), cost
            if np.linalg.norm(e[:3]) < 1e-5 and np.linalg.norm(e[3:]) < 1e-5:
                break
            jac = np.zeros((6, 6))
            for i in range(6):
                dq = np.zeros(6)
                dq[i] = 1e-6
                jac[:, i] = (e - err(q + dq)) / 1e-6  # d(current)/dq
            step = jac.T @ np.linalg.solve(jac @ jac.T + 1e-3 * np.eye(6), e)
            q = np.clip(q + np.clip(step, -0.2, 0.2), lo, hi)
        e = err(best)
        if np.linalg.norm(e[:3]) <= tol_m and np.linalg.norm(e[3:]) <= tol_rad:
            return best  # the first seed that converges wins (seeds are ordered by preference)
    e = err(best)
    if np.linalg.norm(e[:3]) > tol_m or np.linalg.norm(e[3:]) > tol_rad:
        raise ValueError(f"home pose for the {arm} arm at {tcp_xyz_world} not found "
                         f"(best error {np.linalg.norm(e[:3]):.4f} m, q={best})")
    return best
