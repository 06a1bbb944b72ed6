"""scan_object: hold a handheld scanner in one hand and a tea box in the other, and scan the box.

Description
    A handheld barcode scanner (a "gun": a head with a red exit window at its nose and a raked
    handle with a trigger) lies on its side on one half of the table; a cardboard tea box stands
    on the other half. The robot must pick the scanner with one arm and the box with the other,
    and hold the scanner's window close to the box, its beam pointing straight at it.

Randomisation (per seed)
    The sides are drawn at random: the scanner at x in [-0.25, -0.05] and the box at x in
    [0.05, 0.25], or the other way round. Scanner: model variant 0-4 (as upstream's
    ``024_scanner`` ids 0-4; heads 7.5-8.5 cm long, 4.2-4.6 cm thick, handles 10-11 cm, five colour
    schemes), y in [-0.15, -0.05], heading 0 (beam toward +x) +- 1.2 rad, lying on the table.
    Tea box: model variant 0-5 (as upstream's ``112_tea-box`` ids 0-5; 7.2-9.0 x 5.2-6.4 x
    10.5-12.5 cm, six colours), y in [-0.2, 0.0], heading +- 1.2 rad, standing on the table. Both
    with ``rand_pose``; a draw whose footprints come closer than 3 cm is redrawn (the scanner is
    up to 15 cm across, so near the centre line it could overlap the box).

Success (final state)
    With the scanner's functional point 0 (the window centre; its frame's +z is the beam) at p
    with rotation R, t = R (0, 0, -1) and d = t . (p - box centre): ``object_on_beam``: the box
    centre projected onto the beam line, box + d t, lies within 0.025 m of p on every world axis;
    ``scan_distance``: 0 < d < 0.07 m (in front of the window, close); ``grippers_closed``: both
    grippers commanded closed (< 0.2), i.e. both objects held.
    Guard: the scanner and the box must stay on the table (not below table top - 0.08 m).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, sphere
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView
from cab_core.geometry import mat_to_quat, quat_mul, quat_to_mat, transform_point
from cab_core.kits.margins import margin_above, margin_all, margin_below, margin_within
from cab_core.kits.oracle import TOLERANT, BothHands, Hands, top_down_quat, yaw_axis
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, sample_until, vec, yaw_of

from ..assets_tools import (
    SCANNER_MASS,
    SCANNER_VARIANTS,
    TEABOX_MASS,
    TEABOX_VARIANTS,
    Z_TO_X,
    footprint_distance,
    scanner_geometry,
    scanner_shapes,
    teabox_shapes,
)
from ..common import CodeActionTask

LATERAL_TOL = 0.025
MAX_DISTANCE = 0.07
GRIPPER_CLOSED = 0.2
MIN_CLEARANCE = 0.03  # between the two footprints at spawn
SCANNER_TCP_Z = 0.040  # the expert's grasp: TCP this far above the table (fingertips 5 mm above it)
BOX_TCP_BELOW_TOP = 0.020  # the expert's grasp: TCP this far below the box's top
SCAN_GAP = 0.015  # the expert's window-to-face gap
SCAN_CENTRE = (0.07, -0.05)  # the expert holds the box here (x toward the box's side)
SCAN_HEIGHT = 0.21  # box centre above the table top while scanning
PRE_SCAN = 0.05  # the scanner comes in along the beam over the last 5 cm
HOVER = 0.16
PRE_LIFT = 0.10
SCAN_CORRECTIONS = 3  # straight moves of the window onto its goal, each from a fresh look
SCAN_TOLERANCE = 0.003  # m: close enough to stop correcting
CLEAR_SIDE = 0.12  # the scanner arm moves this far out toward its side while the other arm picks


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _box_turn(box_x) -> float:
    """The turn about z (within +-pi/2) that lays the box's long side along world x."""
    t = _wrap(-np.arctan2(box_x[1], box_x[0]))
    if t > np.pi / 2:
        t -= np.pi
    elif t < -np.pi / 2:
        t += np.pi
    return t


def beam_frame(w, info) -> tuple[np.ndarray, np.ndarray]:
    """World position of the scanner's functional point 0 and its rotation matrix."""
    s = info["scanner"]
    pose = w.pose(s["name"])
    fp = np.asarray(s["functional_point"], float)
    return transform_point(pose, fp[:3]), quat_to_mat(quat_mul(pose[3:], fp[3:]))


class ScanObjectVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.info = info
        self.scanner = info["scanner"]["name"]
        self.object = info["object"]["name"]
        self.arms = list(info["arms"])
        self.guarded_objects = (self.scanner, self.object)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        p, rot = beam_frame(w, self.info)
        t = rot @ np.array([0.0, 0.0, -1.0])
        obj = np.asarray(w.pose(self.object)[:3], float)
        d = float(np.dot(t, p - obj))
        lateral = obj + d * t - p
        on_beam = bool(np.all(np.abs(lateral) < LATERAL_TOL))
        close = bool(0.0 < d < MAX_DISTANCE)
        grips = {a: w.gripper_command(a) for a in self.arms}
        closed = all(g < GRIPPER_CLOSED for g in grips.values())
        values = {"beam_distance": d, **{f"lateral_d{ax}": float(v) for ax, v in zip("xyz", lateral)},
                  **{f"gripper_{a}": float(g) for a, g in grips.items()}}
        half = MAX_DISTANCE / 2  # scan_distance: either end of (0, MAX_DISTANCE), against its half-width
        margins = {
            "object_on_beam": margin_within(lateral, LATERAL_TOL, "m"),
            "scan_distance": margin_all(margin_above(d, 0.0, "m", half), margin_below(d, MAX_DISTANCE, "m", half)),
            "grippers_closed": margin_all(*(margin_below(g, GRIPPER_CLOSED, "gripper command")
                                            for g in grips.values())),
        }
        return Evaluation(success=on_beam and close and closed,
                          predicates={"object_on_beam": on_beam, "scan_distance": close, "grippers_closed": closed},
                          values=values, margins=margins)


def scan_tcp_reference(info: dict, obj_xyz) -> np.ndarray:
    """Where the expert's scanner TCP is while scanning, relative to the box centre: the beam
    horizontal along +-x toward the box, the window SCAN_GAP off the box's end face, the scanner
    held as grasped (TCP above the handle's grasp point)."""
    s, o = info["scanner"], info["object"]
    sb = 1.0 if info["object_side"] == "right" else -1.0
    yaw = 0.0 if sb > 0 else np.pi
    win = np.asarray(obj_xyz, float) - sb * np.array([o["size"][0] / 2 + SCAN_GAP, 0.0, 0.0])
    off = np.subtract(s["grasp_tcp_point"], s["functional_point"][:3])
    return win + _rz(yaw) @ off


class ScanObject(CodeActionTask):
    verifier_class = ScanObjectVerifier
    # (1) the box on the beam line; (2) on the beam line and 0 < d < 7 cm together
    subgoal_predicates = (("object_on_beam",), ("object_on_beam", "scan_distance"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        scanner_id = int(rng.integers(0, len(SCANNER_VARIANTS)))
        object_id = int(rng.integers(0, len(TEABOX_VARIANTS)))
        scanner_side = "left" if rng.random() < 0.5 else "right"
        sv, ov = SCANNER_VARIANTS[scanner_id], TEABOX_VARIANTS[object_id]
        sg = scanner_geometry(sv)
        sx, sy, sz = ov.size
        xs = (-0.25, -0.05) if scanner_side == "left" else (0.05, 0.25)
        xo = (0.05, 0.25) if scanner_side == "left" else (-0.25, -0.05)
        box_rects = [((0.0, 0.0), (sx / 2, sy / 2), 0.0)]

        def draw() -> np.ndarray:
            a = rand_pose(rng, xs, (-0.15, -0.05), (top + 2e-4,), rotate_rand=True, rotate_lim=(0.0, 0.0, 1.2))
            b = rand_pose(rng, xo, (-0.2, 0.0), (top + sz / 2 + 2e-4,), rotate_rand=True, rotate_lim=(0.0, 0.0, 1.2))
            return np.concatenate([a, b])

        both = sample_until(draw, lambda p: footprint_distance(sg["rects"], p[:7], box_rects, p[7:]) >= MIN_CLEARANCE,
                            what="the scanner and the box")
        sp, op = both[:7], both[7:]
        scene.bodies.append(Body("scanner", scanner_shapes(scanner_id), pose=tuple(sp), kind="dynamic",
                                 mass=SCANNER_MASS))
        scene.bodies.append(Body("tea_box", teabox_shapes(object_id), pose=tuple(op), kind="dynamic", mass=TEABOX_MASS))
        grasp_tcp = np.array([sg["grasp_point"][0], sg["grasp_point"][1], SCANNER_TCP_Z])
        info = {
            "arms": ["left", "right"],
            "scanner_side": scanner_side,
            "object_side": "right" if scanner_side == "left" else "left",
            # the expert holds the scanner with the arm on its side, the box with the other
            "scanner_arm": scanner_side,
            "object_arm": "right" if scanner_side == "left" else "left",
            "lateral_tolerance": LATERAL_TOL,
            "max_distance": MAX_DISTANCE,
            "scanner": {
                "name": "scanner",
                "model_id": scanner_id,
                "frame": "scanner body, lying on its side: origin on the table at the footprint's centre, +x the "
                         "beam direction (window at the nose's +x face), +z up; the handle leaves the head's -y side",
                "pose": pose_list(sp),
                "yaw": round(yaw_of(sp[3:]), 6),
                "mass_kg": SCANNER_MASS,
                # functional point 0: the window centre, its frame's +z along the beam
                "functional_point": vec([*sg["window_point"], *Z_TO_X]),
                "beam_axis": [1.0, 0.0, 0.0],
                "grasp_point": vec(sg["grasp_point"]),  # on the handle's axis, mid-thickness
                "grasp_tcp_point": vec(grasp_tcp),  # the expert's top-down TCP there
                "handle_axis": vec(sg["handle_axis"]),
                "handle_across": vec(sg["handle_front"]),  # the fingers close along this line
                "handle_width": sv.handle_width,
                "thickness": sv.thickness,
                "extent_xy": vec(sg["extent"]),
            },
            "object": {
                "name": "tea_box",
                "model_id": object_id,
                "frame": "tea box body: origin at the box's centre, +x along the long side of its footprint, +z up",
                "pose": pose_list(op),
                "yaw": round(yaw_of(op[3:]), 6),
                "size": vec(ov.size),
                "mass_kg": TEABOX_MASS,
                "grasp_tcp_point": vec([0.0, 0.0, sz / 2 - BOX_TCP_BELOW_TOP]),  # top-down, fingers across y
            },
        }
        return info

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        """Approach the scanner's handle and the box's top (the expert's grasp TCPs, following the
        objects), then the scanner TCP where the expert holds it while scanning (following the box)."""
        s, o = info["scanner"], info["object"]

        def at(name, local):
            return lambda w: transform_point(w.pose(name), local)

        def scan(w):
            return scan_tcp_reference(info, w.pose(o["name"])[:3])

        return [
            SpatialRule("Approach scanner", "either", at(s["name"], s["grasp_tcp_point"]), sphere(3)),
            SpatialRule("Approach object", "either", at(o["name"], o["grasp_tcp_point"]), sphere(2)),
            SpatialRule("Scan alignment", "either", scan, box(dx=3, dy=6, dz=3), prerequisites=(0, 1)),
        ]

    def solve(self, call, world: WorldView) -> None:
        """Both arms rise 10 cm. The scanner arm picks the scanner by its handle (top-down, from a
        hover, straight down, close, lift) and carries it aside; the other arm picks the box by its
        top likewise. Then the box arm brings the box to the middle, its long side along x,
        while the scanner arm turns the scanner so its beam points at the box, 5 cm short; a
        straight move along the beam brings the window 1.5 cm from the box's end face."""
        info = world.info
        s, o = info["scanner"], info["object"]
        arm_s, arm_o = info["scanner_arm"], info["object_arm"]
        top = float(info["table_top_z"])

        sp, op = world.pose(s["name"]), world.pose(o["name"])
        g_s = transform_point(sp, s["grasp_tcp_point"])
        g_o = transform_point(op, o["grasp_tcp_point"])
        # Fingers across the handle and across the box. The wrist camera sticks out 11 cm on the
        # TCP's +z side (approach x opening): both grasps are chosen so that, once the objects are
        # turned for the scan, it points away from the other arm: along the scanner's handle, and
        # away from the scanner for the box.
        sb = 1.0 if info["object_side"] == "right" else -1.0
        across_s = yaw_axis(sp[3:], s["handle_across"])
        q_s = top_down_quat(across_s)
        box_x, box_y = yaw_axis(op[3:], (1.0, 0.0, 0.0)), yaw_axis(op[3:], (0.0, 1.0, 0.0))
        turn_o = _box_turn(box_x)
        cam_after = _rz(turn_o) @ np.cross([0.0, 0.0, -1.0], box_y)
        q_o = top_down_quat(box_y if cam_after[0] * sb > 0 else -box_y)
        # first straight up: a wrist turning down from the start pose sweeps its links ~10 cm
        # lower than either end of the path, through a standing box (measured)
        call("move_both_delta", left_delta=[0.0, 0.0, PRE_LIFT], right_delta=[0.0, 0.0, PRE_LIFT])
        # one arm after the other (both near the centre line, two wrists collide): the scanner,
        # lifted and carried out toward its own side, then the box
        hs, ho = Hands(call, arm_s, HOVER), Hands(call, arm_o, HOVER)
        hs.grasp_from(world, g_s + [0.0, 0.0, HOVER], q_s, g_s, "the handle", ok=TOLERANT)
        out = 1.0 if arm_s == "right" else -1.0
        hs.move(dx=out * CLEAR_SIDE, dz=HOVER, what="lift the scanner aside", ok=TOLERANT)
        ho.grasp_from(world, g_o + [0.0, 0.0, HOVER], q_o, g_o, "the box", lift=HOVER, ok=TOLERANT)

        # the box: centre to the scanning spot, its long side (x) along world x
        B = np.array([sb * SCAN_CENTRE[0], SCAN_CENTRE[1], top + SCAN_HEIGHT])
        to = world.tcp_pose(arm_o)
        r_to = quat_to_mat(to[3:])
        op = world.pose(o["name"])
        turn_o = _box_turn(quat_to_mat(op[3:])[:, 0])
        r_new_o = _rz(turn_o) @ r_to
        c_in_tcp = r_to.T @ (op[:3] - to[:3])
        tcp_o = B - r_new_o @ c_in_tcp

        # the scanner: beam horizontal toward the box, window SCAN_GAP + PRE_SCAN short of the face
        ts = world.tcp_pose(arm_s)
        r_ts = quat_to_mat(ts[3:])
        win, r_fp = beam_frame(world, info)
        beam = r_fp[:, 2]
        turn_s = _wrap((0.0 if sb > 0 else np.pi) - np.arctan2(beam[1], beam[0]))
        r_new_s = _rz(turn_s) @ r_ts
        w_in_tcp = r_ts.T @ (win - ts[:3])
        win_goal = B - sb * np.array([float(o["size"][0]) / 2 + SCAN_GAP, 0.0, 0.0])
        tcp_s = win_goal - sb * np.array([PRE_SCAN, 0.0, 0.0]) - r_new_s @ w_in_tcp

        BothHands(call).reach({arm_o: tcp_o, arm_s: tcp_s}, {arm_o: mat_to_quat(r_new_o), arm_s: mat_to_quat(r_new_s)},
                              "bring both together", ok=TOLERANT)
        # a straight move along x puts the window at its goal (from where the window and the box
        # really are); the box hangs from its top and may still swing after the big move, so the
        # move is repeated from a fresh look until the window is within 3 mm of its goal
        for _ in range(SCAN_CORRECTIONS):
            win, _ = beam_frame(world, info)
            box_now = world.pose(o["name"])[:3]
            win_goal = box_now - sb * np.array([float(o["size"][0]) / 2 + SCAN_GAP, 0.0, 0.0])
            if np.linalg.norm(win_goal - win) < SCAN_TOLERANCE:
                break
            call("move_delta", arm=arm_s, dx=float(win_goal[0] - win[0]), dy=float(win_goal[1] - win[1]),
                 dz=float(win_goal[2] - win[2]))
        call("done", report="holding the scanner with its window 1.5 cm from the tea box's end face, beam on the "
                            "box's centre; both grippers closed", success_claim=True)


TASK = ScanObject
