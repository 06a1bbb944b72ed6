"""click_bell: click the desk bell's top centre with a closed gripper.

Description
    A desk (service) bell stands on the table: a round foot, a hemispherical metal dome and, on
    top, a plunger with a round knob. The robot must press the knob (the bell's top centre) with
    the arm on the bell's side, its gripper closed.

Randomisation (per seed)
    Model variant 0 or 1 (as upstream's ``050_bell`` ids {0, 1}): a chrome bell on a black foot,
    8.6 cm wide and 7.6 cm tall, or a brass bell on a wooden foot, 10 cm wide and 8.8 cm tall.
    Static, upright (round: no rotation), drawn with ``rand_pose``: x in [-0.25, 0.25] with
    |x| >= 0.05, y in [-0.2, 0.0], standing on the table top.

Success (latch: any physics step, polled every step; false at the start)
    ``side_gripper_closed``: the gripper of the arm on the bell's side (x < 0: left, else right)
    is commanded closed (< 0.2), and ``knob_contact``: some contact point between a gripper (either
    arm's fingers or gripper body) and the bell lies within 0.025 m (x), 0.025 m (y) and 0.03 m (z)
    of the bell's contact point 0, the centre of the knob's top face.
    Guard: none (the bell is static).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Evaluation, WorldView, margin_any, margin_below, margin_within
from cab_core.geometry import transform_point
from cab_core.kits.oracle import Hands, top_down_quat
from cab_core.kits.scene import draw_variant, pose_list, rand_pose, sample_until, vec
from cab_core.kits.task import LatchVerifier

from ..assets_tools import BELL_KNOB_RADIUS, BELL_VARIANTS, bell_geometry, bell_shapes, gripper_bodies, is_gripper
from ..common import CodeActionTask

TOLERANCE = (0.025, 0.025, 0.03)
GRIPPER_CLOSED = 0.2
TIP_AHEAD = 0.0354  # fingertips ahead of the TCP: a top-down press puts the TCP this far above the knob


class ClickBellVerifier(LatchVerifier):
    def __init__(self, info: dict[str, Any]):
        b = info["bell"]
        self.bell = b["name"]
        self.point_local = np.asarray(b["contact_points"][0], float)
        self.arm = info["side_arm"]
        self.tol = np.asarray(info["tolerance"], float)
        self.grippers = info.get("gripper_bodies")
        self.guarded_objects = ()

    def holds(self, w: WorldView) -> bool:
        # success needs the side gripper closed and a gripper touching the bell: check both first
        if not w.gripper_command(self.arm) < GRIPPER_CLOSED:
            return False
        if not any(c.point is not None and c.impulse > 0 and ((c.b == self.bell and is_gripper(c.a, self.grippers))
                                                               or (c.a == self.bell and is_gripper(c.b, self.grippers)))
                   for c in w.contacts()):
            return False
        return bool(self.evaluate(w).success)

    def evaluate(self, w: WorldView) -> Evaluation:
        target = transform_point(w.pose(self.bell), self.point_local)
        best = None
        hit = False
        contact_margins = []  # one per gripper-bell contact: how far inside the box around the knob
        for c in w.contacts():
            if c.point is None or c.impulse <= 0:
                continue
            if not ((c.b == self.bell and is_gripper(c.a, self.grippers))
                    or (c.a == self.bell and is_gripper(c.b, self.grippers))):
                continue
            d = np.asarray(c.point, float) - target
            if best is None or np.linalg.norm(d) < np.linalg.norm(best):
                best = d
            contact_margins.append(margin_within(d, self.tol, "m"))
            if np.all(np.abs(d) < self.tol):
                hit = True
        grip = w.gripper_command(self.arm)
        closed = grip < GRIPPER_CLOSED
        values = {"side_gripper_command": float(grip)}
        margins = {"side_gripper_closed": margin_below(grip, GRIPPER_CLOSED, "gripper command")}
        if best is not None:
            values.update({f"contact_d{ax}": float(v) for ax, v in zip("xyz", best)})
            margins["knob_contact"] = margin_any(*contact_margins)  # some contact inside the box
        return Evaluation(success=bool(closed and hit),
                          predicates={"side_gripper_closed": bool(closed), "knob_contact": bool(hit)},
                          values=values, margins=margins)


class ClickBell(CodeActionTask):
    verifier_class = ClickBellVerifier
    # (1) knob contact with the selected gripper closed (the latched event, when it holds)
    subgoal_predicates = (("side_gripper_closed", "knob_contact"),)

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        model_id, v = draw_variant(rng, BELL_VARIANTS)
        g = bell_geometry(v)
        pose = sample_until(lambda: rand_pose(rng, (-0.25, 0.25), (-0.2, 0.0), (top,)),
                            lambda p: abs(p[0]) >= 0.05, what="the bell")
        scene.bodies.append(Body("bell", bell_shapes(model_id), pose=tuple(pose), kind="static"))
        knob_top = (0.0, 0.0, g["knob_top_z"])
        info = {
            "tolerance": list(TOLERANCE),
            "gripper_closed_threshold": GRIPPER_CLOSED,
            "bell": {
                "name": "bell",
                "model_id": model_id,
                "frame": "bell body: origin at the centre of the foot's bottom (on the table), +z up",
                "pose": pose_list(pose),
                "radius": v.base_radius,
                "dome_radius": v.dome_radius,
                "height": round(g["height"], 6),
                "knob_radius": BELL_KNOB_RADIUS,
                # contact point 0: the centre of the knob's top face (the bell's top centre)
                "contact_points": [vec(knob_top)],
            },
            # upstream's rule: the arm on the bell's side (x < 0: left)
            "side_arm": "left" if pose[0] < 0 else "right",
            "gripper_bodies": gripper_bodies(embodiment),
            # the subgoal the latched event satisfies (snapshots hold no contact points)
            "latch_subgoals": [0],
        }
        return info

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        """Press: the TCP where the expert's closed fingertips rest on the knob (top-down)."""
        b = info["bell"]
        local = np.add(b["contact_points"][0], [0.0, 0.0, TIP_AHEAD])

        def ref(w):
            return transform_point(w.pose(b["name"]), local)

        return [SpatialRule("Press", "either", ref, box(dx=6, dy=6, dz=4))]

    def solve(self, call, world: WorldView) -> None:
        """Close the side arm's gripper, hover 6 cm over the knob pointing down, press straight
        down to 5 mm past the knob's top (the static bell stops the fingertips), and rise."""
        info = world.info
        arm = info["side_arm"]
        hands = Hands(call, arm)
        knob = transform_point(world.pose(info["bell"]["name"]), info["bell"]["contact_points"][0])
        q = top_down_quat([1.0, 0.0, 0.0])
        hands.grip(0.0)
        hands.press(knob + [0.0, 0.0, TIP_AHEAD + 0.06], q, 0.065, 0.06, "the knob")
        call("done", report="pressed the bell's knob with the closed gripper", success_claim=True)


TASK = ClickBell
