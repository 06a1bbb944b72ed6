"""move_can_pot: put the sauce can down beside the pot, on the side it came from.

Description
    A kitchen pot (two side handles) stands in the middle of the table; a sauce can stands upright
    further out to the left or the right, towards the back. With one arm the robot must pick the can
    up and set it down upright beside the pot, on the same side (left or right) where it started,
    level with the pot (aligned with it front to back), and let go.

Randomisation (per seed)
    Pot: one of four variants (upstream's ``060_kitchenpot`` ids 0-6; here a red, a steel, a blue
    and a cream pot, 15-17 cm across, 8.5-10 cm tall, with 4 cm handle tabs: at most 25 cm from
    handle end to handle end, so that a can fits beside the pot within 0.2 m of its centre) at (0, 0) with yaw in
    +-pi/8. Can: one of five sauce cans (upstream's ``105_sauce-can`` ids {0, 2, 4, 5, 6}; here
    6.0-6.8 cm across, 9-11 cm tall, 0.30-0.42 kg), upright, drawn with ``rand_pose``:
    x in [-0.3, 0.3] with |x| >= 0.2, y in [0.05, 0.15], yaw +-pi/4 (about the can's axis), redrawn
    until its centre is >= 0.3 m from the pot's (FACTS B.6). Both stand on the table (origins at
    the centres of their bottoms, 0.2 mm above the table top). The arm on the can's side
    (x < 0: left) is the acting arm ``arm``.

Success (final state; upstream's check)
    With dis = pot.x - can.x for the left arm, can.x - pot.x for the right:
    ``on_start_side``: dis > 0; ``near_pot``: dis < 0.2;
    ``aligned_with_pot``: |pot.y - can.y| < 0.035;
    ``can_upright``: the can's transforms3d ('sxyz') Euler angles are within 15 deg of 90 deg (x)
    and of 0 (y) (the can's axis is its local +y, as in upstream's model frame);
    ``set_down``: can z <= the pot's initial z + 0.001 (both origins are at the bottom: the can
    stands on the table);
    ``grippers_open``: both grippers' commanded values > 0.8.
    Guards: neither the can nor the pot may fall off the table.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, cylinder
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Margin, WorldView, margin_above, margin_below, margin_within
from cab_core.geometry import quat_to_mat, transform_point
from cab_core.kits.oracle import OPEN, TOLERANT, Hands, top_down_quat
from cab_core.kits.scene import DESTRUCTIVE_DROP, draw_variant, pose_list, rand_pose, sample_until, vec, yaw_of
from cab_core.kits.task import GrippersOpenVerifier

from ..assets_pots import CAN_VARIANTS, POT_VARIANTS, can_geometry, can_shapes, pot_geometry, pot_shapes
from ..common import CodeActionTask

POT_IDS = tuple(range(len(POT_VARIANTS)))
CAN_IDS = tuple(sorted(CAN_VARIANTS))
UPRIGHT_Q = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # can axis (local +y) -> world +z
MAX_DIS = 0.2
ALIGN_TOL = 0.035
ANGLE_TOL = math.radians(15.0)
SET_DOWN_TOL = 0.001
GRIPPER_OPEN = 0.8
# the oracle: grasp the can top-down this far below its top, set it down this far from the pot's
# centre (clear of the wall and of a handle tab turned toward it), release from this height
GRASP_BELOW_TOP = 0.02
PLACE_DIS = 0.175
RELEASE_DROP = 0.003


def euler_sxyz(q) -> tuple[float, float, float]:
    """transforms3d's ``quat2euler(q)`` (static x-y-z axes): angles (ax, ay, az), R = Rz Ry Rx."""
    m = quat_to_mat(q)
    cy = math.hypot(m[0, 0], m[1, 0])
    if cy > 1e-9:
        return (math.atan2(m[2, 1], m[2, 2]), math.atan2(-m[2, 0], cy), math.atan2(m[1, 0], m[0, 0]))
    return (math.atan2(-m[1, 2], m[1, 1]), math.atan2(-m[2, 0], cy), 0.0)


class MoveCanPotVerifier(GrippersOpenVerifier):
    open_threshold = GRIPPER_OPEN  # both arms'

    def __init__(self, info: dict[str, Any]):
        self.pot = info["pot"]["name"]
        self.can = info["can"]["name"]
        self.sign = -1.0 if info["arm"] == "left" else 1.0  # the can's side of the pot, along x
        self.pot_z0 = float(info["pot"]["initial_z"])
        self.guarded_objects = (self.can, self.pot)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def measure(self, w: WorldView) -> tuple[dict[str, bool], dict[str, float], dict[str, Margin]]:
        pot = w.pose(self.pot)
        can = w.pose(self.can)
        dis = self.sign * float(can[0] - pot[0])
        dy = float(pot[1] - can[1])
        ax, ay, _ = euler_sxyz(can[3:])
        preds = {
            "on_start_side": dis > 0.0,
            "near_pot": dis < MAX_DIS,
            "aligned_with_pot": abs(dy) < ALIGN_TOL,
            "can_upright": abs(ax - math.pi / 2) < ANGLE_TOL and abs(ay) < ANGLE_TOL,
            "set_down": float(can[2]) <= self.pot_z0 + SET_DOWN_TOL,
        }
        # the band 0 < dis < MAX_DIS is what both side predicates are judged against
        margins = {
            "on_start_side": margin_above(dis, 0.0, "m", MAX_DIS),
            "near_pot": margin_below(dis, MAX_DIS, "m"),
            "aligned_with_pot": margin_within([dy], ALIGN_TOL, "m"),
            "can_upright": margin_within([ax - math.pi / 2, ay], ANGLE_TOL, "rad"),
            "set_down": margin_below(float(can[2]), self.pot_z0 + SET_DOWN_TOL, "m", SET_DOWN_TOL),
        }
        values = {"dis": dis, "dy": dy, "can_euler_x_deg": math.degrees(ax), "can_euler_y_deg": math.degrees(ay),
                  "can_z": float(can[2])}
        return preds, values, margins


class MoveCanPot(CodeActionTask):
    verifier_class = MoveCanPotVerifier
    # (1) beside the pot; (2) beside it, upright and set down
    subgoal_predicates = (("on_start_side", "near_pot", "aligned_with_pot"),
                          ("on_start_side", "near_pot", "aligned_with_pot", "can_upright", "set_down"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        pot_id, pv = draw_variant(rng, POT_VARIANTS, POT_IDS)
        can_id, cv = draw_variant(rng, CAN_VARIANTS, CAN_IDS)
        z = top + 2e-4
        pot_pose = rand_pose(rng, (0.0,), (0.0,), (z,), rotate_rand=True, rotate_lim=(0.0, 0.0, np.pi / 8))
        can_pose = sample_until(
            lambda: rand_pose(rng, (-0.3, 0.3), (0.05, 0.15), (z,), rotate_rand=True,
                              rotate_lim=(0.0, np.pi / 4, 0.0), qpos=UPRIGHT_Q),
            lambda p: abs(p[0]) >= 0.2 and math.hypot(p[0] - pot_pose[0], p[1] - pot_pose[1]) >= 0.3,
            what="the can")
        scene.bodies.append(Body("pot", pot_shapes(pv, pot_id), pose=tuple(pot_pose), kind="dynamic", mass=pv.mass,
                                 angular_damping=0.1))
        scene.bodies.append(Body("can", can_shapes(cv), pose=tuple(can_pose), kind="dynamic", mass=cv.mass,
                                 angular_damping=0.1))
        pg, cg = pot_geometry(pv), can_geometry(cv)
        arm = "left" if can_pose[0] < 0 else "right"
        info = {
            "arm": arm,  # the can's side; the verifier measures "beside" toward this side
            "max_dis": MAX_DIS,
            "align_tolerance": ALIGN_TOL,
            "angle_tolerance_deg": 15.0,
            "pot": {
                "name": "pot",
                "model_id": pot_id,
                "frame": "pot body: origin at the centre of the bottom, +z up, handles along -x and +x",
                "initial_pose": pose_list(pot_pose),
                "initial_z": round(float(pot_pose[2]), 6),
                "yaw": round(yaw_of(pot_pose[3:]), 6),
                "radius": pg["radius"],
                "height": pg["height"],
                "handle_points": [vec(h) for h in pg["handle_points"]],
                "handle_size": vec(pg["handle_size"]),
                "span_with_handles": round(pg["span_with_handles"], 6),
            },
            "can": {
                "name": "can",
                "model_id": can_id,
                "frame": "can body: origin at the centre of the bottom, the can's axis along local +y "
                         "(upright: quaternion [0.707, 0.707, 0, 0] times a turn about that axis)",
                "initial_pose": pose_list(can_pose),
                "radius": cg["radius"],
                "height": cg["height"],
                "axis_local": vec(cg["axis_local"]),
                "center_local": vec(cg["center_local"]),
                "top_local": vec(cg["top_local"]),
                "mass_kg": cg["mass_kg"],
                # the expert grasps on the axis, this far below the top (TCP-to-can offset)
                "grasp_local": vec([0.0, cg["height"] - GRASP_BELOW_TOP, 0.0]),
            },
            # where the expert sets the can down: dis and the TCP height above the pot's base
            "place_dis": PLACE_DIS,
            "place_tcp_above_base": round(cg["height"] - GRASP_BELOW_TOP + RELEASE_DROP, 6),
        }
        return info

    # --- checkpoints ---------------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        can, pot = info["can"], info["pot"]
        sign = -1.0 if info["arm"] == "left" else 1.0
        dis, above = float(info["place_dis"]), float(info["place_tcp_above_base"])

        def grasp(w):
            return transform_point(w.pose(can["name"]), can["grasp_local"])

        def beside(w):
            p = w.pose(pot["name"])
            return np.array([p[0] + sign * dis, p[1], float(pot["initial_z"]) + above])

        return [
            SpatialRule("Approach can", "either", grasp, cylinder(3.0, 3.0)),
            SpatialRule("Beside pot", "either", beside, cylinder(7.0, (-2.0, 5.0)), prerequisites=(0,)),
        ]

    # --- reference solution ----------------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """The arm on the can's side turns its gripper top-down where it is, travels straight to
        above the can, grasps it top-down (fingers opening front-back, i.e. along the pot's side,
        so that no finger comes between the can and the pot or a handle), lifts it above the pot's
        rim, carries it to 17.5 cm beside the pot's centre level with it, lowers it to 3 mm above
        the table, lets go and rises (9-10 tool calls)."""
        info = world.info
        arm = info["arm"]
        can, pot = info["can"], info["pot"]
        hands = Hands(call, arm)
        q = top_down_quat([0.0, 1.0, 0.0])
        grasp = transform_point(world.pose(can["name"]), can["grasp_local"])
        hover = grasp + [0.0, 0.0, 0.16]
        if world.gripper_holds(arm, can["name"]):
            # from a later stage (a fork; ``keeps_hands``): the can is in the hand already
            preds = self.evaluate(world).predicates
            if all(preds[k] for k in ("on_start_side", "near_pot", "aligned_with_pot", "can_upright", "set_down")):
                hands.grip(1.0)  # set down in its place: let go
                hands.move(dz=0.10, what="rise", ok=TOLERANT)
                call("done", report=f"set the can down upright {PLACE_DIS:.2f} m {arm} of the pot, level with it",
                     success_claim=True)
                return
            if float(world.pose(can["name"])[2]) < float(pot["initial_z"]) + 0.01:  # still on the table
                hands.move(dz=0.15, what="lift the can", ok=TOLERANT)
        else:
            if world.gripper_command(arm) < OPEN:
                hands.grip(1.0)
            # turn the wrist to top-down where the gripper is (a planned reach that turns it on the way
            # can sweep the fingers through the can: measured), then travel straight to the hover
            if not _top_down(world, arm, q):
                hands.turn_in_place(world, q, what="turn the gripper top-down")
            tcp = world.tcp_pose(arm)[:3]
            if not (np.linalg.norm(tcp[:2] - grasp[:2]) < 0.01 and grasp[2] - 0.01 < tcp[2] < hover[2] - 0.005):
                for _ in range(3):  # a move covers at most 0.30 m
                    d = hover - world.tcp_pose(arm)[:3]
                    if np.linalg.norm(d) < 0.005:
                        break
                    hands.move(*d, what="over the can", ok=TOLERANT)
            hands.move_to_height(world, grasp[2], "descend onto the can", ok=TOLERANT)
            hands.grip(0.0)
            hands.move(dz=0.15, what="lift the can", ok=TOLERANT)
        p = world.pose(pot["name"])
        sign = -1.0 if arm == "left" else 1.0
        # where the TCP must be for the can's base to end 3 mm above the table: keep the measured
        # TCP-to-can offset (the can may have slipped in the fingers)
        held = world.pose(can["name"])[:3] - world.tcp_pose(arm)[:3]
        base_z = float(pot["initial_z"]) + RELEASE_DROP
        target = np.array([p[0] + sign * PLACE_DIS, p[1], base_z]) - held
        hands.reach(target + [0.0, 0.0, 0.10], None, "carry beside the pot")
        hands.move_to_height(world, target[2], "set the can down", ok=TOLERANT)
        hands.grip(1.0)
        hands.move(dz=0.10, what="rise", ok=TOLERANT)
        call("done", report=f"set the can down upright {PLACE_DIS:.2f} m {arm} of the pot, level with it",
             success_claim=True)

    def keeps_hands(self, world: WorldView) -> bool:
        """Whether the can's arm holds the can, or is open and turned top-down (on its way to the
        can): then the solution goes on from there."""
        arm = world.info["arm"]
        return bool(world.gripper_holds(arm, world.info["can"]["name"])
                    or (world.gripper_command(arm) >= OPEN and _top_down(world, arm, top_down_quat([0.0, 1.0, 0.0]))))


def _top_down(world: WorldView, arm: str, q) -> bool:
    """Whether ``arm``'s TCP is turned as ``q`` (within about 2.5 deg)."""
    return abs(float(np.dot(world.tcp_pose(arm)[3:], q))) > 0.9998


TASK = MoveCanPot
