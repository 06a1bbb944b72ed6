"""handover_block: the left arm picks the long red block, hands it to the right arm, which sets it
on the blue pad.

Description
    A long red block (6 x 6 x 20 cm, standing upright) stands on the left half of the table; a flat
    blue pad (10 x 10 x 1 cm, fixed) lies on the right, toward the back. The left arm must grasp the
    block, hand it over to the right arm, and the right arm must stand the block on the pad and
    let go of it.

Randomisation (per seed; FACTS B.6)
    Block (half-size (0.03, 0.03, 0.10), dynamic) with ``rand_pose``: x in [-0.25, -0.05],
    y in [0, 0.25], z 0.842 (2 mm above the table, settles at reset), base quaternion
    [0.981, 0, 0, 0.195] (yaw ~0.39 rad) composed with a yaw in +-0.2 rad. Pad (half-size
    (0.05, 0.05, 0.005), static, no rotation) lying on the table: x in [0.1, 0.25], y in
    [0.15, 0.20].

Success (final state)
    ``block_on_pad``: the block's bottom-face centre (functional point 0) is within 0.03 m of the
    pad's top-face centre (functional point 1) in x and in y, and within 0.01 m in z (the block
    stands upright on the pad); ``right_gripper_open``: the right arm's commanded gripper value is
    > 0.8 (the right arm has let go). Which arm did what is not checked beyond that (as upstream).
    Guard: the block must stay on the table (not below table top - 0.08 m).
    Margins are recorded for both predicates.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, cylinder
from cab_core.contracts.scene import Body, Box, Material, SceneSpec, Shape
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, margin_above, margin_within
from cab_core.geometry import transform_point
from cab_core.kits.oracle import TOLERANT, Hands, OracleFailed, closest_opening, tcp_quat, top_down_quat, yaw_axis
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, srgb, vec, yaw_of
from cab_core.kits.stages import at_pose, closed, holds, near, near_point

from ..common import CodeActionTask

BLOCK_HALF = (0.03, 0.03, 0.10)
BLOCK_SPAWN_Z = 0.842  # FACTS B.6: 2 mm above the table top for the 0.10 half-height
BLOCK_BASE_QUAT = (0.981, 0.0, 0.0, 0.195)
BLOCK_YAW_RAND = 0.2
BLOCK_DENSITY = 400.0  # kg/m^3, a painted pine block: 0.29 kg
BLOCK_FRICTION = 0.8  # painted wood against rubber finger pads
PAD_HALF = (0.05, 0.05, 0.005)
XY_TOL = 0.03
Z_TOL = 0.01
GRIPPER_OPEN = 0.8

BLOCK_RED = Material(color=srgb(0.85, 0.10, 0.10), roughness=0.5, static_friction=BLOCK_FRICTION,
                     dynamic_friction=BLOCK_FRICTION)
PAD_BLUE = Material(color=srgb(0.10, 0.25, 0.90), roughness=0.6)

# functional points (body frames)
BOTTOM_POINT = (0.0, 0.0, -BLOCK_HALF[2])  # block functional point 0: centre of the bottom face
PAD_TOP_POINT = (0.0, 0.0, PAD_HALF[2])  # pad functional point 1: centre of the top face
# oracle hints: where each arm holds the block (block frame). The left fingers cover the top 6 cm
# (top-down), the right fingers close round the lower part, 5 cm above the bottom (from the front).
LEFT_GRASP = (0.0, 0.0, BLOCK_HALF[2] - 0.025)
RIGHT_GRASP = (0.0, 0.0, -BLOCK_HALF[2] + 0.05)
HANDOVER_CENTRE = (0.0, -0.05, 0.95)  # block centre during the handover (world)


class HandoverBlockVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        b, p = info["block"], info["pad"]
        self.block, self.pad = b["name"], p["name"]
        self.bottom = np.asarray(b["bottom_point"], float)
        self.top = np.asarray(p["top_point"], float)
        self.xy_tol, self.z_tol = float(info["xy_tolerance"]), float(info["z_tolerance"])
        self.guarded_objects = (self.block,)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        d = transform_point(w.pose(self.block), self.bottom) - transform_point(w.pose(self.pad), self.top)
        on_pad = bool(abs(d[0]) < self.xy_tol and abs(d[1]) < self.xy_tol and abs(d[2]) < self.z_tol)
        g = w.gripper_command("right")
        right_open = g > GRIPPER_OPEN
        return Evaluation(success=on_pad and right_open,
                          predicates={"block_on_pad": on_pad, "right_gripper_open": right_open},
                          values={"bottom_dx": float(d[0]), "bottom_dy": float(d[1]), "bottom_dz": float(d[2]),
                                  "gripper_right": float(g)},
                          margins={"block_on_pad": margin_within(d, (self.xy_tol, self.xy_tol, self.z_tol), "m"),
                                   "right_gripper_open": margin_above(g, GRIPPER_OPEN, "gripper command",
                                                                      1 - GRIPPER_OPEN)})


class HandoverBlock(CodeActionTask):
    verifier_class = HandoverBlockVerifier
    subgoal_predicates = (("block_on_pad",),)

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        block_pose = rand_pose(rng, (-0.25, -0.05), (0.0, 0.25), (BLOCK_SPAWN_Z,), rotate_rand=True,
                               rotate_lim=(0.0, 0.0, BLOCK_YAW_RAND), qpos=BLOCK_BASE_QUAT)
        pad_pose = rand_pose(rng, (0.1, 0.25), (0.15, 0.20), (top + PAD_HALF[2],))
        scene.bodies.append(Body("block", [Shape(Box(BLOCK_HALF), material=BLOCK_RED)], pose=tuple(block_pose),
                                 kind="dynamic", density=BLOCK_DENSITY))
        scene.bodies.append(Body("pad", [Shape(Box(PAD_HALF), material=PAD_BLUE)], pose=tuple(pad_pose),
                                 kind="static"))
        info = {
            "xy_tolerance": XY_TOL,
            "z_tolerance": Z_TOL,
            "gripper_open_threshold": GRIPPER_OPEN,
            "block": {
                "name": "block",
                "frame": "block body: centre of the block, z along its 0.20 m length (up when standing)",
                "initial_pose": pose_list(block_pose),
                "yaw": round(yaw_of(block_pose[3:]), 6),
                "half_size": vec(BLOCK_HALF),
                "mass_kg": round(BLOCK_DENSITY * 8 * float(np.prod(BLOCK_HALF)), 6),
                "bottom_point": vec(BOTTOM_POINT),  # functional point 0
                "left_grasp_point": vec(LEFT_GRASP),
                "right_grasp_point": vec(RIGHT_GRASP),
            },
            "pad": {
                "name": "pad",
                "frame": "pad body: centre of the slab, axes along its edges",
                "pose": pose_list(pad_pose),
                "half_size": vec(PAD_HALF),
                "top_point": vec(PAD_TOP_POINT),  # functional point 1
            },
            "handover_centre": vec(HANDOVER_CENTRE),
            "grasp_arm": "left",
            "place_arm": "right",
        }
        return info

    # -- checkpoints ------------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        b, p = info["block"], info["pad"]
        left_g = np.asarray(b["left_grasp_point"], float)
        right_g = np.asarray(b["right_grasp_point"], float)
        # expert placement: the right TCP holds the block right_grasp_point above its bottom, which
        # sits on the pad's top point
        place_off = np.asarray(p["top_point"], float) + (right_g - np.asarray(b["bottom_point"], float))
        return [
            SpatialRule("Approach box", "either", lambda w: transform_point(w.pose(b["name"]), left_g),
                        cylinder(7.0, 4.0)),
            SpatialRule("Handover", "either", lambda w: transform_point(w.pose(b["name"]), right_g),
                        box(10.0, 6.0, 6.0), prerequisites=(0,)),
            SpatialRule("Place at support", "either",
                        lambda w: np.asarray(w.pose(p["name"])[:3], float) + place_off,
                        cylinder(7.5, (-2.0, 5.0)), prerequisites=(1,)),
        ]

    # -- reference solution -----------------------------------------------------------------------
    #: the reference solution's steps, in order (a fork goes on from the step its state shows)
    STEPS = ("behind", "over", "down", "close", "lift", "to_handover", "right_reach", "right_round", "right_close",
             "left_release", "left_up", "over_pad", "set_down", "right_open", "back_off")

    @staticmethod
    def _left_aim(world: WorldView) -> tuple[np.ndarray, list[float]]:
        """The left TCP's grasp point on the block's top where it is now, and its top-down
        orientation (fingers across the two faces nearest the gripper's opening now)."""
        b = world.info["block"]
        pose = world.pose(b["name"])
        faces = [yaw_axis(pose[3:], (1, 0, 0)), yaw_axis(pose[3:], (0, 1, 0))]
        q = top_down_quat(closest_opening(world.tcp_pose("left")[3:], faces))
        return np.asarray(transform_point(pose, b["left_grasp_point"]), float), q

    @staticmethod
    def _right_aim(world: WorldView) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """From the front round the lower part of the block as it is held now: the approach, the
        opening line (the block's face line nearest to x) and the TCP's grasp point."""
        b = world.info["block"]
        held = world.pose(b["name"])
        faces = [yaw_axis(held[3:], (1, 0, 0)), yaw_axis(held[3:], (0, 1, 0))]
        opening = max(faces, key=lambda f: abs(f[0]))
        opening = opening if opening[0] < 0 else -opening
        approach = np.array([-opening[1], opening[0], 0.0])  # horizontal, at right angles
        approach = approach if approach[1] > 0 else -approach
        return approach, opening, np.asarray(transform_point(held, b["right_grasp_point"]), float)

    @staticmethod
    def _place_target(world: WorldView) -> np.ndarray:
        """The right TCP's target for standing the block (as the right hand holds it now) on the pad."""
        b, p = world.info["block"], world.info["pad"]
        pad_top = transform_point(world.pose(p["name"]), p["top_point"])
        off = world.tcp_pose("right")[:3] - transform_point(world.pose(b["name"]), b["bottom_point"])
        return pad_top + off + [0.0, 0.0, 0.004]

    def _stage(self, world: WorldView) -> str | None:
        """The first step of the reference solution still to do, read from the hands and the block
        (a fork); None where the state is not one the solution passes through (at an attempt's
        start too: there it starts with its first step)."""
        info = world.info
        b = info["block"]
        name = b["name"]
        if self.evaluate(world).predicates["block_on_pad"] and closed(world, "right"):
            return "right_open"
        if holds(world, "right", name):
            if closed(world, "left"):
                return "left_release"
            if near(world, "left", transform_point(world.pose(name), b["left_grasp_point"]), 0.03):
                return "left_up"
            if near(world, "right", self._place_target(world) + [0.0, 0.0, 0.04]):
                return "set_down"
            return "over_pad"
        if holds(world, "left", name):
            pose = world.pose(name)
            if near_point(pose[:3], info["handover_centre"], 0.03):
                if closed(world, "right"):
                    return None
                approach, opening, low = self._right_aim(world)
                q = tcp_quat(approach, opening)
                if at_pose(world, "right", low, q):
                    return "right_close"
                if at_pose(world, "right", low - 0.10 * approach, q):
                    return "right_round"
                return "right_reach"
            if pose[2] > b["initial_pose"][2] + 0.05:
                return "to_handover"
            return "lift"
        if closed(world, "left"):
            return None
        g, q = self._left_aim(world)
        if at_pose(world, "left", g, q):
            return "close"
        if at_pose(world, "left", g + [0.0, 0.0, 0.16], q):
            return "down"
        if at_pose(world, "left", g + [0.0, -0.15, 0.16], q):
            return "over"
        return None

    def keeps_hands(self, world: WorldView) -> bool:
        return self._stage(world) is not None

    def solve(self, call, world: WorldView) -> None:
        """Left arm: top-down grasp of the block's top, lift, carry it to the handover point in
        front of the robot turning it square to the world axes. Right arm: grasp the lower part
        from the front, the left lets go and rises; the right carries the block over the pad,
        lowers it onto the pad, releases and backs off (15 tool calls). From a fork it goes on
        from the step the state shows (``_stage``)."""
        info = world.info
        b = info["block"]
        name = b["name"]
        left, right = Hands(call, "left"), Hands(call, "right")
        start = self.STEPS.index(self._stage(world) or "behind")

        def todo(step: str) -> bool:
            return self.STEPS.index(step) >= start

        # 1. left arm: top-down onto the block's top, fingers across two faces
        # turn the gripper down well behind the block (a planned path may sweep through anything
        # near it), then slide over it and go straight down (to where the block was seen first)
        g, q = self._left_aim(world)
        hover = g + [0.0, 0.0, 0.16]
        if todo("behind"):
            left.reach(hover + [0.0, -0.15, 0.0], q, "behind and above the block")
        if todo("over"):
            left.move_to(world, hover, "over the block")
        if todo("down"):
            left.move_to(world, g, "down onto the block")
        if todo("close"):
            left.grip(0.0)
        if todo("lift"):
            left.move(dz=0.10, what="lift", ok=TOLERANT)

        # 2. to the handover point, the block turned square to the world axes (opening along x)
        if todo("to_handover"):
            hc = np.asarray(info["handover_centre"], float)
            held = world.pose(name)
            up = np.asarray(transform_point(held, b["left_grasp_point"]), float) - held[:3]
            left.reach(hc + [0.0, 0.0, float(np.linalg.norm(up))], top_down_quat([1.0, 0.0, 0.0]),
                       "to the handover")

        # 3. right arm: from the front round the lower part, fingers open along the block's face
        # line nearest to x (the block may have turned a little in the left hand); the left lets go
        # only once the right fingers hold it, else the right backs off and aims again
        if todo("right_close"):
            for attempt in range(3):
                approach, opening, low = self._right_aim(world)
                if attempt > 0 or todo("right_reach"):
                    right.reach(low - 0.10 * approach, tcp_quat(approach, opening), "in front of the block")
                if attempt > 0 or todo("right_round"):
                    low = transform_point(world.pose(name), b["right_grasp_point"])  # it may have swung meanwhile
                    right.move_to(world, low, "round the block", ok=TOLERANT)
                right.grip(0.0)
                if world.gripper_holds("right", name):
                    break
                right.grip(1.0)
                right.move(*(-0.10 * approach), what="back off to aim again", ok=TOLERANT)
            else:
                raise OracleFailed("the right hand did not get hold of the block in three tries")
        if todo("left_release"):
            left.grip(1.0)
        if todo("left_up"):
            left.move(dz=0.10, what="left hand up", ok=TOLERANT)

        # 4. right arm: over the pad, down until the block stands on it, let go, back off
        if todo("set_down"):
            target = self._place_target(world)
            if todo("over_pad"):
                right.reach(target + [0.0, 0.0, 0.04], None, "over the pad")
            right.move_to(world, target, "set down", ok=TOLERANT)
        if todo("right_open"):
            right.grip(1.0)
        right.move(dy=-0.10, dz=0.02, what="back off", ok=TOLERANT)
        if not world.gripper_command("right") > GRIPPER_OPEN:
            raise OracleFailed("right gripper not open")
        call("done", report="left arm picked the block and handed it to the right arm, which stood it on the "
                            "blue pad and let go", success_claim=True)

TASK = HandoverBlock
