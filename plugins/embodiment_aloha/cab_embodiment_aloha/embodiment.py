"""Build the ``aloha_agilex`` :class:`EmbodimentSpec`: generate (or reuse) the URDF/SRDF in the cache.

Files live in ``cache_dir()/embodiments/aloha_agilex-<hash of the parameters>/``; they are written
to a temporary folder and renamed into place, so concurrent processes never see a partial file.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from cab_core.contracts.embodiment import ArmSpec, EmbodimentSpec, GripperSpec
from cab_core.contracts.scene import CameraSpec, cache_dir
from cab_core.geometry import look_at_cv

from .kinematics import solve_home, tcp_pose_world
from .params import ARM_PREFIX, DEFAULT_PARAMS, AlohaParams
from .urdf import build_srdf, build_urdf

NAME = "aloha_agilex"
URDF_NAME = "aloha_agilex.urdf"
SRDF_NAME = "aloha_agilex.srdf"
META_NAME = "meta.json"


def home_qpos(p: AlohaParams) -> dict[str, tuple[float, ...]]:
    out = {}
    for arm, xyz in (("left", p.home_tcp_left), ("right", p.home_tcp_right)):
        q = solve_home(p, arm, xyz)
        out[arm] = tuple(float(round(v, 6)) for v in q)
    return out


def generate(p: AlohaParams = DEFAULT_PARAMS, root: Path | None = None) -> Path:
    """Write the robot description for ``p`` if it is not in the cache yet; return its folder."""
    root = Path(root) if root is not None else cache_dir() / "embodiments"
    target = root / f"{NAME}-{p.digest()}"
    if (target / META_NAME).is_file():
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=root))
    try:
        (tmp / URDF_NAME).write_text(build_urdf(p, NAME))
        (tmp / SRDF_NAME).write_text(build_srdf(p, NAME))
        meta = {"name": NAME, "digest": p.digest(), "home_qpos": home_qpos(p)}
        (tmp / META_NAME).write_text(json.dumps(meta, indent=1, sort_keys=True))  # written last
        try:
            os.replace(tmp, target)
        except OSError:  # another process won the race (target exists and is non-empty)
            if not (target / META_NAME).is_file():
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return target


def gripper_spec(p: AlohaParams, arm: str) -> GripperSpec:
    x = ARM_PREFIX[arm]
    return GripperSpec(
        joints=(f"{x}_joint7", f"{x}_joint8"),
        finger_links=(f"{x}_link7", f"{x}_link8"),
        closed_target=p.gripper_closed_target,
        open_target=p.gripper_open_target,
        gap_at_zero_m=p.gap_at_zero,
        gap_per_unit=1.0,
        max_opening_m=0.08,
        empty_close_gap_m=p.gap_at_zero,
        tip_ahead_of_tcp_m=round(p.finger_tip_length - p.finger_origin_behind_tcp, 6),
    )


def arm_links(arm: str) -> tuple[str, ...]:
    x = ARM_PREFIX[arm]
    return (f"{x}_base_link", *[f"{x}_link{i}" for i in range(1, 9)], f"{x}_tcp", f"{x}_camera")


def cameras(p: AlohaParams) -> tuple[CameraSpec, ...]:
    pos = np.asarray(p.head_cam_pos, dtype=float)
    head_pose = look_at_cv(pos, pos + np.asarray(p.head_cam_forward, dtype=float))
    hw, hh = p.head_cam_size
    ww, wh = p.wrist_cam_size
    return (
        CameraSpec("head_camera", hw, hh, p.cam_fovy_deg, tuple(float(v) for v in head_pose), None),
        CameraSpec("left_camera", ww, wh, p.cam_fovy_deg, mount_link="fl_camera"),
        CameraSpec("right_camera", ww, wh, p.cam_fovy_deg, mount_link="fr_camera"),
    )


def facts(p: AlohaParams) -> dict:
    """Public, qualitative facts for the ``get_embodiment`` tool (no scene facts, no privileged data)."""
    tip_ahead = round(p.finger_tip_length - p.finger_origin_behind_tcp, 4)
    return {
        "embodiment": NAME,
        "description": "Dual-arm mobile manipulator: two 6-DoF arms, each with a parallel two-finger "
                       "gripper, mounted side by side at the front of a wheeled base, facing the table.",
        "arms": {
            "left": {"side": "-x (robot's left)", "dof": 6, "gripper": "parallel two-finger"},
            "right": {"side": "+x (robot's right)", "dof": 6, "gripper": "parallel two-finger"},
        },
        "gripper": {
            "command": "gripper value in [0, 1]: 1.0 = fully open, 0.0 = closed (squeezes)",
            "max_opening_m": 0.08,
            "opening_m_meaning": "gripper value x max_opening_m (tracks the command)",
            "finger_gap_range_m": [round(p.gap_at_zero, 4), round(p.gap_at_zero + 2 * p.finger_travel, 4)],
            "finger_gap_meaning": "distance between the two finger-link origins (physical FK)",
            "empty_close_finger_gap_m": round(p.gap_at_zero, 4),
            "finger_origin_behind_tcp_m": p.finger_origin_behind_tcp,
            "finger_origin_to_tip_m": round(p.finger_tip_length, 4),
            "finger_origin_to_outer_side_face_m": p.finger_side_face,
            "finger_origin_to_inner_pad_face_m": p.pad_inner_offset,
            "fingertip_plane_ahead_of_tcp_m": tip_ahead,
            "pad_clearance_m": "finger_gap_m - 2 x finger_origin_to_inner_pad_face_m",
            "open_threshold": 0.8,
            "closed_threshold": 0.2,
        },
        "tcp": {
            "definition": "nominal grasp centre, between the finger pads",
            "flange_to_tcp_m": p.tcp_offset,
            "local_axes": {"+x": "approach (from the wrist toward the fingertips)",
                           "+y": "finger-opening line", "+z": "completes a right-handed frame"},
            "home": "both TCPs start in front of the robot, approach axis pointing +y (forward), "
                    "grippers open",
        },
        "frame": {"axes": "+x robot-right, +y forward (away from the robot), +z up",
                  "units": "metres", "left_arm": "-x side", "right_arm": "+x side"},
        "orientation": {"quaternion": "wxyz", "pose": "[x, y, z, qw, qx, qy, qz]"},
        "cameras": {
            "head_camera": "fixed, above and behind the arms, looking forward and down at the table",
            "left_camera": "on the left wrist, looking along the approach axis; sees the fingertips",
            "right_camera": "on the right wrist, looking along the approach axis; sees the fingertips",
        },
        "reachability": "each arm reaches the tabletop in front of the robot on its own side and "
                        "somewhat past the centre line, from above (approach -z) or from the front "
                        "(approach +y); targets far from an arm's side are better served by the "
                        "other arm. The planner checks robot self-collision only.",
        "motion": {"max_single_displacement_m": 0.30},
        "units": {"length": "m", "angle": "rad", "contact_impulse": "N*s"},
    }


def build_spec(p: AlohaParams = DEFAULT_PARAMS) -> EmbodimentSpec:
    folder = generate(p)
    meta = json.loads((folder / META_NAME).read_text())
    arms = {}
    for arm in ("left", "right"):
        x = ARM_PREFIX[arm]
        arms[arm] = ArmSpec(
            name=arm,
            joints=tuple(f"{x}_joint{i}" for i in range(1, 7)),
            base_link=f"{x}_base_link",
            ee_link=f"{x}_link6",
            tcp_link=f"{x}_tcp",
            camera_link=f"{x}_camera",
            gripper=gripper_spec(p, arm),
            home_qpos=tuple(meta["home_qpos"][arm]),
            links=arm_links(arm),
        )
    return EmbodimentSpec(
        name=NAME,
        urdf=str(folder / URDF_NAME),
        srdf=str(folder / SRDF_NAME),
        base_pose=tuple(float(v) for v in p.base_pose),
        arms=arms,
        cameras=cameras(p),
        drive_stiffness=1000.0,
        drive_damping=200.0,
        gripper_stiffness=1000.0,
        gripper_damping=200.0,
        tcp_offset_m=p.tcp_offset,
        facts=facts(p),
    )


def factory(cfg: dict) -> EmbodimentSpec:
    """Plugin factory. ``cfg`` may hold ``params: {field: value}`` overrides of :class:`AlohaParams`
    (other keys, e.g. Hydra's ``name``, are ignored)."""
    overrides = dict((cfg or {}).get("params") or {})
    p = DEFAULT_PARAMS.with_overrides(overrides) if overrides else DEFAULT_PARAMS
    return build_spec(p)


def home_tcp_poses(p: AlohaParams = DEFAULT_PARAMS) -> dict[str, np.ndarray]:
    return {arm: tcp_pose_world(p, arm, q) for arm, q in home_qpos(p).items()}
