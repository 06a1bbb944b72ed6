"""hanging_mug: turn a mug with the left arm, then hang it on a rack's peg with the right arm.

Description
    A coffee mug (8 cm across, 9.5 cm tall, a loop handle with a 2.6 x 4.1 cm opening; one of four
    glaze colours) stands on the left of the table; a dark wooden mug rack stands at the back on
    the right: a round foot, an upright post, and one round peg (1.2 cm thick, 14 cm long) leaving
    the post 13 cm above the table toward the left, rising 10 deg, with a knob at its tip. The
    robot must pick the mug with the left arm, turn it and set it down in the middle of the table,
    then pick it with the right arm and hang it on the peg by its handle, and let go.

Randomisation (per seed; FACTS B.6)
    Mug: colour one of four; ``rand_pose`` x in [-0.25, -0.1], y in [-0.05, 0.05] with
    ``ylim_prop``, standing on the table, turned about its axis by +-1.57 rad from the handle
    pointing away from the robot (+y), so the handle points anywhere in the right-hand half turn
    from +x through +y to -x. Rack (static): x in [0.1, 0.3], y in [0.13, 0.17], on the table,
    turned about the vertical by +-0.2 rad (unturned, its peg points along -x).

Success (final state)
    The mug's functional point 0 is where a peg's axis lies when the mug hangs from it by its
    handle (the opening's upper outer corner, 6 mm in from both edges); the rack's functional
    point 0 is the tip of its peg and its pose's origin is the foot of the post on the table, so
    their midpoint lies over the middle of the peg.
    ``mug_at_peg``: |mug point - midpoint| < 0.02 in x and in y;
    ``mug_high``: mug point z > 0.86;
    ``right_gripper_open``: the right arm's commanded gripper value > 0.8.
    Guard: the mug must not fall off the table.
    Margins are recorded for all three predicates.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, cylinder, sphere
from cab_core.contracts.scene import Body, Cylinder, Material, SceneSpec, Shape, Sphere, cache_dir
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, margin_above, margin_within
from cab_core.geometry import axis_angle_quat, mat_to_quat, quat_to_mat, transform_point
from cab_core.kits.oracle import TOLERANT, Hands, OracleFailed, top_down_quat
from cab_core.kits.scene import DESTRUCTIVE_DROP, draw_variant, pose_list, rand_pose, srgb, vec, yaw_of

from ..assets_organise import Vessel, revolved, rod, tilt_correction, vessel_collision, visual, x_to
from ..common import CodeActionTask

# --- the mug, in its frame: origin at the bottom centre, +z up the axis, handle along +x -------------
MUG = Vessel(r_bottom=0.039, r_rim=0.041, height=0.095, wall=0.004, base=0.006)
MUG_MASS = 0.22  # kg, a light porcelain mug
MUG_FRICTION = 0.5
# a mug hung by its handle rolls on the peg and would swing for tens of seconds (rolling contact
# dissipates almost nothing in the solver); this stands in for the rolling friction that stops it
# within ~5 s (side effect: a mug falling 10 cm lands ~10% slower)
MUG_ANGULAR_DAMPING = 1.0
MUG_LINEAR_DAMPING = 1.0  # (the swing's energy is mostly the centre of mass's motion)
MUG_COLOURS = ((0.80, 0.16, 0.14), (0.12, 0.45, 0.62), (0.93, 0.93, 0.90), (0.20, 0.55, 0.30))
HANDLE_R = 0.0055  # round bar
HANDLE_ROOT_X = 0.039  # where the bars enter the wall
HANDLE_OUT_X = 0.072  # the outer bar's axis
HANDLE_TOP_Z = 0.080
HANDLE_BOTTOM_Z = 0.028
HOLE_X = (MUG.r_outer(0.05), HANDLE_OUT_X - HANDLE_R)  # the opening, radially
HOLE_Z = (HANDLE_BOTTOM_Z + HANDLE_R, HANDLE_TOP_Z - HANDLE_R)  # and vertically
HOLE_CENTRE = ((HOLE_X[0] + HOLE_X[1]) / 2, 0.0, (HOLE_Z[0] + HOLE_Z[1]) / 2)
OPENING_TOP = ((HOLE_X[0] + HOLE_X[1]) / 2, 0.0, HOLE_Z[1])  # middle of the opening's top edge
# functional point 0: where the axis of a 1.2 cm peg lies when the mug hangs from it (the mug tips
# ~60 deg about the peg, whose axis then sits in the opening's upper outer corner)
HANG_POINT = (HOLE_X[1] - 0.006, 0.0, HOLE_Z[1] - 0.006)

# --- the rack, in its frame: origin at the foot of the post on the table, +z up ----------------------
RACK_FRICTION = 0.7  # oiled wood (0.6 against the mug's glaze, averaged): a hung mug stays where it is put
RACK_WOOD = Material(color=srgb(0.30, 0.19, 0.11), roughness=0.6, static_friction=RACK_FRICTION,
                     dynamic_friction=RACK_FRICTION)
FOOT_R, FOOT_H = 0.06, 0.014
POST_R, POST_H = 0.011, 0.19
PEG_R = 0.006
PEG_ROOT_Z = 0.13
PEG_LEN = 0.14  # from the post's axis to the tip
PEG_ELEVATION = np.radians(10.0)
PEG_DIR = (-float(np.cos(PEG_ELEVATION)), 0.0, float(np.sin(PEG_ELEVATION)))  # root -> tip
PEG_ROOT = (0.0, 0.0, PEG_ROOT_Z)
PEG_TIP = tuple(float(a + PEG_LEN * d) for a, d in zip(PEG_ROOT, PEG_DIR))  # functional point 0
KNOB_R = 0.0085

XY_TOLERANCE = 0.02
MIN_Z = 0.86
GRIPPER_OPEN = 0.8

# --- the reference solution -------------------------------------------------------------------------
PINCH_ABOVE_RIM = 0.022  # TCP above the rim: fingertips 1.3 cm down the wall
PINCH_OPEN = 0.4  # gripper command for the pinch: pads 2.6 cm apart
MIDDLE = (0.0, -0.06)  # where the left arm sets the mug down
PRESS = 0.004  # lowered this far past resting, so it sits before the fingers open
HOVER = 0.22
PARK_X = 0.28
BEYOND_TIP = 0.035  # the handle's opening is lined up on the peg's axis this far beyond the tip
HANG_ALONG = PEG_LEN / 2 + 0.006  # and slid to this far from the post's axis (it slips ~8 mm back as it tips)


def mug_material(colour) -> Material:
    return Material(color=srgb(*colour), roughness=0.25, static_friction=MUG_FRICTION,
                    dynamic_friction=MUG_FRICTION)


def handle_points() -> list[tuple[float, float, float]]:
    return [(HANDLE_ROOT_X, 0.0, HANDLE_TOP_Z), (HANDLE_OUT_X, 0.0, HANDLE_TOP_Z),
            (HANDLE_OUT_X, 0.0, HANDLE_BOTTOM_Z), (HANDLE_ROOT_X, 0.0, HANDLE_BOTTOM_Z)]


@lru_cache(maxsize=8)
def mug_shapes(colour: tuple[float, float, float], cache: str) -> tuple[Shape, ...]:
    """Wall wedges + floor disc + three capsule bars for the handle (collision); a smooth body of
    revolution (visual); ``cache`` keys the assets' directory."""
    mat = mug_material(colour)
    shapes = vessel_collision("mug", MUG, mat)
    shapes.append(visual("mug-visual", revolved(MUG.profile()), mat))
    pts = handle_points()
    for a, b in zip(pts[:-1], pts[1:]):
        shapes.append(rod(a, b, HANDLE_R, mat))
    return tuple(shapes)


def rack_shapes() -> list[Shape]:
    up = x_to((0.0, 0.0, 1.0))
    shapes = [
        Shape(Cylinder(FOOT_R, FOOT_H / 2), pose=(0.0, 0.0, FOOT_H / 2, *up), material=RACK_WOOD),
        Shape(Cylinder(POST_R, (POST_H - FOOT_H) / 2), pose=(0.0, 0.0, (POST_H + FOOT_H) / 2, *up),
              material=RACK_WOOD),
        Shape(Sphere(POST_R * 1.3), pose=(0.0, 0.0, POST_H, 1.0, 0.0, 0.0, 0.0), material=RACK_WOOD),
        rod(PEG_ROOT, PEG_TIP, PEG_R, RACK_WOOD, capsule=False),
        Shape(Sphere(KNOB_R), pose=(*PEG_TIP, 1.0, 0.0, 0.0, 0.0), material=RACK_WOOD),
    ]
    return shapes


def rack_midpoint(rack_pose) -> np.ndarray:
    """Midpoint of the rack's pose origin and its functional point 0 (the peg's tip)."""
    return 0.5 * (np.asarray(rack_pose[:3], float) + transform_point(rack_pose, PEG_TIP))


class HangingMugVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.mug = info["mug"]["name"]
        self.rack = info["rack"]["name"]
        self.point = np.asarray(info["mug"]["hang_point"], float)
        self.tip = np.asarray(info["rack"]["peg_tip"], float)
        # ``mug_high``'s margin is judged against how far MIN_Z lies above the point of the upright mug
        self.high_scale = MIN_Z - (float(info["table_top_z"]) + float(self.point[2]))
        self.guarded_objects = (self.mug,)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        p = transform_point(w.pose(self.mug), self.point)
        rp = w.pose(self.rack)
        mid = 0.5 * (np.asarray(rp[:3], float) + transform_point(rp, self.tip))
        d = p - mid
        at_peg = bool(abs(d[0]) < XY_TOLERANCE and abs(d[1]) < XY_TOLERANCE)
        high = bool(p[2] > MIN_Z)
        grip = w.gripper_command("right")
        return Evaluation(
            success=at_peg and high and grip > GRIPPER_OPEN,
            predicates={"mug_at_peg": at_peg, "mug_high": high, "right_gripper_open": grip > GRIPPER_OPEN},
            values={"mug_point_dx": float(d[0]), "mug_point_dy": float(d[1]), "mug_point_z": float(p[2]),
                    "gripper_right": float(grip)},
            margins={"mug_at_peg": margin_within(d[:2], XY_TOLERANCE, "m"),
                     "mug_high": margin_above(p[2], MIN_Z, "m", self.high_scale),
                     "right_gripper_open": margin_above(grip, GRIPPER_OPEN, "gripper command", 1 - GRIPPER_OPEN)},
        )


class HangingMug(CodeActionTask):
    verifier_class = HangingMugVerifier
    subgoal_predicates = (("mug_at_peg", "mug_high"),)

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        colour_id, colour = draw_variant(rng, MUG_COLOURS)
        handle_back = tuple(float(c) for c in axis_angle_quat([0, 0, 1], np.pi / 2))  # local +x -> world +y
        mug_pose = rand_pose(rng, (-0.25, -0.1), (-0.05, 0.05), (top + 0.0005,), ylim_prop=True, rotate_rand=True,
                             rotate_lim=(0.0, 0.0, 1.57), qpos=handle_back)
        rack_pose = rand_pose(rng, (0.1, 0.3), (0.13, 0.17), (top,), rotate_rand=True, rotate_lim=(0.0, 0.0, 0.2))
        scene.bodies.append(Body("mug", list(mug_shapes(colour, str(cache_dir()))),
                                 pose=tuple(mug_pose), kind="dynamic", mass=MUG_MASS,
                                 linear_damping=MUG_LINEAR_DAMPING, angular_damping=MUG_ANGULAR_DAMPING))
        scene.bodies.append(Body("rack", rack_shapes(), pose=tuple(rack_pose), kind="static"))
        peg_dir_world = quat_to_mat(rack_pose[3:]) @ np.asarray(PEG_DIR)
        # where the reference solution's TCP is when the hung mug is let go: over the rim opposite
        # the handle, the handle's opening on the middle of the peg (rack frame, from the midpoint)
        rim_to_point = np.array([-(MUG.rim_mid_radius + OPENING_TOP[0]), 0.0,
                                 MUG.height + PINCH_ABOVE_RIM - OPENING_TOP[2]])  # mug frame (handle +x)
        on_peg = np.asarray(PEG_ROOT) + HANG_ALONG * np.asarray(PEG_DIR) + [0.0, 0.0, PEG_R]  # rack frame
        hang_tcp = on_peg + [0.0, rim_to_point[0], rim_to_point[2]] - 0.5 * np.asarray(PEG_TIP)  # handle along +y
        info = {
            "mug": {
                "name": "mug",
                "frame": "origin at the centre of the mug's bottom, +z up its axis, +x toward the handle",
                "colour_id": colour_id,
                "colour_srgb": list(colour),
                "pose": pose_list(mug_pose),
                "handle_yaw": round(yaw_of(mug_pose[3:]), 6),
                "outer_radius": MUG.r_rim,
                "height": MUG.height,
                "wall_thickness": MUG.wall,
                "mass_kg": MUG_MASS,
                "hang_point": vec(HANG_POINT),  # functional point 0
                "handle_opening_top": vec(OPENING_TOP),
                "handle_opening_centre": vec(HOLE_CENTRE),
                "handle_opening_size_xz": vec([HOLE_X[1] - HOLE_X[0], HOLE_Z[1] - HOLE_Z[0]]),
                "handle_bar_radius": HANDLE_R,
                "rim_mid_radius": round(MUG.rim_mid_radius, 6),
                "grasp_tcp_dz": round(MUG.height + PINCH_ABOVE_RIM, 6),  # reference pinch: TCP above the origin
                "pinch_gripper_command": PINCH_OPEN,
            },
            "rack": {
                "name": "rack",
                "frame": "origin at the foot of the post on the table, +z up; the peg leaves the post toward -x, "
                         "rising 10 deg",
                "pose": pose_list(rack_pose),
                "yaw": round(yaw_of(rack_pose[3:]), 6),
                "peg_root": vec(PEG_ROOT),
                "peg_tip": vec(PEG_TIP),  # functional point 0
                "peg_direction": vec(PEG_DIR),
                "peg_direction_world": vec(peg_dir_world),
                "peg_length": PEG_LEN,
                "hang_along": HANG_ALONG,  # the reference solution hangs the handle this far along the peg
                "peg_radius": PEG_R,
                "knob_radius": KNOB_R,
                "post_radius": POST_R,
                "post_height": POST_H,
                "foot_radius": FOOT_R,
                "midpoint_world": vec(rack_midpoint(rack_pose)),
                "hang_tcp_from_midpoint_rack": vec(hang_tcp),
            },
            "middle_xy": list(MIDDLE),
            "xy_tolerance": XY_TOLERANCE,
            "min_hang_point_z": MIN_Z,
            "gripper_open_threshold": GRIPPER_OPEN,
        }
        return info

    # -- checkpoints ------------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        """Approach: the TCP at the reference pinch height over the mug, within 5 cm of its axis
        (the rim is 3.9 cm from it). Hanging: the TCP within 3 cm of where the reference's is when
        it lets go of the hung mug (the rack's midpoint plus that offset, in the rack's frame)."""
        m, r = info["mug"], info["rack"]

        def mug_top(w):
            return np.asarray(w.pose(m["name"])[:3], float) + [0.0, 0.0, float(m["grasp_tcp_dz"])]

        def hang(w):
            rp = w.pose(r["name"])
            return rack_midpoint(rp) + quat_to_mat(rp[3:]) @ np.asarray(r["hang_tcp_from_midpoint_rack"], float)

        return [SpatialRule("Approach mug", "either", mug_top, cylinder(5.0, 4.0)),
                SpatialRule("Final hanging target", "either", hang, sphere(3.0), (0,))]

    # -- reference solution -----------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """Left arm: pinch the rim top-down (fingers along the radius) at the point that, once the
        mug is turned, faces the left shoulder; lift; turn the wrist so the handle points at right
        angles to the peg, toward the wall (and tip it back upright); set the mug down in the middle
        of the table; withdraw. Right arm: pinch the rim opposite the handle; lift; bring the
        handle's opening onto the peg's axis line beyond its tip (from above), slide it along the
        peg to the middle, lower the handle onto the peg, let go and rise."""
        info = world.info
        m, r = info["mug"], info["rack"]
        top = float(info["table_top_z"])
        r_g = float(m["rim_mid_radius"])
        grasp_dz = float(m["grasp_tcp_dz"])

        def handle_angle() -> float:
            return yaw_of(world.pose(m["name"])[3:])

        rack = world.pose(r["name"])
        peg_dir = quat_to_mat(rack[3:]) @ np.asarray(r["peg_direction"], float)
        want = float(np.arctan2(-peg_dir[0], peg_dir[1]))  # peg direction turned -90 deg: toward the wall

        # 1. left arm: pick, turn, set down in the middle
        left = Hands(call, "left", hover=HOVER)
        psi = handle_angle()
        delta = float(np.angle(np.exp(1j * (want - psi))))
        mid = np.array([MIDDLE[0], MIDDLE[1]])
        d = np.array([-0.27, -0.65]) - mid
        rel = float(np.angle(np.exp(1j * (np.arctan2(d[1], d[0]) - want))))  # pinch angle from the handle
        if abs(rel) < np.radians(60):
            rel = np.sign(rel or 1.0) * np.radians(60)
        phi = psi + rel
        radial = np.array([np.cos(phi), np.sin(phi), 0.0])
        q = top_down_quat(radial)
        left.grip(PINCH_OPEN)
        left.turn_in_place(world, q, rise=0.04, what="turn the gripper down")
        c = np.asarray(world.pose(m["name"])[:3], float)
        left.pick(c + r_g * radial + [0.0, 0.0, grasp_dz], q, lift=0.10)
        tcp = world.tcp_pose("left")
        pose = world.pose(m["name"])
        turn = quat_to_mat(axis_angle_quat([0.0, 0.0, 1.0], delta)) @ tilt_correction(quat_to_mat(pose[3:])[:, 2])
        q_place = mat_to_quat(turn @ quat_to_mat(tcp[3:]))
        target = np.array([mid[0], mid[1], top - PRESS])
        tcp_target = target - turn @ (np.asarray(pose[:3], float) - tcp[:3])
        left.place(tcp_target, q_place, retreat=0.08)  # turned over the middle, set down
        left.park(world, -PARK_X, "clear the middle")

        # 2. right arm: pinch opposite the handle, hang the mug on the peg
        right = Hands(call, "right", hover=HOVER)
        pose = world.pose(m["name"])
        phi = handle_angle() + np.pi
        radial = np.array([np.cos(phi), np.sin(phi), 0.0])
        q = top_down_quat(radial)
        right.grip(PINCH_OPEN)
        right.turn_in_place(world, q, rise=0.04, what="turn the gripper down")
        right.pick(np.asarray(pose[:3], float) + r_g * radial + [0.0, 0.0, grasp_dz], q, lift=0.10)
        tcp = world.tcp_pose("right")
        hole = transform_point(world.pose(m["name"]), m["handle_opening_centre"])
        offset = hole - tcp[:3]
        root = transform_point(rack, r["peg_root"])
        length = float(r["peg_length"])
        start = root + (length + BEYOND_TIP) * peg_dir
        right.reach(start - offset + [0.0, 0.0, 0.05], None, "above the peg's tip")
        right.move(dz=-0.05, what="down to the peg's line", ok=TOLERANT)
        now = world.tcp_pose("right")[:3] + offset
        right.move(*(root + float(r["hang_along"]) * peg_dir - now), what="slide the handle onto the peg",
                   ok=TOLERANT)
        opening_half = 0.5 * float(m["handle_opening_size_xz"][1])
        right.move(dz=-(opening_half - float(r["peg_radius"]) + 0.002), what="rest the handle on the peg",
                   ok=TOLERANT)
        right.grip(1.0)
        right.move(dy=-0.03, dz=0.08, what="withdraw", ok=TOLERANT)
        if not np.isfinite(offset).all():
            raise OracleFailed("lost the mug")
        call("done", report="turned the mug with the left arm and hung it on the rack's peg with the right arm",
             success_claim=True)


TASK = HangingMug
