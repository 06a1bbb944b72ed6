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


def joint_frames(p: AlohaParams, arm: str) -> list[tuple[tuple[float, float, float], str]]:
    """(origin offset in the parent link frame, rotation axis) of joints 1..6."""
    return [
        ((0.0, 0.0, p.h_base), "z"),
        ((0.0, 0.0, p.h_shoulder), "y"),
        ((0.0, 0.0, p.upper_arm), "y"),
        ((p.forearm, 0.0, 0.0), "y"),
        ((p.wrist1, 0.0, 0.0), "z"),
        ((p.wrist2, 0.0, 0.0), "x"),
    ]


def mount_offset(p: AlohaParams, arm: str) -> tuple[float, float, float]:
    """The arm's ``<p>_base_link`` origin in the robot (URDF root) frame."""
    return (p.shoulder_x, ARM_SIDE[arm] * p.shoulder_y, p.shoulder_z)


def link_mats_robot(p: AlohaParams, arm: str, q) -> list[np.ndarray]:
    """4x4 robot-frame transforms of ``<p>_base_link, link1..link6, tcp``."""
    q = np.asarray(q, dtype=float)
    t = _trans(*mount_offset(p, arm))
    out = [t]
    for (off, axis), qi in zip(joint_frames(p, arm), q):
        t = t @ _trans(*off) @ _rot(axis, qi)
        out.append(t)
    out.append(t @ _trans(p.tcp_offset, 0.0, 0.0))
    return out


def tcp_pose_world(p: AlohaParams, arm: str, q) -> np.ndarray:
    """World TCP pose [x, y, z, qw, qx, qy, qz] for arm joint values ``q`` (6,)."""
    return mat_to_pose(pose_to_mat(p.base_pose) @ link_mats_robot(p, arm, q)[-1])


def solve_home(p: AlohaParams, arm: str, tcp_xyz_world, seed=None, iters: int = 300) -> np.ndarray:
    """Joint values putting the TCP at ``tcp_xyz_world`` with the approach axis along robot +x
    (world +y with the default base) and the opening line along robot +y, elbow up.

    Damped least squares on a numerical Jacobian; deterministic. Raises ValueError if it does not
    converge within 0.1 mm / 1e-4 rad inside the joint limits.
    """
    base = pose_to_mat(p.base_pose)
    target = np.linalg.inv(base) @ np.r_[np.asarray(tcp_xyz_world, float), 1.0]
    goal = np.eye(4)
    goal[:3, 3] = target[:3]
    q = np.array(seed if seed is not None else (0.0, -0.5, 1.2, -0.7, 0.0, 0.0), dtype=float)
    lo = np.array([a for a, _ in p.limits])
    hi = np.array([b for _, b in p.limits])

    def err(qq):
        t = link_mats_robot(p, arm, qq)[-1]
        dp = goal[:3, 3] - t[:3, 3]
        r = goal[:3, :3] @ t[:3, :3].T
        w = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
        return np.r_[dp, w]

    for _ in range(iters):
        e = err(q)
        if np.linalg.norm(e[:3]) < 1e-4 and np.linalg.norm(e[3:]) < 1e-4:
            return np.clip(q, lo, hi)
        jac = np.zeros((6, 6))
        for i in range(6):
            dq = np.zeros(6)
            dq[i] = 1e-6
            jac[:, i] = (err(q) - err(q + dq)) / 1e-6  # d(current)/dq
        lam = 1e-3
        step = jac.T @ np.linalg.solve(jac @ jac.T + lam * np.eye(6), e)
        q = np.clip(q + step, lo, hi)
    raise ValueError(f"home pose for the {arm} arm at {tcp_xyz_world} did not converge (q={q})")
