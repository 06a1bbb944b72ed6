"""place_dual_shoes: put both shoes into the shoe box, toes pointing left.

Description
    The table is lowered by 10 cm (top at 0.64 m). An open cardboard shoe box stands in front of
    the robot at the middle of the table, its length along world x. A pair of children's sneakers
    (left and right foot, 19 cm long) stands on the table, one on each side of the box, each
    upright at a random heading. The robot must put both shoes into the box side by side with their
    toes pointing to the left (-x) and let go of them.

Randomisation (per seed)
    Shoe style 0-4 (the same for both shoes, as upstream loads one ``041_shoe`` id for both).
    ``rand_pose`` with upstream's base quaternion [0.707, 0.707, 0, 0] (sole down) and a random turn
    of +-pi about the shoe's up axis: left shoe x in [-0.3, -0.2], right shoe x in [0.2, 0.3], both
    y in [-0.1, 0.05] (``ylim_prop``), >= 0.15 m from the origin, standing on the lowered table
    (origin on the sole, z = 0.641: upstream's 0.741 less the 0.1 table drop). This shoe's
    footprint adds one constraint: every point of it keeps >= 3.5 cm from the box (upstream's
    meshes and ours differ; without it some draws would put a shoe through the box wall, or leave
    no room for fingers between a heel and the box). The shoe box is static at
    (0, -0.13) on the table (FACTS gives z 0.74 and quaternion [0.5, 0.5, -0.5, -0.5] for
    upstream's mesh frame; this box's origin is its bottom centre, standing on the lowered table).

Success (final state; CodeActionBench's adaptation of RoboTwin's ``place_dual_shoes``)
    ``assignment_xy``: an allowed assignment of shoes to the two places: either the left shoe's
    origin within 0.05 m (per axis, x and y) of (0, -0.17) and the right shoe's within 0.05 m of
    (0, -0.09), or swapped (the benchmark accepts either pairing; RoboTwin only the first);
    ``heights``: both shoe origins (on the sole's underside) within 0.03 m of the box's z + 0.01
    (the box floor's top: the shoes stand on the floor);
    ``orientations``: both shoe quaternions (sign-normalised, w >= 0) within 0.07 per component of
    [0.5, 0.5, -0.5, -0.5] (sole down, toe toward -x);
    ``grippers_open``: both commanded gripper values > 0.8.
    Guard: neither shoe may fall off the table.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, cylinder
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, margin_all, margin_any, margin_within
from cab_core.geometry import pose_inv, pose_mul, quat_to_mat, transform_point
from cab_core.kits.margins import grippers_open
from cab_core.kits.oracle import TOLERANT, Hands, OracleFailed, tcp_quat
from cab_core.kits.scene import DESTRUCTIVE_DROP, draw_variant, pose_list, rand_pose, sample_until, vec
from cab_core.kits.task import arm_names

from ..assets_articulated import (
    SHOE_BOX,
    SHOE_MASS,
    SHOE_STYLES,
    shoe_box_shapes,
    shoe_geometry,
    shoe_outline,
    shoe_shapes,
)
from ..common import CodeActionTask

TABLE_Z_BIAS = -0.1
BOX_XY = (0.0, -0.13)
SLOT_OFFSET = 0.04  # places at box y -+ 0.04: (0, -0.17) "left shoe", (0, -0.09) "right shoe"
XY_TOLERANCE = 0.05
Z_TOLERANCE = 0.03
FLOOR_OFFSET = 0.01  # upstream: shoe z within 0.03 of box z + 0.01
TARGET_QUAT = (0.5, 0.5, -0.5, -0.5)  # sole down, toe toward world -x
QUAT_TOLERANCE = 0.07
GRIPPER_OPEN = 0.8
SPAWN_QUAT = (0.70710678, 0.70710678, 0.0, 0.0)  # sole down, toe toward world -y
BOX_CLEARANCE = 0.035  # room for fingers round a shoe next to the box

# --- the reference solution's grasp and placement --------------------------------------------------
TIP_AHEAD = 0.0354
TIP_ABOVE_INSOLE = 0.022  # fingertips above the cavity floor: the wide finger bodies clear a box wall
HOVER = 0.14
LIFT = 0.12
PLACE_X = -0.02  # shoe origin x at release: the heel (at +x) keeps room for the open fingers
RELEASE_DROP = 0.004  # the sole is let go this far above the box floor
PRE_GRIP = 0.5  # half-open fingers straddle the heel counter with 1.5 cm to spare on each side
# where each arm's TCP waits (world x) while the other one works over the box: the right arm, its
# shoe in hand, while the left one places (the left arm's wrist and open fingers reach x ~ 0.15);
# the left arm, empty, while the right one carries its shoe, whose toe swings round the TCP
RIGHT_WAIT_X = 0.28
LEFT_PARK_X = -0.32
# each shoe is set down this far outward (y) of its place: the 6.6 cm wide shoes then stand 2.6 cm
# apart (not 1.4), so one nudged while its gripper lets go cannot lean on the other; the box's inner
# walls stay 1.1 cm away
PLACE_SPREAD = 0.006
MAX_STEP = 0.3  # the longest move_delta (longer ones are clamped)
# over the box, a shoe turned in the grip by more than this (largest quaternion component off the
# target, the verifier's measure) is aimed again, at most REAIM_TRIES reaches in all
REAIM_QUAT_ERROR = 0.03
REAIM_TRIES = 3


def _qnorm(q) -> np.ndarray:
    q = np.asarray(q, float)
    return -q if q[0] < 0 else q


def _quat_error(q, target) -> float:
    """The verifier's orientation measure: the largest quaternion component off the target."""
    return float(np.max(np.abs(_qnorm(q) - np.asarray(target, float))))


class PlaceDualShoesVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.shoes = (info["shoes"]["left"]["name"], info["shoes"]["right"]["name"])
        self.box = info["box"]["name"]
        self.places = (np.asarray(info["places"]["left"], float), np.asarray(info["places"]["right"], float))
        self.xy_tol = float(info["xy_tolerance"])
        self.z_tol = float(info["z_tolerance"])
        self.floor_offset = float(info["floor_offset"])
        self.q_target = np.asarray(info["target_quat"], float)
        self.q_tol = float(info["quat_tolerance"])
        self.arms = list(info["arms"])
        self.guarded_objects = self.shoes
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        poses = [np.asarray(w.pose(n), float) for n in self.shoes]
        box_z = float(w.pose(self.box)[2])

        def at(p, place) -> bool:
            return bool(np.all(np.abs(p[:2] - place) < self.xy_tol))

        direct = at(poses[0], self.places[0]) and at(poses[1], self.places[1])
        swapped = at(poses[0], self.places[1]) and at(poses[1], self.places[0])
        dq = [np.abs(_qnorm(p[3:]) - self.q_target) for p in poses]
        dz = [float(p[2] - (box_z + self.floor_offset)) for p in poses]
        oriented = all(bool(np.all(d < self.q_tol)) for d in dq)
        heights = all(abs(d) < self.z_tol for d in dz)
        open_, grips, grips_margin = grippers_open(w, self.arms, GRIPPER_OPEN)
        values: dict[str, float] = {}
        for side, p, q, z in zip(("left", "right"), poses, dq, dz):
            for k, place in zip(("left_place", "right_place"), self.places):
                values[f"{side}_shoe_to_{k}_dx"] = float(p[0] - place[0])
                values[f"{side}_shoe_to_{k}_dy"] = float(p[1] - place[1])
            values[f"{side}_shoe_dz"] = z
            values[f"{side}_shoe_quat_err"] = float(np.max(q))
        values.update(grips)
        values["swapped_assignment"] = float(swapped and not direct)
        preds = {"assignment_xy": bool(direct or swapped), "heights": heights, "orientations": oriented,
                 "grippers_open": open_}

        def at_margin(p, place):
            return margin_within(p[:2] - place, self.xy_tol, "m")

        margins = {
            "assignment_xy": margin_any(
                margin_all(at_margin(poses[0], self.places[0]), at_margin(poses[1], self.places[1])),
                margin_all(at_margin(poses[0], self.places[1]), at_margin(poses[1], self.places[0]))),
            "heights": margin_within(dz, self.z_tol, "m"),
            "orientations": margin_within(np.concatenate(dq), self.q_tol, "quaternion component"),
            "grippers_open": grips_margin,
        }
        return Evaluation(success=all(preds.values()), predicates=preds, values=values, margins=margins)


class PlaceDualShoes(CodeActionTask):
    table_z_bias = TABLE_Z_BIAS
    verifier_class = PlaceDualShoesVerifier
    subgoal_predicates = (("assignment_xy",), ("assignment_xy", "heights", "orientations"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        style_id, style = draw_variant(rng, SHOE_STYLES)
        geo = shoe_geometry(style)
        bx = SHOE_BOX
        box_half = np.array([bx.inner[0] / 2 + bx.wall_t, bx.inner[1] / 2 + bx.wall_t])
        box_pose = np.array([BOX_XY[0], BOX_XY[1], top, 1.0, 0.0, 0.0, 0.0])

        shoes: dict[str, dict[str, Any]] = {}
        for side, xlim in (("left", (-0.3, -0.2)), ("right", (0.2, 0.3))):
            outline = shoe_outline(style, side)  # design frame (X toe, Y left) = body (z, x)
            local = np.stack([outline[:, 1], np.zeros(len(outline)), outline[:, 0]], axis=1)

            def ok(p: np.ndarray, local=local) -> bool:
                if np.hypot(p[0], p[1]) < 0.15:
                    return False
                r = quat_to_mat(p[3:])
                foot = (local @ r.T)[:, :2] + p[:2]
                d = np.maximum(np.abs(foot - box_pose[:2]) - box_half, 0.0)
                return bool(np.all(np.hypot(d[:, 0], d[:, 1]) >= BOX_CLEARANCE))

            pose = sample_until(
                lambda xlim=xlim: rand_pose(rng, xlim, (-0.1, 0.05), (top + 0.001,), ylim_prop=True, rotate_rand=True,
                                  rotate_lim=(0.0, np.pi, 0.0), qpos=SPAWN_QUAT),
                ok, what=f"the {side} shoe")
            name = f"{side}_shoe"
            scene.bodies.append(Body(name, shoe_shapes(style, side, f"shoe{style_id}{side[0].upper()}"),
                                     pose=tuple(pose), kind="dynamic", mass=SHOE_MASS, angular_damping=0.1))
            toe = quat_to_mat(pose[3:])[:, 2]
            shoes[side] = {"name": name, "foot": side, "pose": pose_list(pose),
                           "toe_heading": round(float(np.arctan2(toe[1], toe[0])), 6)}
        scene.bodies.append(Body("shoe_box", shoe_box_shapes(bx), pose=tuple(box_pose), kind="static"))

        grasp_tcp = np.asarray(geo["heel_wall_center"], float)
        grasp_tcp[1] = geo["sole_thickness"] + TIP_ABOVE_INSOLE + TIP_AHEAD
        # at release the shoe stands toe-left on the box floor, midway between the places (box frame)
        release_tcp = transform_point([PLACE_X, 0.0, bx.floor_t + RELEASE_DROP, *TARGET_QUAT], grasp_tcp)
        info = {
            "table_z_bias": TABLE_Z_BIAS,
            "arms": list(arm_names(embodiment)),
            "style_id": style_id,
            "shoe": {
                "frame": "shoe body: origin on the sole's underside at the middle of its length and width; "
                         "+y up (out of the sole), +z toward the toe, +x toward the shoe's left side",
                "mass_kg": SHOE_MASS,
                **{k: (vec(v) if isinstance(v, list) else round(float(v), 6)) for k, v in geo.items()},
                # where a top-down pinch of the heel counter puts the TCP (fingers along the shoe's
                # length, one inside the heel cavity, one behind the heel)
                "grasp_tcp_point": vec(grasp_tcp),
            },
            "shoes": shoes,
            "box": {
                "name": "shoe_box",
                "pose": pose_list(box_pose),
                "frame": "box body: origin at the bottom centre, +x along its length, +z up",
                "inner_size": vec([*bx.inner, bx.height - bx.floor_t]),
                "outer_size": vec([2 * box_half[0], 2 * box_half[1], bx.height]),
                "floor_top_z": round(top + bx.floor_t, 6),
                "wall_thickness": bx.wall_t,
            },
            # RoboTwin's places: (0, -0.13) -+ (0, 0.04); the benchmark accepts either shoe at either
            "places": {"left": [BOX_XY[0], BOX_XY[1] - SLOT_OFFSET], "right": [BOX_XY[0], BOX_XY[1] + SLOT_OFFSET]},
            "xy_tolerance": XY_TOLERANCE,
            "z_tolerance": Z_TOLERANCE,
            "floor_offset": FLOOR_OFFSET,
            "target_quat": list(TARGET_QUAT),
            "quat_tolerance": QUAT_TOLERANCE,
            "gripper_open_threshold": GRIPPER_OPEN,
            # the reference solution's TCP at release, in the box frame (midway between the places)
            "release_tcp_box": vec(release_tcp),
        }
        return info

    # -- checkpoints --------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        grasp = np.asarray(info["shoe"]["grasp_tcp_point"], float)
        release = np.asarray(info["release_tcp_box"], float)
        box = info["box"]["name"]

        def approach(name: str):
            return lambda w: transform_point(w.pose(name), grasp)

        return [
            SpatialRule("Approach left shoe", "either", approach(info["shoes"]["left"]["name"]),
                        cylinder(5.0, (-3.0, 6.0))),
            SpatialRule("Approach right shoe", "either", approach(info["shoes"]["right"]["name"]),
                        cylinder(5.0, (-3.0, 6.0))),
            # catalog prerequisite "1 or 2"; the rule's prerequisites are all-of: the reference
            # solution approaches both shoes before placing either
            SpatialRule("Place at shoe box", "either", lambda w: transform_point(w.pose(box), release),
                        cylinder(10.0, (-2.0, 5.0)), prerequisites=(0, 1), any_prerequisite=True),
        ]

    # -- reference solution -------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """Both arms pinch their shoe's heel counter top-down at once (fingers along the shoe, one
        inside the heel cavity, one behind the heel) and lift (a shoe not held is picked again);
        the right arm waits with its shoe at x >= RIGHT_WAIT_X while the left arm turns its shoe
        toe-left, sets it down in the near place, opens and parks at x = LEFT_PARK_X; the right arm
        puts its shoe in the far place the same way. Each lets go half open and opens fully
        once risen clear of its shoe (21-22 tool calls). From a later state (a fork): a shoe already
        in its place stays, a shoe in hand is carried on (``keeps_hands``), the shoes still to move
        are picked one arm at a time."""
        shoes = _ShoePlacing(call, world)
        # from a later state (a fork): a shoe already in its place stays there, a shoe in hand is
        # carried on; neither at the scene's start
        placed = {a: self._placed(world, a) for a in shoes.arms}
        held = {a: self._holds(world, a) for a in shoes.arms}
        if not any(placed.values()) and not any(held.values()):
            shoes.pick_both()
        else:
            shoes.go_on(placed, held)
        shoes.pick_again(placed)
        shoes.wait_right(placed)
        # 2. one after the other: carry over the place (turning the toe to -x), set down, let go
        for arm in shoes.arms:
            if not placed[arm]:
                shoes.put_down(arm)
        call("done", report="put both shoes into the shoe box side by side, toes pointing left, and let go",
             success_claim=True)

    @staticmethod
    def _park_left(world: WorldView, h: Hands) -> None:
        """The left hand out along x to LEFT_PARK_X (clear of the right shoe's swing)."""
        for _ in range(2):  # move_delta goes at most MAX_STEP at a time
            dx = LEFT_PARK_X - float(world.tcp_pose(h.arm)[0])
            if dx > -0.01:
                break
            h.move(dx=max(dx, -MAX_STEP), what="out of the way", ok=TOLERANT)

    @staticmethod
    def _holds(world: WorldView, arm: str) -> bool:
        """Whether ``arm``'s closed gripper holds its own shoe (the left arm the left shoe)."""
        return world.gripper_command(arm) < 0.3 and world.gripper_holds(arm, world.info["shoes"][arm]["name"])

    @classmethod
    def _placed(cls, world: WorldView, arm: str) -> bool:
        """Whether ``arm``'s shoe stands in its place in the box, toe left, not held."""
        info = world.info
        p = np.asarray(world.pose(info["shoes"][arm]["name"]), float)
        place = np.asarray(info["places"][arm], float)
        return bool(np.all(np.abs(p[:2] - place) < 0.03)
                    and abs(p[2] - float(info["box"]["floor_top_z"])) < 0.015
                    and _quat_error(p[3:], info["target_quat"]) < 0.05
                    and not cls._holds(world, arm))

    def keeps_hands(self, world: WorldView) -> bool:
        """True where a closed hand holds its shoe, or a hand is still by its shoe set down in the
        box: the solution carries the shoe on, or lets go and rises as it would have."""
        if world.start is None:
            return False
        for a in world.info["arms"]:
            shoe = world.info["shoes"][a]["name"]
            if self._holds(world, a):
                return True
            if self._placed(world, a) and (world.gripper_touches(a, shoe) or np.linalg.norm(
                    world.tcp_pose(a)[:3] - world.pose(shoe)[:3]) < 0.2):
                return True
        return False


class _ShoePlacing:
    """The stages of the reference solution (:meth:`PlaceDualShoes.solve`): the box's pose is the
    one read before the first move."""

    arms = ("left", "right")

    def __init__(self, call, world: WorldView):
        self.call, self.world = call, world
        info = world.info
        self.info = info
        self.grasp = np.asarray(info["shoe"]["grasp_tcp_point"], float)
        self.target_q = np.asarray(info["target_quat"], float)
        self.box = np.asarray(world.pose(info["box"]["name"]), float)
        self.shoe_of = {a: info["shoes"][a]["name"] for a in self.arms}
        self.place_of = {"left": info["places"]["left"], "right": info["places"]["right"]}
        self.hands = {a: Hands(call, a) for a in self.arms}
        self.up = np.array([0.0, 0.0, HOVER])

    def pick_quat(self, arm: str) -> np.ndarray:
        """Top-down, opening line along the shoe; of its two senses, the one that keeps both
        the pick and the place orientation closest to the gripper's present roll."""
        world = self.world
        s = np.asarray(world.pose(self.shoe_of[arm]), float)
        toe = quat_to_mat(s[3:])[:, 2]
        toe_now = np.arctan2(toe[1], toe[0])
        turn = np.pi - toe_now  # the toe ends at world -x
        cur = quat_to_mat(world.tcp_pose(arm)[3:])[:, 1]
        best, cost = None, np.inf
        for sign in (1.0, -1.0):
            o = sign * np.array([toe[0], toe[1], 0.0])
            c, s_ = np.cos(turn), np.sin(turn)
            o_place = np.array([c * o[0] - s_ * o[1], s_ * o[0] + c * o[1], 0.0])
            k = max(_angle_between(o, cur), _angle_between(o_place, cur))
            if k < cost:
                best, cost = o, k
        return np.asarray(tcp_quat([0.0, 0.0, -1.0], best))

    def aim(self, a: str):
        """A shoe that slipped out is picked again where it lies (heel aimed from its present pose)."""
        return lambda pose: (transform_point(pose, self.grasp), self.pick_quat(a))

    def pick_both(self) -> None:
        """1. Both arms at once: fingers half open (a shoe may stand with its heel close to the box),
        hover above the heels, descend, pinch, lift."""
        world, call, arms = self.world, self.call, self.arms
        for a in arms:
            self.hands[a].grip(PRE_GRIP)
        grasp_w = {a: transform_point(world.pose(self.shoe_of[a]), self.grasp) for a in arms}
        q = {a: self.pick_quat(a) for a in arms}
        r = call("reach_both_tcp", left_xyz=(grasp_w["left"] + self.up).tolist(),
                 right_xyz=(grasp_w["right"] + self.up).tolist(), left_quat=q["left"].tolist(),
                 right_quat=q["right"].tolist())
        if r.get("status") != "SUCCESS":
            raise OracleFailed(f"hover above the heels: {r.get('status')} {r.get('failure')}")
        down = {a: (grasp_w[a] - world.tcp_pose(a)[:3]).tolist() for a in arms}
        call("move_both_delta", left_delta=down["left"], right_delta=down["right"])
        for a in arms:
            self.hands[a].grip(0.0)
        call("move_both_delta", left_delta=[0.0, 0.0, LIFT], right_delta=[0.0, 0.0, LIFT])

    def go_on(self, placed: dict[str, bool], held: dict[str, bool]) -> None:
        """From a later state: a hand by its placed shoe lets go and rises clear, a held shoe still
        down is lifted, the left hand parks once its shoe is placed, and the shoes neither placed nor
        held are picked one arm at a time."""
        world, info, hands = self.world, self.info, self.hands
        floor = float(info["box"]["floor_top_z"])
        for a in self.arms:
            if placed[a] and not held[a]:  # a hand by its placed shoe lets go, rises clear
                if float(world.tcp_pose(a)[2]) < floor + 0.12:
                    if world.gripper_command(a) < PRE_GRIP:
                        hands[a].grip(PRE_GRIP)
                    hands[a].move(dz=0.10, what="rise", ok=TOLERANT)
                if world.gripper_command(a) < 1.0:
                    hands[a].grip(1.0)
            elif held[a] and float(world.pose(self.shoe_of[a])[2]) < float(info["table_top_z"]) + 0.05:
                hands[a].move(dz=LIFT, what="lift", ok=TOLERANT)
        if placed["left"] and not held["left"]:
            PlaceDualShoes._park_left(world, hands["left"])
        for a in self.arms:
            if not placed[a] and not held[a]:
                hands[a].grip(PRE_GRIP)
                hands[a].pick_held(world, self.shoe_of[a], self.aim(a), lift=LIFT)

    def pick_again(self, placed: dict[str, bool]) -> None:
        """A shoe still to place that no hand holds is picked again where it lies."""
        for a in self.arms:
            if not placed[a] and not self.world.gripper_holds(a, self.shoe_of[a]):
                self.hands[a].grip(PRE_GRIP)
                self.hands[a].pick_held(self.world, self.shoe_of[a], self.aim(a), lift=LIFT)

    def wait_right(self, placed: dict[str, bool]) -> None:
        """The right arm waits out of the left arm's way (a heel picked near the box would leave its
        wrist where the left wrist comes down to place)."""
        wait_dx = RIGHT_WAIT_X - float(self.world.tcp_pose("right")[0])
        if wait_dx > 0.01 and not placed["right"]:
            self.hands["right"].move(dx=wait_dx, what="wait aside with the right shoe", ok=TOLERANT)

    def put_down(self, arm: str) -> None:
        """``arm`` carries its shoe over its place (turning the toe to -x), sets it down, lets go
        half open, rises and opens fully; the left hand then parks."""
        world, info = self.world, self.info
        spread = -PLACE_SPREAD if arm == "left" else PLACE_SPREAD
        px, py = PLACE_X + self.box[0] - BOX_XY[0], self.place_of[arm][1] + spread
        shoe_goal = np.array([px, py, float(info["box"]["floor_top_z"]) + RELEASE_DROP, *self.target_q])
        h = self.hands[arm]
        # the shoe, held by its heel, can turn in the grip while it is carried: the TCP's goal
        # is aimed again from where the shoe hangs once over the box
        for _ in range(REAIM_TRIES):
            s = np.asarray(world.pose(self.shoe_of[arm]), float)
            held = pose_mul(pose_inv(s), world.tcp_pose(arm))  # the TCP in the shoe frame
            tcp_goal = pose_mul(shoe_goal, held)
            h.reach(tcp_goal[:3] + self.up, tcp_goal[3:], f"carry the {arm} shoe over the box")
            if _quat_error(world.pose(self.shoe_of[arm])[3:], self.target_q) < REAIM_QUAT_ERROR:
                break
        h.descend_to(float(tcp_goal[2]), f"set the {arm} shoe down", ok=TOLERANT)
        # let go half open: a fully open inner finger ends under the front of the heel opening
        # and can catch the collar on the way up (the shoe is then lifted with the gripper);
        # the fingers open fully once clear above the shoe
        h.grip(PRE_GRIP)
        h.move(dz=0.10, what="rise", ok=TOLERANT)
        h.grip(1.0)
        if arm == "left":  # well clear of the right shoe's swing on its way to the box
            PlaceDualShoes._park_left(world, h)


def _angle_between(a, b) -> float:
    """Angle between two directions (rad)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.arccos(np.clip(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))


TASK = PlaceDualShoes
