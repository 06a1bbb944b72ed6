"""place_bread_skillet: one arm lifts the skillet, the other puts the bread into it.

Description
    A frying pan (about 21 cm across the rim, 4.5 cm deep, a 14-15 cm handle rising at 25 deg
    from the rim) stands on one side of the table with its handle pointing to the front outer
    corner; a piece of bread (as in place_bread_basket) lies on the other side. The robot must lift
    the skillet with one arm and, with the other arm, put the bread into it and let go.

Randomisation (per seed; FACTS B.6)
    Bread model {0, 1, 3, 5, 6} with ``rand_pose``: x in [-0.28, 0.28] with |x| >= 0.2, y in
    [-0.2, 0.05], yaw +-pi/4 (upstream draws no rotation range for it; +-pi/4 as its other bread
    task). Skillet model 0-3 on the opposite side: x in [0.15, 0.25] (bread on the left) or
    [-0.25, -0.15], y in [-0.2, 0.05], yaw +-pi/6 about a base heading that points the handle
    50 deg outward from straight toward the robot (upstream's base orientation belongs to its
    mesh; this pan's handle then stays within the arms' reach). The skillet pose (not its model)
    is redrawn until, seen from above, the point 20 cm beyond the handle's end along the handle
    lies at least 0.24 m from the skillet arm's shoulder (the joint-2 axis at (+-0.22, -0.70)):
    a hand that slides onto the handle from beyond its end has its wrist about there, and a
    handle that points at the arm from near the table's front edge leaves the elbow no room
    (at 0.19 m, seed 100 before this rule, the approach needs the elbow past its 2.85 rad
    limit; at 0.19-0.22 m it comes within 0.05 rad of it; from 0.24 m it keeps about 0.08 rad
    or more). About 5 % of first draws are redrawn; the rest, the catalog seed among them,
    keep their instance.

Success (final state; CodeActionBench's subclass)
    ``bread_over_pan``: |bread x - pan point x| < 0.035 and |bread y - pan point y| < 0.035 (the
    pan point is the centre of the pan's inner floor, its functional point; it rests at
    z = table + 0.005);
    ``bread_at_pan_height``: |bread z - pan point z| < 0.06 (replaces upstream's absolute heights,
    so bread still held above the pan does not pass);
    ``bread_released``: no gripper (finger link) of either arm touches the bread.
    Lifting the skillet is what the instruction asks for, not a scored term (as the benchmark).
    Guard: neither the bread nor the skillet may fall off the table.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, cylinder
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, margin_within
from cab_core.geometry import quat_to_mat, transform_point
from cab_core.kits.oracle import TOLERANT, Hands, closest_opening, tcp_quat, top_down_quat, yaw_axis
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, sample_until, yaw_of
from cab_core.kits.task import arm_names

from ..assets_placing import BREAD_MASS, SKILLET_MASS, SKILLETS, bread_shapes, skillet_shapes
from ..common import CodeActionTask
from .place_bread_basket import grasp_tcp_dz

BREAD_IDS = (0, 1, 3, 5, 6)
XY_TOLERANCE = 0.035
Z_TOLERANCE = 0.06
HANDLE_OUTWARD = np.deg2rad(50.0)  # base heading of the handle: from -y toward the skillet's side
# reach rule (Randomisation): the wrist of a hand sliding onto the handle from beyond its end sits
# about WRIST_BEYOND_END (horizontally) beyond the handle's end; it must keep MIN_WRIST_SHOULDER
# from that arm's shoulder (aloha_agilex joint-2 axis, seen from above)
SHOULDER_XY = {"left": (-0.22, -0.70), "right": (0.22, -0.70)}
WRIST_BEYOND_END = 0.20
MIN_WRIST_SHOULDER = 0.24
RELEASE_GAP = 0.005  # bread bottom above the pan floor when the expert lets go


def wrist_to_shoulder(pose, sdims: dict, shoulder_xy) -> float:
    """Seen from above: distance from ``shoulder_xy`` to the point WRIST_BEYOND_END beyond the
    handle's end along the handle of a skillet at ``pose`` (the reach rule of ``build``)."""
    pose = np.asarray(pose, dtype=float)
    axis_local = np.asarray(sdims["handle_axis"], float)
    end = transform_point(pose, np.asarray(sdims["handle_start"], float) + float(sdims["handle_length"]) * axis_local)
    axis = (quat_to_mat(pose[3:]) @ axis_local)[:2]
    wrist = end[:2] + WRIST_BEYOND_END * axis / np.linalg.norm(axis)
    return float(np.linalg.norm(wrist - np.asarray(shoulder_xy, float)))


class PlaceBreadSkilletVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.bread = info["bread"]["name"]
        self.skillet = info["skillet"]["name"]
        self.pan_point = np.asarray(info["skillet"]["pan_point"], dtype=float)
        self.arms = list(info["arms"])
        self.guarded_objects = (self.bread, self.skillet)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        b = np.asarray(w.pose(self.bread)[:3], dtype=float)
        pan = transform_point(w.pose(self.skillet), self.pan_point)
        d = b - pan
        over = bool(abs(d[0]) < XY_TOLERANCE and abs(d[1]) < XY_TOLERANCE)
        height = bool(abs(d[2]) < Z_TOLERANCE)
        touching = {a: bool(w.gripper_touches(a, self.bread)) for a in self.arms}
        released = not any(touching.values())
        values = {"bread_dx": float(d[0]), "bread_dy": float(d[1]), "bread_dz": float(d[2]),
                  "pan_point_z": float(pan[2])}
        values.update({f"gripper_{a}_touches_bread": float(t) for a, t in touching.items()})
        return Evaluation(success=over and height and released,
                          predicates={"bread_over_pan": over, "bread_at_pan_height": height,
                                      "bread_released": released},
                          values=values,
                          # ``bread_released`` is an event (no finger touches the bread): no margin
                          margins={"bread_over_pan": margin_within(d[:2], XY_TOLERANCE, "m"),
                                   "bread_at_pan_height": margin_within(d[2:], Z_TOLERANCE, "m")})


class PlaceBreadSkillet(CodeActionTask):
    verifier_class = PlaceBreadSkilletVerifier
    # (1) the bread aligned with the pan point and within 6 cm in height; (2) that, with neither
    # gripper touching the bread
    subgoal_predicates = (("bread_over_pan", "bread_at_pan_height"),
                          ("bread_over_pan", "bread_at_pan_height", "bread_released"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        bread_id = int(BREAD_IDS[int(rng.integers(0, len(BREAD_IDS)))])
        bshapes, bdims = bread_shapes(bread_id)
        h = bdims["size"][2]
        bread_pose = None
        while bread_pose is None or abs(bread_pose[0]) < 0.2:
            bread_pose = rand_pose(rng, (-0.28, 0.28), (-0.2, 0.05), (top + h / 2 + 0.001,), rotate_rand=True,
                                   rotate_lim=(0.0, 0.0, np.pi / 4))
        side = -1.0 if bread_pose[0] > 0 else 1.0  # the skillet's side (+1: right)
        skillet_id = int(rng.integers(0, len(SKILLETS)))
        sshapes, sdims = skillet_shapes(skillet_id)
        base_heading = -np.pi / 2 + side * HANDLE_OUTWARD  # the handle's direction (body +x)
        q0 = (float(np.cos(base_heading / 2)), 0.0, 0.0, float(np.sin(base_heading / 2)))
        xlim = (0.15, 0.25) if side > 0 else (-0.25, -0.15)
        shoulder = np.asarray(SHOULDER_XY["right" if side > 0 else "left"])

        def reachable(pose: np.ndarray) -> bool:
            return wrist_to_shoulder(pose, sdims, shoulder) >= MIN_WRIST_SHOULDER

        skillet_pose = sample_until(
            lambda: rand_pose(rng, xlim, (-0.2, 0.05), (top + 0.0005,), rotate_rand=True,
                              rotate_lim=(0.0, 0.0, np.pi / 6), qpos=q0),
            reachable, what="skillet (handle within the arm's reach)")

        scene.bodies.append(Body("bread", bshapes, pose=tuple(bread_pose), kind="dynamic", mass=BREAD_MASS))
        scene.bodies.append(Body("skillet", sshapes, pose=tuple(skillet_pose), kind="dynamic", mass=SKILLET_MASS,
                                 angular_damping=0.1))
        pan_point = np.asarray(sdims["pan_point"])
        gdz = grasp_tcp_dz(h, top, float(bread_pose[2]))
        info = {
            "xy_tolerance": XY_TOLERANCE,
            "z_tolerance": Z_TOLERANCE,
            "arms": list(arm_names(embodiment)),
            "bread": {
                "name": "bread",
                "frame": "bread body: centre of its bounding box, x along its length, y across (grasp), z up",
                **bdims,
                "pose": pose_list(bread_pose),
                "yaw": round(yaw_of(bread_pose[3:]), 6),
                "grasp_tcp_dz": round(gdz, 6),
            },
            "skillet": {
                "name": "skillet",
                "frame": "skillet body: origin at the centre of the pan's bottom face, +x along the handle "
                         "(seen from above), z up",
                **sdims,
                "pose": pose_list(skillet_pose),
                "yaw": round(yaw_of(skillet_pose[3:]), 6),
                "pan_point_world": pose_list(transform_point(skillet_pose, pan_point)),
            },
            "bread_arm": "left" if bread_pose[0] < 0 else "right",
            "skillet_arm": "right" if side > 0 else "left",
            # expert release: TCP above the pan point (bread bottom RELEASE_GAP above the floor)
            "release_tcp_dz": round(RELEASE_GAP + h / 2 + gdz, 6),
        }
        return info

    # --- checkpoints ---------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        bread, skillet = info["bread"], info["skillet"]
        pan_point = np.asarray(skillet["pan_point"], float)
        gdz, rdz = float(bread["grasp_tcp_dz"]), float(info["release_tcp_dz"])
        return [
            SpatialRule("Approach bread", "either",
                        lambda w: np.asarray(w.pose(bread["name"])[:3], float) + [0.0, 0.0, gdz], cylinder(5, (-3, 4))),
            SpatialRule("Bread in pan", "either",
                        lambda w: transform_point(w.pose(skillet["name"]), pan_point) + [0.0, 0.0, rdz],
                        cylinder(10, 6), prerequisites=(0,)),
        ]

    # --- reference solution ----------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """The skillet arm slides its half-open fingers along the handle from beyond its end
        (fingers above and below it, the TCP pointing down the handle toward the pan), closes,
        lifts the pan 6 cm and brings it 12 cm toward the middle. The bread arm picks the bread
        top-down across its width, carries it over the pan point and lays it on the pan floor,
        lets go and rises."""
        info = world.info
        sk, br = info["skillet"], info["bread"]
        s_arm, b_arm = info["skillet_arm"], info["bread_arm"]
        side = 1.0 if s_arm == "right" else -1.0

        # 1. skillet arm onto the handle
        hold = Hands(call, s_arm)
        sp = world.pose(sk["name"])
        rot = quat_to_mat(sp[3:])
        axis = rot @ np.asarray(sk["handle_axis"], float)  # up the handle, away from the pan
        approach = -axis
        up = np.array([0.0, 0.0, 1.0])
        opening = up - np.dot(up, approach) * approach
        q = tcp_quat(approach, opening)
        grasp = transform_point(sp, sk["handle_grasp_point"])
        hold.grip(0.4)  # 1.6 cm pad clearance each side of the handle; the lower finger clears the table
        start = grasp - 0.09 * approach  # beyond the handle's end, on its axis
        # the planned reach turns the wrist and dips the hand several cm on the way: rise first and
        # come from well above
        hold.move(dz=0.12, what="rise before turning the wrist", ok=TOLERANT)
        hold.reach(start + [0.0, 0.0, 0.15], q, "above the handle's end")
        # the arm may have nudged the pan on its way: aim at the handle where it is now
        grasp = transform_point(world.pose(sk["name"]), sk["handle_grasp_point"])
        start = grasp - 0.09 * approach
        hold.move_to(world, start, "down to the handle's axis")
        hold.move_to(world, grasp, "fingers along the handle")
        hold.grip(0.0)
        # 2. lift the pan and bring it toward the middle (the bread arm reaches it there)
        hold.move(dx=-side * 0.12, dy=0.04, dz=0.06, what="lift the skillet", ok=TOLERANT)

        # 3. bread arm: pick the bread top-down across its width
        hands = Hands(call, b_arm)
        hands.pick_top_down(world, br["name"], float(br["grasp_tcp_dz"]))
        # 4. over the pan point (fingers across the handle's line, away from the other hand), down
        # onto the floor, let go, rise
        handle_dir = yaw_axis(world.pose(sk["name"])[3:], (1.0, 0.0, 0.0))
        tcp = world.tcp_pose(b_arm)
        qr = top_down_quat(closest_opening(tcp[3:], [np.array([-handle_dir[1], handle_dir[0], 0.0])]))
        h = float(br["size"][2])

        def target(held: np.ndarray) -> np.ndarray:
            pan = transform_point(world.pose(sk["name"]), sk["pan_point"])
            return np.array([pan[0] - held[0], pan[1] - held[1], pan[2] + RELEASE_GAP + h / 2 - held[2]])

        held0 = quat_to_mat(qr) @ (quat_to_mat(tcp[3:]).T @ (world.pose(br["name"])[:3] - tcp[:3]))
        hands.place_at(world, target(held0), qr, retreat=0.10,
                       refine=lambda: target(world.pose(br["name"])[:3] - world.tcp_pose(b_arm)[:3]))
        call("done", report="lifted the skillet by its handle and put the bread into it", success_claim=True)


TASK = PlaceBreadSkillet
