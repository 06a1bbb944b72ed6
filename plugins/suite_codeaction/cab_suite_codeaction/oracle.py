"""Building blocks of the reference solutions. Oracles read privileged state (through the
``WorldView``) only to compute targets; every action goes through the public tools (``call``).
Quaternions are computed locally from axes, as an agent could do with ``grasp_quat_candidates``."""
from __future__ import annotations

import numpy as np

from cab_core.errors import CabError
from cab_core.geometry import mat_to_quat, quat_to_mat, transform_point


class OracleFailed(CabError):
    """The reference solution could not complete a step (reported in the record)."""


def tcp_quat(approach, opening) -> list[float]:
    """TCP orientation with +x = approach and +y = opening line (orthogonalised)."""
    a = np.asarray(approach, float)
    a = a / np.linalg.norm(a)
    o = np.asarray(opening, float)
    o = o - np.dot(o, a) * a
    o = o / np.linalg.norm(o)
    return [float(v) for v in mat_to_quat(np.stack([a, o, np.cross(a, o)], axis=1))]


def top_down_quat(opening_xy) -> list[float]:
    """Approach straight down; fingers open along ``opening_xy`` (a horizontal line)."""
    o = np.array([opening_xy[0], opening_xy[1], 0.0])
    return tcp_quat([0.0, 0.0, -1.0], o)


def yaw_axis(quat, axis=(1.0, 0.0, 0.0)) -> np.ndarray:
    """A body axis in the world, projected to the table plane and normalised."""
    v = quat_to_mat(quat) @ np.asarray(axis, float)
    v[2] = 0.0
    n = np.linalg.norm(v)
    return v / n if n > 1e-9 else np.array([1.0, 0.0, 0.0])


def world_point(pose, local) -> np.ndarray:
    return transform_point(np.asarray(pose, float), local)


def closest_opening(current_quat, candidates: list[np.ndarray]) -> np.ndarray:
    """Of the horizontal opening lines, the one needing the least wrist roll from now (the line
    is unoriented, so both signs are tried)."""
    cur = quat_to_mat(current_quat)[:, 1]
    best, score = None, -1.0
    for c in candidates:
        for s in (1.0, -1.0):
            d = float(np.dot(cur, s * np.asarray(c)))
            if d > score:
                best, score = s * np.asarray(c), d
    return best


def finger_reach(opening: float) -> float:
    """aloha_agilex: TCP to a finger's outer side along the opening line at gripper command
    ``opening`` (the pads' clearance is 0.11 * opening - 0.018 m)."""
    return 0.024 + 0.055 * opening


def fingers_clear(centre_xy, line, opening: float, obstacles, margin: float = 0.01) -> bool:
    """Whether both fingers, opened to ``opening`` along the horizontal ``line`` about
    ``centre_xy``, stay ``margin`` clear of every obstacle ``(centre_xy, radius)``."""
    reach = finger_reach(opening)
    c = np.asarray(centre_xy, float)[:2]
    d = np.asarray(line, float)[:2]
    return all(np.linalg.norm(c + s * reach * d - np.asarray(o, float)[:2]) > r + margin
               for s in (-1.0, 1.0) for o, r in obstacles)


def expect(result: dict, what: str, ok=("SUCCESS",)) -> dict:
    if "error" in result:
        raise OracleFailed(f"{what}: {result['error']}")
    st = result.get("status")
    if st is not None and st not in ok:
        raise OracleFailed(f"{what}: status {st} ({(result.get('failure') or {}).get('message')})")
    return result


class Hands:
    """Pick-and-place moves for one arm, through the public tools."""

    def __init__(self, call, arm: str, hover: float = 0.16):
        self.call = call
        self.arm = arm
        self.hover = hover

    def reach(self, xyz, quat=None, what="reach", ok=("SUCCESS",)) -> dict:
        args = {"arm": self.arm, "target_xyz": [float(v) for v in xyz]}
        if quat is not None:
            args["target_quat"] = [float(v) for v in quat]
        return expect(self.call("reach_tcp", **args), what, ok)

    def move(self, dx=0.0, dy=0.0, dz=0.0, what="move", ok=("SUCCESS",)) -> dict:
        return expect(self.call("move_delta", arm=self.arm, dx=float(dx), dy=float(dy), dz=float(dz)), what, ok)

    def descend_to(self, z: float, what: str, ok=("SUCCESS",)) -> dict:
        """A straight vertical move (guarded legs) down to TCP height ``z``."""
        r = self.call("get_arm_pose", arm=self.arm)
        return self.move(dz=float(z) - float(r["tcp_pose"][2]), what=what, ok=ok)

    def grip(self, pos: float) -> dict:
        return expect(self.call("set_gripper", arm=self.arm, pos=float(pos)), "set_gripper")

    def pick(self, xyz, quat, lift: float = 0.10) -> None:
        """Open, hover above, descend, close, lift."""
        x, y, z = (float(v) for v in xyz)
        self.reach([x, y, z + self.hover], quat, "hover above pick")
        self.descend_to(z, "descend to grasp")
        self.grip(0.0)
        self.move(dz=lift, what="lift", ok=("SUCCESS", "ABORTED", "FAILED"))

    def pick_held(self, world, name: str, aim, lift: float = 0.10, tries: int = 3) -> None:
        """Pick ``name`` and make sure it is held. ``aim(pose) -> (grasp_xyz, quat)`` from the
        object's pose. Once hovering above it, the pose is read again and the aim renewed if the
        object moved (the arm's planned path may have brushed it); after the lift, every finger must
        touch it, else the gripper opens and the pick starts over from where it lies."""
        for _ in range(tries):
            xyz, q = aim(world.pose(name))
            self.reach([xyz[0], xyz[1], xyz[2] + self.hover], q, "hover above pick")
            xyz2, q2 = aim(world.pose(name))
            if np.linalg.norm(np.subtract(xyz2, xyz)) > 0.003 or abs(float(np.dot(q2, q))) < 0.9995:
                xyz, q = xyz2, q2
                self.reach([xyz[0], xyz[1], xyz[2] + self.hover], q, "hover above pick again")
            self.descend_to(float(xyz[2]), "descend to grasp")
            self.grip(0.0)
            self.move(dz=lift, what="lift", ok=("SUCCESS", "ABORTED", "FAILED"))
            if world.gripper_holds(self.arm, name):
                return
            self.grip(1.0)
        raise OracleFailed(f"{name}: not held after {tries} picks")

    def place(self, xyz, quat=None, retreat: float = 0.08) -> None:
        """Carry above, descend, release, retreat upward."""
        x, y, z = (float(v) for v in xyz)
        self.reach([x, y, z + self.hover], quat, "carry above place")
        self.descend_to(z, "descend to place", ok=("SUCCESS", "ABORTED", "FAILED"))
        self.grip(1.0)
        self.move(dz=retreat, what="retreat", ok=("SUCCESS", "ABORTED", "FAILED"))
