"""rotate_qrcode: turn the QR-code payment board round so it faces the robot the right way up,
and leave it lying flat on the table.

Description
    A rigid QR-code payment board (a white 7 x 10 cm plaque, 1.4 cm thick, printed with a real,
    scannable QR code and a coloured 'scan to pay' header band above the code) lies flat on the
    table, face up, but turned round: its code reads upside down (the header toward the robot),
    give or take 40 degrees. The robot must turn it face-up the right way round for a person at
    the robot, the header at the far side and the code upright, and leave it flat on the table
    (both grippers open).

Randomisation (per seed; FACTS B.6)
    Board variant 0-3 (upstream ``070_paymentsign`` ids: header colour and encoded text differ).
    ``rand_pose``: x in [-0.25, 0.25] redrawn until |x| >= 0.05, y in [-0.2, 0.0], lying on the
    table (centre 1 mm above its resting height), base quaternion [0, 0, 0.707, 0.707] in
    upstream's mesh frame (this board's frame turned +90 deg about x, see below), i.e. a half turn
    about the vertical from the goal, composed with a random turn of +-0.7 rad about the vertical.

Success (final state)
    ``oriented``: the board's quaternion in upstream's mesh frame, q_mesh = q_board * Rx(90 deg),
    sign-normalised (q_w >= 0), is within 0.05 of [0.707, 0.707, 0, 0] in every component (the
    board flat and face-up within ~8 deg of tilt, its header toward +y within ~8 deg of heading);
    ``on_table``: the board's centre is below z = 0.75 (+ table bias): it lies on the table;
    ``grippers_open``: both arms' commanded gripper values > 0.8.
    Guard: the board must stay on the table (not below table top - 0.08 m).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, sphere
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Margin, WorldView, margin_below, margin_within
from cab_core.geometry import axis_angle_quat, quat_mul, quat_normalize, transform_point
from cab_core.kits.oracle import TOLERANT, Hands, OracleFailed, top_down_quat, yaw_axis
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, sample_until, yaw_of
from cab_core.kits.task import GrippersOpenVerifier

from ..assets_handover import QR_BOARD_HALF, qr_board
from ..common import CodeActionTask

MODEL_IDS = (0, 1, 2, 3)
MESH_FRAME = tuple(float(v) for v in axis_angle_quat([1.0, 0.0, 0.0], np.pi / 2))  # ours -> upstream mesh frame
BASE_QUAT_MESH = (0.0, 0.0, 0.707, 0.707)  # FACTS B.6, upstream mesh frame
TARGET_QUAT_MESH = (0.707, 0.707, 0.0, 0.0)
QUAT_TOL = 0.05
ON_TABLE_Z = 0.75  # + table bias
YAW_RAND = 0.7
GRIPPER_OPEN = 0.8
GRASP_TCP_HEIGHT = 0.040  # TCP above the table top for the grasp: fingertips 4.6 mm above it


def mesh_quat(q_board) -> np.ndarray:
    """The board's orientation in upstream's mesh frame, sign-normalised (q_w >= 0)."""
    q = quat_mul(np.asarray(q_board, float), MESH_FRAME)
    return -q if q[0] < 0 else q


def board_base_quat() -> np.ndarray:
    """Our board-frame quaternion whose mesh-frame quaternion is FACTS' base [0, 0, 0.707, 0.707]:
    a half turn about z."""
    q = quat_mul(quat_normalize(BASE_QUAT_MESH), [MESH_FRAME[0], -MESH_FRAME[1], -MESH_FRAME[2], -MESH_FRAME[3]])
    return quat_normalize(q)


class RotateQrcodeVerifier(GrippersOpenVerifier):
    open_threshold = GRIPPER_OPEN

    def __init__(self, info: dict[str, Any]):
        self.board = info["board"]["name"]
        self.arms = list(info["arms"])
        self.z_max = float(info["on_table_z"])
        # on_table's tolerance: the threshold's height above the centre of the board lying flat (3 mm)
        self.z_band = self.z_max - (float(info["table_top_z"]) + float(info["board"]["half_size"][2]))
        self.target = np.asarray(TARGET_QUAT_MESH, float)
        self.guarded_objects = (self.board,)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def measure(self, w: WorldView) -> tuple[dict[str, bool], dict[str, float], dict[str, Margin]]:
        p = w.pose(self.board)
        q = mesh_quat(p[3:])
        err = np.abs(q - self.target)
        oriented = bool(np.all(err < QUAT_TOL))
        on_table = bool(p[2] < self.z_max)
        values = {"quat_err_max": float(err.max()), "board_z": float(p[2]), "board_yaw": yaw_of(p[3:])}
        values.update({f"q_mesh_{k}": float(v) for k, v in zip("wxyz", q)})
        margins = {
            "oriented": margin_within(q - self.target, QUAT_TOL, "quaternion component"),
            "on_table": margin_below(p[2], self.z_max, "m", self.z_band),
        }
        return {"oriented": oriented, "on_table": on_table}, values, margins


class RotateQrcode(CodeActionTask):
    verifier_class = RotateQrcodeVerifier
    subgoal_predicates = (("oriented",), ("oriented", "on_table"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        model_id = int(rng.choice(MODEL_IDS))
        z = top + QR_BOARD_HALF[2] + 0.001
        pose = sample_until(
            lambda: rand_pose(rng, (-0.25, 0.25), (-0.2, 0.0), (z,), rotate_rand=True,
                              rotate_lim=(0.0, 0.0, YAW_RAND), qpos=board_base_quat()),
            lambda p: abs(p[0]) >= 0.05, what="the QR board")
        shapes, facts = qr_board(model_id)
        scene.bodies.append(Body("qrcode_board", shapes, pose=tuple(pose), kind="dynamic", mass=facts["mass_kg"],
                                 angular_damping=0.1))
        info = {
            "on_table_z": ON_TABLE_Z + (top - 0.74),
            "arms": ["left", "right"],
            "gripper_open_threshold": GRIPPER_OPEN,
            "orientation_test": {"mesh_frame_quat": list(MESH_FRAME), "target_mesh_quat": list(TARGET_QUAT_MESH),
                                 "tolerance": QUAT_TOL,
                                 "goal_in_board_frame": "identity: face up (+z), header toward +y"},
            "board": {
                "name": "qrcode_board",
                "frame": "board body: origin at the plaque's centre, +z out of the printed face, +y toward the "
                         "header band (the top of the code), +x to the code's right",
                "initial_pose": pose_list(pose),
                "yaw": round(yaw_of(pose[3:]), 6),
                **facts,
                "grasp_tcp_height": GRASP_TCP_HEIGHT,
            },
            "suggested_arm": "right" if pose[0] > 0 else "left",
        }
        return info

    # -- checkpoints ------------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        b = info["board"]
        top = float(info["table_top_z"])
        h = float(b["grasp_tcp_height"])
        # the expert's grasp TCP, in the board frame (lying flat: its centre is half_size[2] above the table)
        centre_to_tcp = np.asarray(b["grasp_point"], float) + [0.0, 0.0, h - float(b["half_size"][2])]
        return [
            SpatialRule("Approach qrcode", "either", lambda w: transform_point(w.pose(b["name"]), centre_to_tcp),
                        sphere(2.0)),
            # table-relative: the expert's TCP height when it sets the board down; XY unrestricted
            SpatialRule("Return to table", "either", lambda w: np.array([0.0, 0.0, top + h]),
                        box(None, None, (-5.0, 6.0)), prerequisites=(0,)),
        ]

    # -- reference solution -----------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """The arm on the board's side grasps it top-down across its width, lifts it 6 cm, turns the
        wrist by the board's heading error (about half a turn, the shorter way), sets it down flat
        where it was, lets go and rises (8 tool calls)."""
        info = world.info
        b = info["board"]
        arm = info["suggested_arm"]
        hands = Hands(call, arm)
        top = float(info["table_top_z"])
        h = float(b["grasp_tcp_height"])
        pose = world.pose(b["name"])
        across = yaw_axis(pose[3:], (1.0, 0.0, 0.0))  # the board's width direction (its +x)
        turn = -float(np.arctan2(across[1], across[0]))  # heading error: +x must point along world +x
        # the opening line is +-across; take the sign whose heading after the turn is nearer the
        # arm's natural top-down roll (opening along -x for the left arm, +x for the right)
        rest = np.array([-1.0, 0.0, 0.0]) if arm == "left" else np.array([1.0, 0.0, 0.0])
        c, s = np.cos(turn), np.sin(turn)
        after = np.array([c * across[0] - s * across[1], s * across[0] + c * across[1], 0.0])
        sign = 1.0 if float(np.dot(after, rest)) >= 0 else -1.0
        o_grasp, o_place = sign * across, sign * after
        g = transform_point(pose, b["grasp_point"])
        g[2] = top + h
        hands.grasp_from(world, g + [0.0, 0.0, 0.12], top_down_quat(o_grasp), g, "the board", lift=0.06)
        # turn the wrist in place, then set the board down flat where it was
        hands.turn_in_place(world, top_down_quat(o_place), what="turn the board")
        hands.move_to(world, (g[0], g[1], top + h + 0.003), "set down", ok=TOLERANT)
        hands.grip(1.0)
        hands.move(dz=0.08, what="rise", ok=TOLERANT)
        if not all(world.gripper_command(a) > GRIPPER_OPEN for a in info["arms"]):
            raise OracleFailed("a gripper is not open")
        call("done", report="turned the QR board round so it reads upright from the robot, flat and face-up on the "
                            "table", success_claim=True)


TASK = RotateQrcode
