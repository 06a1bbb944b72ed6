"""beat_block_hammer: grab the hammer and strike the block with it.

Description
    A hammer (wooden handle; steel head with a round striking face and a flat peen) lies on its
    side at the middle front of the table, handle along world x with the head on the right and the
    striking face toward the robot (so a top-down grasp followed by a forward roll of the wrist
    turns the face down); a red 5 cm cube stands fixed on the table. The robot must grasp the
    hammer and bring its striking face onto the block's top.

Randomisation (per seed)
    The hammer's pose is fixed: (0, -0.06) on the table (FACTS B.6), yaw 0, resting height computed
    from its geometry. The block (static, half-size 0.025) is drawn with ``rand_pose``:
    x in [-0.25, 0.25] with |x| >= 0.05, y in [-0.05, 0.15], yaw in +-0.5 rad. This hammer's own
    footprint adds one constraint: the block's centre keeps >= 0.065 m from the hammer's footprint
    (upstream's mesh and ours differ; without it a few draws would put the block through the head).
    The block stands on the table (centre z = 0.765; upstream's 0.76 sinks a static cube 5 mm).

Success (latch: any physics step, polled every step)
    ``face_over_block``: the hammer's striking-face centre (functional point 0) lies within 0.02 m
    of the block's top-face centre (functional point 1) in x and in y, and
    ``hammer_touches_block``: the hammer and the block are in contact.
    Guard: the hammer must stay on the table (not below table top - 0.08 m).
    Margins are recorded for ``face_over_block`` (the contact is an event: none).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, sphere
from cab_core.contracts.scene import Body, Box, Capsule, Cylinder, Material, SceneSpec, Shape
from cab_core.contracts.verifier import Evaluation, WorldView, margin_within
from cab_core.geometry import transform_point
from cab_core.kits.oracle import Hands, closest_opening, top_down_quat, world_point, yaw_axis
from cab_core.kits.scene import (
    DESTRUCTIVE_DROP,
    RED,
    lowest_point_z,
    pose_list,
    rand_pose,
    sample_until,
    srgb,
    vec,
    yaw_of,
)
from cab_core.kits.task import LatchVerifier

from ..common import CodeActionTask

GRASP_TCP_ABOVE_AXIS = 0.026  # the expert's top-down handle grasp: TCP this far above the handle axis

# --- the hammer, in its body frame ---------------------------------------------------------------
# Origin on the handle axis; +x runs along the handle toward the head; the head's long axis is y,
# the striking face at its -y end (outward normal -y), the peen at +y; +z is up while the hammer
# lies on the table.
HANDLE_RADIUS = 0.014  # 2.8 cm thick: fits the 8 cm gripper with room
HANDLE_X = (-0.125, 0.095)  # capsule extent incl. its rounded end (0.22 m)
HEAD_X = (0.085, 0.115)  # 3 cm square steel head ...
HEAD_Y = (-0.05, 0.055)  # ... 10.5 cm long: striking face at -y, peen at +y
FACE_LEN = 0.025  # the round striking end
HEAD_HALF_Z = 0.014  # head bottom flush with the handle bottom: rests on both
PEEN_HALF = (0.015, 0.0125, 0.009)
# Mass: upstream sets 0.001 kg so the grasp never fails, 1000x lighter than the 1 kg robot links (a
# mass ratio that invites solver jitter in contact). 0.1 kg (a light toy/tack hammer) is still light
# enough for a friction grasp to hold it turned face-down, and close enough to the links' mass for
# stable contacts. Density is uniform over the shapes: the centre of mass is on the handle at x = 0.027.
HAMMER_MASS = 0.1  # kg
HAMMER_GRASP_FRICTION = 0.8  # varnished wood against rubber finger pads

HANDLE_HALF_LEN = (HANDLE_X[1] - HANDLE_X[0]) / 2 - HANDLE_RADIUS
HEAD_CX = (HEAD_X[0] + HEAD_X[1]) / 2
FACE_POINT = (HEAD_CX, HEAD_Y[0], 0.0)  # functional point 0: centre of the striking face
GRASP_POINT = (-0.03, 0.0, 0.0)  # middle of the free handle length
# oracle hint: one grasp on each half of the handle (the hammer lies at x = 0, yaw 0), because an arm
# may not reach a top-down grasp across the midline (measured: aloha_agilex with mplib IK)
GRASP_POINT_BY_SIDE = {"left": (-0.05, 0.0, 0.0), "right": (0.045, 0.0, 0.0)}

WOOD_HANDLE = Material(color=srgb(0.72, 0.50, 0.27), roughness=0.6, static_friction=HAMMER_GRASP_FRICTION,
                       dynamic_friction=HAMMER_GRASP_FRICTION)
STEEL = Material(color=srgb(0.42, 0.44, 0.48), roughness=0.35, metallic=0.8)
STEEL_FACE = Material(color=srgb(0.62, 0.64, 0.68), roughness=0.3, metallic=0.9)

# --- the block ------------------------------------------------------------------------------------
BLOCK_HALF = 0.025
BLOCK_TOP_POINT = (0.0, 0.0, BLOCK_HALF)  # functional point 1: centre of the top face
HAMMER_XY = (0.0, -0.06)
BLOCK_CLEARANCE = 0.065  # block centre to hammer footprint
XY_TOLERANCE = 0.02


def hammer_shapes() -> list[Shape]:
    """Handle (capsule along x), head block, round striking end, peen; all collide."""
    rz90 = (float(np.cos(np.pi / 4)), 0.0, 0.0, float(np.sin(np.pi / 4)))  # local x -> y
    head_box_y = (HEAD_Y[0] + FACE_LEN, HEAD_Y[1] - PEEN_HALF[1] * 2)
    return [
        Shape(Capsule(HANDLE_RADIUS, HANDLE_HALF_LEN),
              pose=((HANDLE_X[0] + HANDLE_X[1]) / 2, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0), material=WOOD_HANDLE),
        Shape(Box(((HEAD_X[1] - HEAD_X[0]) / 2, (head_box_y[1] - head_box_y[0]) / 2, HEAD_HALF_Z)),
              pose=(HEAD_CX, (head_box_y[0] + head_box_y[1]) / 2, 0.0, 1.0, 0.0, 0.0, 0.0), material=STEEL),
        Shape(Cylinder(HEAD_HALF_Z, FACE_LEN / 2),
              pose=(HEAD_CX, HEAD_Y[0] + FACE_LEN / 2, 0.0, *rz90), material=STEEL_FACE),
        Shape(Box(PEEN_HALF), pose=(HEAD_CX, HEAD_Y[1] - PEEN_HALF[1], 0.0, 1.0, 0.0, 0.0, 0.0), material=STEEL),
    ]


def _footprint_rects() -> list[tuple[float, float, float, float]]:
    """Hammer footprint as axis-aligned rectangles (xmin, xmax, ymin, ymax) in the hammer frame."""
    return [(HANDLE_X[0], HANDLE_X[1], -HANDLE_RADIUS, HANDLE_RADIUS), (HEAD_X[0], HEAD_X[1], HEAD_Y[0], HEAD_Y[1])]


def _distance_to_footprint(p_local: np.ndarray) -> float:
    d = np.inf
    for x0, x1, y0, y1 in _footprint_rects():
        dx = max(x0 - p_local[0], 0.0, p_local[0] - x1)
        dy = max(y0 - p_local[1], 0.0, p_local[1] - y1)
        d = min(d, float(np.hypot(dx, dy)))
    return d


class BeatBlockHammerVerifier(LatchVerifier):
    def __init__(self, info: dict[str, Any]):
        self.hammer = info["hammer"]["name"]
        self.block = info["block"]["name"]
        self.face_local = np.asarray(info["hammer"]["face_point"], dtype=float)
        self.top_local = np.asarray(info["block"]["top_point"], dtype=float)
        self.tol = float(info["xy_tolerance"])
        self.guarded_objects = (self.hammer,)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def _face_over_block(self, w: WorldView) -> tuple[bool, np.ndarray]:
        face = transform_point(w.pose(self.hammer), self.face_local)
        top = transform_point(w.pose(self.block), self.top_local)
        d = face - top
        return bool(abs(d[0]) < self.tol and abs(d[1]) < self.tol), d

    def holds(self, w: WorldView) -> bool:
        return self._face_over_block(w)[0] and bool(w.in_contact(self.hammer, self.block))

    def evaluate(self, w: WorldView) -> Evaluation:
        over, d = self._face_over_block(w)
        touch = bool(w.in_contact(self.hammer, self.block))
        return Evaluation(
            success=over and touch,
            predicates={"face_over_block": over, "hammer_touches_block": touch},
            values={"face_dx": float(d[0]), "face_dy": float(d[1]), "face_dz": float(d[2])},
            margins={"face_over_block": margin_within(d[:2], self.tol, "m")},  # the contact: an event, no margin
        )


class BeatBlockHammer(CodeActionTask):
    verifier_class = BeatBlockHammerVerifier
    # (1) the hammer's face aligned with and touching the block (the latch predicate)
    subgoal_predicates = (("face_over_block", "hammer_touches_block"),)

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        shapes = hammer_shapes()
        hammer_pose = np.array([HAMMER_XY[0], HAMMER_XY[1], top - lowest_point_z(shapes) + 2e-4, 1.0, 0.0, 0.0, 0.0])

        def ok(p: np.ndarray) -> bool:
            local = p[:2] - hammer_pose[:2]  # the hammer has yaw 0
            return abs(p[0]) >= 0.05 and _distance_to_footprint(local) >= BLOCK_CLEARANCE

        block_pose = sample_until(
            lambda: rand_pose(rng, (-0.25, 0.25), (-0.05, 0.15), (top + BLOCK_HALF,), rotate_rand=True,
                              rotate_lim=(0.0, 0.0, 0.5)),
            ok, what="the block")

        scene.bodies.append(Body("hammer", shapes, pose=tuple(hammer_pose), kind="dynamic", mass=HAMMER_MASS,
                                 angular_damping=0.05))
        scene.bodies.append(Body("block", [Shape(Box((BLOCK_HALF,) * 3), material=RED)], pose=tuple(block_pose),
                                 kind="static"))

        info = {
            "xy_tolerance": XY_TOLERANCE,
            "hammer": {
                "name": "hammer",
                "frame": "hammer body: origin on the handle axis; +x handle->head; head along y with the "
                         "striking face at -y (normal -y) and the peen at +y; +z up while lying on the table",
                "initial_pose": pose_list(hammer_pose),
                "mass_kg": HAMMER_MASS,
                "grasp_point": vec(GRASP_POINT),
                "grasp_point_by_side": {k: vec(v) for k, v in GRASP_POINT_BY_SIDE.items()},
                "handle_axis": [1.0, 0.0, 0.0],
                "handle_radius": HANDLE_RADIUS,
                "handle_x_range": vec([HANDLE_X[0], HEAD_X[0]]),  # graspable length (handle end to head)
                "head_center": vec([HEAD_CX, (HEAD_Y[0] + HEAD_Y[1]) / 2, 0.0]),
                "head_size": vec([HEAD_X[1] - HEAD_X[0], HEAD_Y[1] - HEAD_Y[0], 2 * HEAD_HALF_Z]),
                "face_point": vec(FACE_POINT),  # functional point 0
                "face_normal": [0.0, -1.0, 0.0],
                "face_radius": HEAD_HALF_Z,
                "length": round(HEAD_X[1] - HANDLE_X[0], 6),
            },
            "block": {
                "name": "block",
                "frame": "block body: centre of the cube, axes along its faces",
                "pose": pose_list(block_pose),
                "yaw": round(yaw_of(block_pose[3:]), 6),
                "half_size": BLOCK_HALF,
                "top_point": vec(BLOCK_TOP_POINT),  # functional point 1
            },
            # upstream's expert uses the arm on the block's side
            "suggested_arm": "right" if block_pose[0] > 0 else "left",
            # the subgoal the latch event satisfies (checkpoints read it from the record)
            "latch_subgoals": [0],
        }
        return info

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        """(1) Approach hammer: the expert's top-down grasp over the handle; (2) Strike: where the
        TCP is when the held hammer's face rests on the block top (follows the hammer)."""
        h, b = info["hammer"], info["block"]
        grasp_local = h["grasp_point_by_side"][info["suggested_arm"]]
        above = np.array([0.0, 0.0, GRASP_TCP_ABOVE_AXIS])

        def approach(w):
            return world_point(w.pose(h["name"]), grasp_local) + above

        def strike(w):
            hp = w.pose(h["name"])
            top = world_point(w.pose(b["name"]), b["top_point"])
            return (top + np.array([0.0, 0.0, float(h["face_radius"])]) + world_point(hp, grasp_local)
                    - world_point(hp, h["face_point"]) + above)

        return [SpatialRule("Approach hammer", "either", approach, box(dx=2, dy=6, dz=(-3, 4))),
                SpatialRule("Strike", "either", strike, sphere(5), prerequisites=(0,))]

    def solve(self, call, world: WorldView) -> None:
        """Grasp the handle top-down with the arm on the block's side, carry the hammer flat so
        its striking face is over the block's top, and lower it until the head strikes."""
        info = world.info
        h, b = info["hammer"], info["block"]
        arm = info["suggested_arm"]
        hands = Hands(call, arm)
        hp = world.pose(h["name"])
        g = world_point(hp, h["grasp_point_by_side"][arm])
        handle = yaw_axis(hp[3:], (1.0, 0.0, 0.0))
        across = np.cross([0.0, 0.0, 1.0], handle)
        q = top_down_quat(closest_opening(world.tcp_pose(arm)[3:], [across]))
        # the fingertips reach 0.0354 m past the TCP: keep them just above the table top
        z = max(g[2] + GRASP_TCP_ABOVE_AXIS, float(info["table_top_z"]) + 0.038)
        hands.pick([g[0], g[1], z], q, lift=0.10)
        face = world_point(world.pose(h["name"]), h["face_point"])
        offset = face - world.tcp_pose(arm)[:3]
        top = world_point(world.pose(b["name"]), b["top_point"])
        # the face 2.5 cm over the block's top, then strike it
        hands.press(top + np.array([0.0, 0.0, float(h["face_radius"]) + 0.025]) - offset, None, 0.05, 0.05, "the block")
        call("done", report="struck the block with the hammer's face", success_claim=True)


TASK = BeatBlockHammer
