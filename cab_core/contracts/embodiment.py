"""Embodiments declare data, not behaviour: asset paths, joint groups, TCP link, gripper mapping."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.scene import CameraSpec


@dataclass(frozen=True)
class GripperSpec:
    """A parallel gripper driven by ``joints`` (each finger its own prismatic joint).

    The normalised command ``g`` in [0, 1] (0 closed, 1 open) maps to the drive target
    ``closed_target + g * (open_target - closed_target)`` of every finger joint.
    ``finger_gap_m(q)`` = ``gap_at_zero_m + gap_per_unit * (q_a + q_b)`` is the distance between
    the finger-link origins.
    """
    joints: tuple[str, str]
    finger_links: tuple[str, str]
    closed_target: float
    open_target: float
    gap_at_zero_m: float
    gap_per_unit: float = 1.0
    max_opening_m: float = 0.08
    empty_close_gap_m: float = 0.049
    tip_ahead_of_tcp_m: float = 0.0354


@dataclass(frozen=True)
class ArmSpec:
    name: str  # "left" or "right"
    joints: tuple[str, ...]  # arm joints, base to tip
    base_link: str
    ee_link: str  # flange / wrist link
    tcp_link: str  # fixed link at the nominal grasp centre; +x approach, +y opening line
    camera_link: str  # wrist camera mount (OpenCV-convention frame)
    gripper: GripperSpec
    home_qpos: tuple[float, ...]
    links: tuple[str, ...] = ()  # every link of the arm incl. fingers (contact attribution)


@dataclass(frozen=True)
class EmbodimentSpec:
    name: str
    urdf: str  # absolute path of a generated file in the cache (never stored in records)
    srdf: str
    base_pose: tuple[float, ...]  # world pose of the URDF root
    arms: dict[str, ArmSpec]
    cameras: tuple[CameraSpec, ...]  # mounted cameras (mount_link set) and fixed robot cameras
    drive_stiffness: float = 1000.0
    drive_damping: float = 200.0
    gripper_stiffness: float = 1000.0
    gripper_damping: float = 200.0
    tcp_offset_m: float = 0.12  # TCP ahead of ee_link along +x
    facts: dict = field(default_factory=dict)  # qualitative/public facts for get_embodiment

    def joint_order(self) -> list[str]:
        """All driven joints, arms in sorted name order, arm joints then gripper joints."""
        out: list[str] = []
        for name in sorted(self.arms):
            arm = self.arms[name]
            out += list(arm.joints) + list(arm.gripper.joints)
        return out
