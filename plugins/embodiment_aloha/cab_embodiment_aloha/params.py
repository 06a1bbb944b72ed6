"""Every number that defines the generated aloha_agilex robot, in one frozen dataclass.

Frames. The URDF root ``base_link`` sits at the world pose ``base_pose`` (x = forward, y = left,
z = up in the robot's own frame; the default pose yaws it +90 degrees so that robot-forward is
world +y and robot-left is world -x). Each arm stands on a fixed ``<p>_base_link`` on the shoulder
beam; at zero joint angles the whole arm points straight up. Joint axes: 1 yaw (z), 2 shoulder
pitch (y, + tilts the upper arm forward), 3 elbow pitch (y, 0 = straight, both bending directions
allowed), 4 wrist pitch (y), 5 wrist yaw (z), 6 wrist roll (x). The flange ``<p>_link6`` has +x
along the approach axis and +y along the finger-opening line; the TCP is ``tcp_offset`` ahead of
it. The home joint values are solved (not fixed) so that the TCPs start at ``home_tcp_*``.

The gripper: two prismatic fingers per arm, each its own driven joint (no mimic joint). Finger
``<p>_link7`` opens along +y, ``<p>_link8`` along -y. Finger-link origins sit
``finger_origin_behind_tcp`` behind the TCP and ``gap_at_zero / 2 + q`` off the approach axis; a
finger's flat pad spans ``finger_tip_length`` ahead of its origin and its inner (contact) face is
``pad_inner_offset`` inward of the origin, so the pads' clearance is
``finger_gap - 2 * pad_inner_offset``.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, fields, replace

from cab_core.errors import ConfigError

GENERATOR_VERSION = "aloha_agilex-gen-1"


@dataclass(frozen=True)
class AlohaParams:
    # --- placement -------------------------------------------------------------------------
    base_pose: tuple[float, ...] = (0.0, -0.65, 0.0, 0.70710678, 0.0, 0.0, 0.70710678)
    # Chosen with ``python -m cab_embodiment_aloha.reach``: shoulders set back and high with long
    # links let the nearer arm reach the far table edge from above and objects close to the robot
    # from the front (see that module for the figures).
    shoulder_x: float = -0.05  # arm mount, robot frame (forward of the base origin)
    shoulder_y: float = 0.22  # |lateral| of each arm mount (left = +y, right = -y)
    shoulder_z: float = 0.95  # top of the shoulder beam = arm mount height
    # --- arm chain (metres) ----------------------------------------------------------------
    h_base: float = 0.05  # mount -> joint1
    h_shoulder: float = 0.06  # joint1 -> joint2
    upper_arm: float = 0.50  # joint2 -> joint3 (along +z at zero)
    forearm: float = 0.50  # joint3 -> joint4 (continues the upper arm at zero)
    wrist1: float = 0.08  # joint4 -> joint5
    wrist2: float = 0.05  # joint5 -> joint6 (flange)
    tcp_offset: float = 0.12  # flange -> TCP along the approach axis
    # --- joint limits (rad) ----------------------------------------------------------------
    limits: tuple[tuple[float, float], ...] = (
        (-2.6, 2.6),  # 1 yaw
        (-2.4, 2.4),  # 2 shoulder pitch (0 = upper arm up, + tilts it forward)
        (-2.85, 2.85),  # 3 elbow (0 = straight, + bends the forearm forward/down)
        (-2.4, 2.4),  # 4 wrist pitch
        (-2.4, 2.4),  # 5 wrist yaw
        (-4.71238898, 4.71238898),  # 6 wrist roll (+-3pi/2: any roll has a solution away from a limit)
    )
    joint_velocity: float = 3.0  # URDF velocity limit (rad/s)
    joint_effort: float = 200.0  # URDF effort limit (N m)
    # --- gripper ---------------------------------------------------------------------------
    finger_origin_behind_tcp: float = 0.0354
    finger_tip_length: float = 0.0708  # finger-link origin -> fingertip plane (≈ 0.070)
    gap_at_zero: float = 0.048  # distance between finger-link origins at q = 0
    finger_travel: float = 0.047  # upper limit of each finger joint: gap 0.048 .. 0.142
    pad_inner_offset: float = 0.023  # finger-link origin -> inner pad face (toward the centre)
    pad_thickness: float = 0.010
    pad_half_height: float = 0.013  # along the TCP z axis
    finger_side_face: float = 0.010  # finger-link origin -> outer side face
    gripper_open_target: float = 0.045
    gripper_closed_target: float = -0.01  # beyond the closed limit: a closed gripper squeezes
    # --- masses (kg) -----------------------------------------------------------------------
    link_masses: tuple[float, ...] = (0.9, 1.6, 1.2, 0.45, 0.4, 0.7)  # link1..link6 (+gripper)
    finger_mass: float = 0.05
    # --- wrist camera (in the flange frame) ------------------------------------------------
    # above the gripper housing, pitched down so that the fingertips sit in the lower third of the
    # image and the TCP just above the housing's front edge
    wrist_cam_pos: tuple[float, float, float] = (-0.02, 0.0, 0.10)
    wrist_cam_pitch_deg: float = 20.0  # optical axis tilted down from the approach axis
    # --- head camera (world) ---------------------------------------------------------------
    head_cam_pos: tuple[float, float, float] = (-0.032, -0.45, 1.35)
    head_cam_forward: tuple[float, float, float] = (0.0, 0.6, -0.8)
    head_cam_size: tuple[int, int] = (640, 480)
    wrist_cam_size: tuple[int, int] = (320, 240)
    cam_fovy_deg: float = 37.0
    # --- home TCP targets (world) the home joint values are solved for ---------------------
    home_tcp_left: tuple[float, float, float] = (-0.300, -0.194, 0.942)
    home_tcp_right: tuple[float, float, float] = (0.305, -0.193, 0.941)

    def digest(self) -> str:
        """A short, stable hash of the parameters and of the generator's own source, so that a
        changed generator never reuses stale cached files."""
        blob = json.dumps({"v": GENERATOR_VERSION, "p": asdict(self), "src": _source_digest()},
                          sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    def with_overrides(self, overrides: dict) -> AlohaParams:
        """A copy with some fields replaced (lists become tuples); unknown names raise."""
        known = {f.name for f in fields(self)}
        bad = sorted(set(overrides) - known)
        if bad:
            raise ConfigError(f"unknown aloha_agilex parameter(s): {', '.join(bad)}")

        def tup(v):
            return tuple(tup(x) for x in v) if isinstance(v, (list, tuple)) else v

        return replace(self, **{k: tup(v) for k, v in overrides.items()})


def _source_digest() -> str:
    from pathlib import Path

    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in ("params.py", "kinematics.py", "urdf.py", "embodiment.py"):
        h.update((here / name).read_bytes())
    return h.hexdigest()


DEFAULT_PARAMS = AlohaParams()

ARM_PREFIX = {"left": "fl", "right": "fr"}
ARM_SIDE = {"left": 1.0, "right": -1.0}  # sign of the mount's robot-frame y
