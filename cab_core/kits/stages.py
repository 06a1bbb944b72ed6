"""Reading a task's stage from the state (forks): small predicates a stage-aware reference
solution uses to tell which of its steps are done (a door opened, an object handed from one hand to
the other, a grasp closed on both sides). They only read privileged state;
none makes a tool call. Distances in metres."""
from __future__ import annotations

import numpy as np

#: a gripper commanded below this is closed (the reference solutions command 0.0 or 1.0)
CLOSED = 0.5
#: a TCP this close (m) to where a step of the reference solution leaves it has done that step
AT_M = 0.015


def closed(world, arm: str) -> bool:
    return world.gripper_command(arm) < CLOSED


def near(world, arm: str, xyz, tol: float = AT_M) -> bool:
    """Whether ``arm``'s TCP is within ``tol`` of ``xyz``."""
    return float(np.linalg.norm(world.tcp_pose(arm)[:3] - np.asarray(xyz, float))) <= tol


def near_xy(world, arm: str, xyz, tol: float) -> bool:
    """Whether ``arm``'s TCP is within ``tol`` of ``xyz`` in the table plane."""
    return float(np.linalg.norm(world.tcp_pose(arm)[:2] - np.asarray(xyz, float)[:2])) <= tol


def turned(world, arm: str, quat, tol: float = 0.9995) -> bool:
    """Whether ``arm``'s TCP has orientation ``quat`` (either sign)."""
    return abs(float(np.dot(world.tcp_pose(arm)[3:], np.asarray(quat, float)))) >= tol


def at_pose(world, arm: str, xyz, quat, tol: float = AT_M) -> bool:
    return near(world, arm, xyz, tol) and turned(world, arm, quat)


def holds(world, arm: str, name: str) -> bool:
    """``arm``'s gripper is closed and every finger touches ``name``."""
    return closed(world, arm) and world.gripper_holds(arm, name)


def near_point(a, b, tol: float) -> bool:
    """Whether the points ``a`` and ``b`` are within ``tol`` of each other."""
    return float(np.linalg.norm(np.asarray(a, float)[:3] - np.asarray(b, float)[:3])) <= tol
