"""press_stapler: press the stapler's top with one arm.

Description
    A desk stapler lies on the table: a base plate with an anvil at its front and, hinged at its
    back, the top arm (staple magazine under a coloured cover). Pressing the cover near its front
    end pushes the arm down onto the anvil (a few millimetres of travel); released, it springs back
    up. The robot must press the stapler with one arm.

Randomisation (per seed)
    Model variant 0-6 (as upstream's ``048_stapler`` ids 0-6): staplers 13-17 cm long, 3.4-4.4 cm
    wide, about 5 cm tall, in seven colour schemes. Fixed root (static as upstream), drawn with
    ``rand_pose``: x in [-0.2, 0.2], y in [-0.1, 0.05], heading uniform in +-pi (upstream's +-pi
    about the mesh's up axis), standing on the table top. The arm starts up (qpos 0).

Success (latch: any physics step, polled every step; false at the start)
    ``press_contact``: some contact point between a gripper (either arm's fingers or gripper
    housing) and the stapler lies within 0.03 m in x, y and z of the stapler's contact point 2,
    the press point on the cover 3.5 cm behind the arm's nose (it moves with the arm). No gripper
    state is required.
    Guard: none (the stapler's base is fixed).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box
from cab_core.contracts.scene import ArticulatedObject, SceneSpec
from cab_core.contracts.verifier import Evaluation, Margin, WorldView, margin_any, margin_within
from cab_core.geometry import transform_point
from cab_core.kits.oracle import Hands, closest_opening, top_down_quat, yaw_axis
from cab_core.kits.scene import draw_variant, pose_list, rand_pose, vec, yaw_of
from cab_core.kits.task import LatchVerifier

from ..assets_tools import (
    STAPLER_JOINT_DAMPING,
    STAPLER_PRESS_TRAVEL,
    STAPLER_VARIANTS,
    gripper_bodies,
    is_gripper,
    stapler_asset,
    stapler_geometry,
)
from ..common import CodeActionTask

TOLERANCE = (0.03, 0.03, 0.03)
TIP_AHEAD = 0.0354  # fingertips ahead of the TCP: a top-down press puts the TCP this far above the cover
PRESS_DEPTH = 0.012  # the oracle commands the fingertips this far below the resting cover


def arm_point(info: dict, root_pose, q: float, p_arm) -> np.ndarray:
    """A point given in the stapler's arm-link frame, in the world, with the hinge at ``q``."""
    s = info["stapler"]
    c, sn = np.cos(q), np.sin(q)
    ry = np.array([[c, 0.0, sn], [0.0, 1.0, 0.0], [-sn, 0.0, c]])  # rotation about the hinge's +y
    return transform_point(root_pose, np.asarray(s["hinge_point_base"], float) + ry @ np.asarray(p_arm, float))


def hinge_q(w: WorldView, info: dict) -> float:
    q = np.asarray(w.qpos(info["stapler"]["name"]), float)
    return float(q[0]) if q.size else 0.0


class PressStaplerVerifier(LatchVerifier):
    def __init__(self, info: dict[str, Any]):
        self.info = info
        s = info["stapler"]
        self.name = s["name"]
        self.point_arm = np.asarray(s["contact_points_arm"][2], float)
        self.tol = np.asarray(info["tolerance"], float)
        self.grippers = info.get("gripper_bodies")
        self.guarded_objects = ()

    def press_point(self, w: WorldView) -> np.ndarray:
        return arm_point(self.info, w.pose(self.name), hinge_q(w, self.info), self.point_arm)

    def holds(self, w: WorldView) -> bool:
        # success needs a gripper touching the stapler near the press point: look for the touch first
        prefix = self.name + "/"
        if not any(c.point is not None and c.impulse > 0 and ((c.a.startswith(prefix) and is_gripper(c.b, self.grippers))
                                                               or (c.b.startswith(prefix) and is_gripper(c.a, self.grippers)))
                   for c in w.contacts()):
            return False
        return bool(self.evaluate(w).success)

    def evaluate(self, w: WorldView) -> Evaluation:
        target = self.press_point(w)
        prefix = self.name + "/"
        best, hit = None, False
        margin: Margin | None = None  # of the contact farthest inside the box (or nearest to entering it)
        for c in w.contacts():
            if c.point is None or c.impulse <= 0:
                continue
            if not ((c.a.startswith(prefix) and is_gripper(c.b, self.grippers))
                    or (c.b.startswith(prefix) and is_gripper(c.a, self.grippers))):
                continue
            d = np.asarray(c.point, float) - target
            if best is None or np.linalg.norm(d) < np.linalg.norm(best):
                best = d
            if np.all(np.abs(d) < self.tol):
                hit = True
            m = margin_within(d, self.tol, "m")
            margin = m if margin is None else margin_any(margin, m)
        values = {"hinge_qpos": hinge_q(w, self.info)}
        if best is not None:
            values.update({f"contact_d{ax}": float(v) for ax, v in zip("xyz", best)})
        # no gripper-stapler contact at all: an event with nothing to measure, no margin
        margins = {"press_contact": margin} if margin is not None else {}
        return Evaluation(success=hit, predicates={"press_contact": hit}, values=values, margins=margins)


class PressStapler(CodeActionTask):
    verifier_class = PressStaplerVerifier
    # (1) stapler contact at the press point (the latched event, when it holds)
    subgoal_predicates = (("press_contact",),)

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        model_id, v = draw_variant(rng, STAPLER_VARIANTS)
        g = stapler_geometry(v)
        pose = rand_pose(rng, (-0.2, 0.2), (-0.1, 0.05), (top,), rotate_rand=True, rotate_lim=(0.0, 0.0, np.pi))
        scene.articulations.append(ArticulatedObject("stapler", stapler_asset(model_id), pose=tuple(pose),
                                                     fix_root=True, qpos=(0.0,), joint_damping=STAPLER_JOINT_DAMPING))
        info = {
            "tolerance": list(TOLERANCE),
            "stapler": {
                "name": "stapler",
                "model_id": model_id,
                "asset": f"stapler{model_id}",
                "root_pose": pose_list(pose),
                "yaw": round(yaw_of(pose[3:]), 6),
                "frame": "base link: origin at the base plate's bottom centre, +x toward the front (the nose, "
                         "where staples come out), +z up",
                "arm_frame": "arm link: origin on the hinge axis; equals the base frame's axes at qpos 0; the "
                             "hinge turns about +y, positive presses the nose down",
                "size": vec([v.length, v.width, g["height"]]),
                "base_link": "base",
                "arm_link": "arm",
                "hinge_joint": "hinge",
                "hinge_limits": [0.0, STAPLER_PRESS_TRAVEL],
                "hinge_point_base": vec(g["hinge"]),
                # contact points in the arm frame: 0 the nose, 1 above the hinge, 2 the press point
                "contact_points_arm": [vec(p) for p in g["contact_points_arm"]],
                "press_point_world_rest": vec(transform_point(pose, np.add(g["hinge"], g["press_point_arm"]))),
            },
            "gripper_bodies": gripper_bodies(embodiment),
            "latch_subgoals": [0],
            # the expert presses with the arm on the stapler's side
            "suggested_arm": "left" if pose[0] < 0 else "right",
        }
        return info

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        """Press: the TCP where the expert's fingertips rest on the press point (top-down)."""
        p_arm = np.asarray(info["stapler"]["contact_points_arm"][2], float)

        def ref(w):
            return arm_point(info, w.pose(info["stapler"]["name"]), hinge_q(w, info), p_arm) + [0.0, 0.0, TIP_AHEAD]

        return [SpatialRule("Press", "either", ref, box(dx=5, dy=(-6, 4), dz=(-3, 4)))]

    def solve(self, call, world: WorldView) -> None:
        """Close the gripper of the arm on the stapler's side, hover over the press point pointing
        down (fingers across the stapler), press straight down 1.2 cm past the resting cover
        (the arm gives way a few millimetres, then the move stalls on the anvil), and rise."""
        info = world.info
        s = info["stapler"]
        arm = info["suggested_arm"]
        hands = Hands(call, arm)
        root = world.pose(s["name"])
        press = arm_point(info, root, hinge_q(world, info), s["contact_points_arm"][2])
        across = yaw_axis(root[3:], (0.0, 1.0, 0.0))
        q = top_down_quat(closest_opening(world.tcp_pose(arm)[3:], [across]))
        hands.grip(0.0)
        hands.press(press + [0.0, 0.0, TIP_AHEAD + 0.06], q, 0.06 + PRESS_DEPTH, 0.06, "the stapler")
        call("done", report="pressed the stapler's top near its front with one arm", success_claim=True)


TASK = PressStapler
