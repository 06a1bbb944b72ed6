"""place_mouse_pad: put the computer mouse on the coloured mat, centred and aligned with it.

Description
    A computer mouse (about 6 x 11 x 3.5 cm) lies on the table at some heading; a thin coloured mat
    (7 x 13 cm, long side front-to-back) lies flat nearby on the same side of the table. The robot
    must grasp the mouse and put it down on the mat, centred on it and lined up with the mat's long
    side (its front pointing forward or backward), then let go.

Randomisation (per seed; FACTS B.6)
    Mouse variant in {0, 1, 2} (upstream ``047_mouse`` ids: three sizes/colourings), mass 0.05 kg.
    Its pose with ``rand_pose``: x in [-0.25, 0.25], y in [-0.2, 0.0], z 0.741, heading in
    +-3.14 rad on the first draw and +-pi/4 on redraws, redrawn until |x| >= 0.05. The mat (static
    box, half-size (0.035, 0.065, 0.0005), lying on the table, no rotation) takes one of 8 named
    colours and lies on the mouse's side: x in [0.05, 0.25] (or [-0.25, -0.05] for a mouse at
    x < 0), y in [-0.2, 0.0], redrawn until its centre is >= 0.1 m from the mouse's.

Success (final state)
    ``centred``: the mouse's origin (centre of its footprint) is within 0.015 m in x and 0.012 m in y
    of the mat's centre;
    ``aligned``: the upstream orientation test on the mouse's quaternion expressed in upstream's
    mesh frame (ours turned +90 deg about x: q_mesh = q_mouse * Rx(90 deg)):
    ||q_y q_z| - 0.49| < 0.015 or ||q_w q_x| - 0.49| < 0.015. For an upright mouse this means its
    long axis is within ~26 deg of the world y axis (the mat's long side), front forward or
    backward (as upstream's, the test would also accept the mouse upside down along y);
    ``grippers_open``: both arms' commanded gripper values > 0.8.
    Guard: the mouse must stay on the table (not below table top - 0.08 m).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, cylinder, sphere
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Margin, WorldView, margin_any, margin_within
from cab_core.geometry import axis_angle_quat, quat_mul, transform_point
from cab_core.kits.oracle import TOLERANT, Hands, OracleFailed, top_down_quat, yaw_axis
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, sample_until, vec, yaw_of
from cab_core.kits.task import GrippersOpenVerifier

from ..assets_handover import MAT_COLOURS, MAT_HALF, computer_mouse, mouse_mat
from ..common import CodeActionTask

MODEL_IDS = (0, 1, 2)
TOL_X, TOL_Y = 0.015, 0.012
ORIENT_TARGET, ORIENT_TOL = 0.49, 0.015
GRIPPER_OPEN = 0.8
MESH_FRAME = tuple(float(v) for v in axis_angle_quat([1.0, 0.0, 0.0], np.pi / 2))  # ours -> upstream mesh frame
GRASP_TCP_HEIGHT = 0.040  # TCP above the table for the grasp: fingertips 4.6 mm above the table


def aligned(q_mouse) -> tuple[bool, float, float]:
    """Upstream's test on the mesh-frame quaternion; returns (ok, |q_y q_z|, |q_w q_x|)."""
    q = quat_mul(np.asarray(q_mouse, float), MESH_FRAME)
    yz, wx = abs(float(q[2] * q[3])), abs(float(q[0] * q[1]))
    return (abs(yz - ORIENT_TARGET) < ORIENT_TOL or abs(wx - ORIENT_TARGET) < ORIENT_TOL), yz, wx


class PlaceMousePadVerifier(GrippersOpenVerifier):
    open_threshold = GRIPPER_OPEN

    def __init__(self, info: dict[str, Any]):
        self.mouse, self.mat = info["mouse"]["name"], info["mat"]["name"]
        self.arms = list(info["arms"])
        self.guarded_objects = (self.mouse,)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def measure(self, w: WorldView) -> tuple[dict[str, bool], dict[str, float], dict[str, Margin]]:
        m, p = w.pose(self.mouse), w.pose(self.mat)
        d = np.asarray(m[:3], float) - np.asarray(p[:3], float)
        centred = bool(abs(d[0]) < TOL_X and abs(d[1]) < TOL_Y)
        ok, yz, wx = aligned(m[3:])
        values = {"mouse_dx": float(d[0]), "mouse_dy": float(d[1]), "q_yz": yz, "q_wx": wx,
                  "mouse_yaw": yaw_of(m[3:])}
        margins = {
            "centred": margin_within(d[:2], (TOL_X, TOL_Y), "m"),
            # either of upstream's two products within its band (unit: the product |q_i q_j|)
            "aligned": margin_any(margin_within([yz - ORIENT_TARGET], ORIENT_TOL, "quaternion product"),
                                  margin_within([wx - ORIENT_TARGET], ORIENT_TOL, "quaternion product")),
        }
        return {"centred": centred, "aligned": bool(ok)}, values, margins


class PlaceMousePad(CodeActionTask):
    verifier_class = PlaceMousePadVerifier
    subgoal_predicates = (("centred",), ("centred", "aligned"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        model_id = int(rng.choice(MODEL_IDS))
        first = [True]

        def draw_mouse() -> np.ndarray:
            lim = 3.14 if first[0] else np.pi / 4
            first[0] = False
            return rand_pose(rng, (-0.25, 0.25), (-0.2, 0.0), rotate_rand=True, rotate_lim=(0.0, 0.0, lim))

        mouse_pose = sample_until(draw_mouse, lambda p: abs(p[0]) >= 0.05, what="the mouse")
        colour = str(rng.choice(sorted(MAT_COLOURS)))
        xlim = (0.05, 0.25) if mouse_pose[0] > 0 else (-0.25, -0.05)
        mat_pose = sample_until(lambda: rand_pose(rng, xlim, (-0.2, 0.0), (top + MAT_HALF[2],)),
                                lambda p: float(np.hypot(*(p[:2] - mouse_pose[:2]))) >= 0.1, what="the mat")
        shapes, facts = computer_mouse(model_id)
        scene.bodies.append(Body("mat", mouse_mat(colour), pose=tuple(mat_pose), kind="static"))
        scene.bodies.append(Body("mouse", shapes, pose=tuple(mouse_pose), kind="dynamic", mass=facts["mass_kg"],
                                 angular_damping=0.1))
        info = {
            "arms": ["left", "right"],
            "tolerance_xy": [TOL_X, TOL_Y],
            "orientation_test": {"target": ORIENT_TARGET, "tolerance": ORIENT_TOL,
                                 "mesh_frame_quat": list(MESH_FRAME)},
            "gripper_open_threshold": GRIPPER_OPEN,
            "mouse": {
                "name": "mouse",
                "frame": "mouse body: origin at the centre of its footprint on the table, +y toward its front "
                         "(buttons), +z up",
                "initial_pose": pose_list(mouse_pose),
                "yaw": round(yaw_of(mouse_pose[3:]), 6),
                **facts,
                "grasp_tcp_height": GRASP_TCP_HEIGHT,
            },
            "mat": {
                "name": "mat",
                "frame": "mat body: centre of the slab; long side along y",
                "pose": pose_list(mat_pose),
                "colour": colour,
                "half_size": vec(MAT_HALF),
            },
            "suggested_arm": "right" if mouse_pose[0] > 0 else "left",
        }
        return info

    # -- checkpoints ------------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        m, mat = info["mouse"], info["mat"]
        h = float(m["grasp_tcp_height"])
        g = np.asarray(m["grasp_point"], float) + [0.0, 0.0, h]
        top = float(mat["half_size"][2])
        return [
            SpatialRule("Approach mouse", "either", lambda w: transform_point(w.pose(m["name"]), g), sphere(2.0)),
            SpatialRule("Place at pad", "either",
                        lambda w: np.asarray(w.pose(mat["name"])[:3], float) + [0.0, 0.0, top + h],
                        cylinder(4.0, (-2.0, 5.0)), prerequisites=(0,)),
        ]

    # -- reference solution -----------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """The arm on the mouse's side grasps it top-down across its width, lifts it, turns it so its
        long axis runs along y (the mat's long side; whichever way needs the smaller wrist turn),
        lowers it onto the mat's centre, lets go and rises (8 tool calls)."""
        info = world.info
        m, mat = info["mouse"], info["mat"]
        arm = info["suggested_arm"]
        hands = Hands(call, arm)
        top = float(info["table_top_z"])
        h = float(m["grasp_tcp_height"])
        pose = world.pose(m["name"])
        across = yaw_axis(pose[3:], (1.0, 0.0, 0.0))  # the mouse's width direction
        # grasp opening: +-across, the sign that needs the smaller turn to +-world x at the mat
        # (the turn is then at most 90 deg); the placement opening is the nearer of +-x
        o_grasp = across if abs(np.arctan2(across[1], across[0])) <= np.pi / 2 else -across
        o_place = np.array([1.0, 0.0, 0.0])
        g = transform_point(pose, m["grasp_point"])
        g[2] = top + h
        hands.grasp_from(world, g + [0.0, 0.0, 0.12], top_down_quat(o_grasp), g, "the mouse", lift=0.06)
        # where the mouse hangs relative to the TCP, turned with the wrist to the placing heading
        held = world.pose(m["name"])[:3] - world.tcp_pose(arm)[:3]
        a0, a1 = np.arctan2(o_grasp[1], o_grasp[0]), np.arctan2(o_place[1], o_place[0])
        c, s = np.cos(a1 - a0), np.sin(a1 - a0)
        held_xy = np.array([c * held[0] - s * held[1], s * held[0] + c * held[1]])
        target = np.asarray(world.pose(mat["name"])[:3], float)
        t = np.array([target[0] - held_xy[0], target[1] - held_xy[1], top + 2 * float(mat["half_size"][2]) + h + 0.003])
        hands.reach(t + [0.0, 0.0, 0.06], top_down_quat(o_place), "over the mat")
        hands.move_to(world, t, "set down", ok=TOLERANT)
        hands.grip(1.0)
        hands.move(dz=0.08, what="rise", ok=TOLERANT)
        if not all(world.gripper_command(a) > GRIPPER_OPEN for a in info["arms"]):
            raise OracleFailed("a gripper is not open")
        call("done", report="put the mouse on the mat, centred and lined up with its long side", success_claim=True)


TASK = PlaceMousePad
