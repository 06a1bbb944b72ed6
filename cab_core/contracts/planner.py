"""The planner contract: inverse kinematics and joint trajectories for TCP targets of one arm.

The planner's collision world holds the robot only (as in the paper): no table, no objects.
A refusal is a result, not an exception: ``status`` says whether IK or path search failed.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.embodiment import EmbodimentSpec

PlanStatus = Literal["success", "no_ik", "no_path", "invalid_start", "invalid_goal"]


@dataclass
class PlanResult:
    status: PlanStatus
    positions: np.ndarray | None = None  # (N, n_arm_joints) at ``dt`` spacing, first row = start
    dt: float = 1.0 / 250.0
    message: str = ""
    position_error_m: float | None = None  # of the IK solution, when one was found
    rotation_error_rad: float | None = None
    attempts: int = 1
    planning_time_s: float = 0.0
    raw: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "success"


@dataclass
class IKResult:
    ok: bool
    qpos: np.ndarray | None = None  # arm joints
    message: str = ""
    position_error_m: float | None = None
    rotation_error_rad: float | None = None


class Planner(ABC):
    name: str = "abstract"

    @abstractmethod
    def setup(self, embodiment: EmbodimentSpec, dt: float) -> None:
        """Load the robot model. Called once per attempt, before any query."""

    @abstractmethod
    def fk(self, arm: str, arm_qpos: np.ndarray) -> np.ndarray:
        """World TCP pose for the given arm joint positions."""

    @abstractmethod
    def ik(self, arm: str, tcp_pose_world: np.ndarray, seed_qpos: np.ndarray) -> IKResult: ...

    @abstractmethod
    def plan_to_pose(self, arm: str, start_qpos: np.ndarray, tcp_pose_world: np.ndarray,
                     *, straight_line: bool = False) -> PlanResult:
        """A collision-free (self-collision only) joint trajectory from ``start_qpos`` (arm joints)
        to a TCP pose. ``straight_line`` asks for a Cartesian (screw) path."""

    @abstractmethod
    def versions(self) -> dict[str, str]: ...
