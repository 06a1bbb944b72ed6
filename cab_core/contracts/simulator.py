"""The simulator contract. Simulator backends (plugins, hook ``cab_simulators``) implement it; the
core never imports a simulator. All poses are world-frame [x,y,z,qw,qx,qy,qz]; cameras use OpenCV axes.

Naming: rigid bodies and articulated objects keep their ``SceneSpec`` names; robot links are
reported as ``"robot/<link>"``, links of an articulated object as ``"<object>/<link>"``, the ground
as ``"ground"``. Names are privileged: they never reach the agent.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:  # pragma: no cover  (annotations only: the contract names the descriptions it builds from)
    from cab_core.contracts.embodiment import EmbodimentSpec
    from cab_core.contracts.scene import SceneSpec

ROBOT = "robot"


@dataclass(frozen=True)
class Contact:
    """Contact between two bodies during the last physics step."""
    a: str
    b: str
    impulse: float  # N*s, summed over the contact points of the pair during the last step
    point: tuple[float, float, float] | None = None  # mean world contact point, if known


@dataclass(frozen=True)
class SimState:
    """An opaque, exact snapshot of the simulation (bodies, joints, drive targets, time)."""
    backend: str
    data: bytes


class WorldReads(Protocol):
    """The reads a :class:`~cab_core.contracts.verifier.WorldView` makes of a world: a
    :class:`Simulator` answers them live, a recorded privileged snapshot from its record."""

    def object_names(self) -> list[str]: ...

    def get_object_pose(self, name: str) -> np.ndarray: ...

    def get_object_qpos(self, name: str) -> np.ndarray: ...

    def get_object_link_pose(self, name: str, link: str) -> np.ndarray: ...

    def get_link_pose(self, link: str) -> np.ndarray: ...

    def get_contacts(self) -> list[Contact]: ...


class Simulator(ABC):
    """One simulated world, built once per attempt. Not thread-safe: one owner thread."""

    name: str = "abstract"

    # -- life cycle ---------------------------------------------------------------------------
    @abstractmethod
    def build(self, scene: SceneSpec, embodiment: EmbodimentSpec) -> None:
        """Create the world from a scene description plus the robot. Called once."""

    @abstractmethod
    def close(self) -> None:
        """Release native resources. Idempotent."""

    @property
    @abstractmethod
    def timestep(self) -> float:
        """Seconds per physics step (1/250 by default)."""

    @abstractmethod
    def step(self, n: int = 1) -> None:
        """Advance physics ``n`` steps with the current drive targets. Hosts call this only
        through the episode's step clock, which charges simulated time."""

    # -- robot --------------------------------------------------------------------------------
    @property
    @abstractmethod
    def joint_names(self) -> list[str]:
        """Driven robot joints, in ``EmbodimentSpec.joint_order()``."""

    @abstractmethod
    def get_qpos(self) -> np.ndarray: ...

    @abstractmethod
    def get_qvel(self) -> np.ndarray: ...

    @abstractmethod
    def set_qpos(self, qpos: np.ndarray) -> None:
        """Teleport the robot joints (reset only) and set the drive targets to match."""

    @abstractmethod
    def set_drive_targets(self, targets: np.ndarray, velocities: np.ndarray | None = None) -> None:
        """Position targets (and optional velocity targets, default zero) for every driven joint
        (``joint_names`` order), as a planned trajectory streams them. Raises BadCommand on a
        wrong shape or non-finite value."""

    @abstractmethod
    def get_drive_targets(self) -> np.ndarray: ...

    @abstractmethod
    def get_link_pose(self, link: str) -> np.ndarray:
        """World pose of a robot link. Raises BadCommand for an unknown link."""

    # -- objects ------------------------------------------------------------------------------
    @abstractmethod
    def object_names(self) -> list[str]:
        """Rigid bodies and articulated objects of the scene."""

    @abstractmethod
    def get_object_pose(self, name: str) -> np.ndarray:
        """World pose of a body or of an articulated object's root. BadCommand if unknown."""

    @abstractmethod
    def set_object_pose(self, name: str, pose) -> None:
        """Teleport a body (or an articulated object's root) and zero its velocity."""

    @abstractmethod
    def get_object_velocity(self, name: str) -> np.ndarray:
        """[vx, vy, vz, wx, wy, wz] of a body (root link for articulations)."""

    @abstractmethod
    def get_object_qpos(self, name: str) -> np.ndarray:
        """Joint positions of an articulated object (empty for rigid bodies)."""

    @abstractmethod
    def set_object_qpos(self, name: str, qpos) -> None: ...

    @abstractmethod
    def get_object_link_pose(self, name: str, link: str) -> np.ndarray:
        """World pose of a link of an articulated object."""

    def get_object_link_names(self, name: str) -> list[str]:
        """Links of an articulated object (empty for rigid bodies)."""
        return []

    # -- contacts -----------------------------------------------------------------------------
    @abstractmethod
    def get_contacts(self) -> list[Contact]:
        """Contacts of the last physics step, one entry per body pair with a non-zero impulse."""

    # -- cameras ------------------------------------------------------------------------------
    @abstractmethod
    def camera_names(self) -> list[str]: ...

    @abstractmethod
    def camera_pose(self, name: str) -> np.ndarray:
        """Current world pose of a camera (OpenCV axes)."""

    @abstractmethod
    def camera_intrinsics(self, name: str) -> np.ndarray:
        """3x3 pinhole K."""

    @abstractmethod
    def camera_size(self, name: str) -> tuple[int, int]:
        """(height, width)."""

    @abstractmethod
    def render(self, name: str) -> np.ndarray:
        """RGB image, uint8 HxWx3, of the current state. BadCommand for an unknown camera."""

    # -- rendering later (optional) -----------------------------------------------------------
    def render_sample(self) -> object | None:
        """A cheap record of what rendering the current state takes (the poses of everything
        drawn), read without changing the world in any way: a run in which samples are taken
        steps bit-identically to the same run without them. ``None`` where the backend cannot
        render from samples (the default; also when it was built without a renderer): the host
        then renders in the loop. The episode takes one every ``record.video_every_steps`` steps
        and renders the video from them once the attempt is over (:meth:`render_samples`)."""
        return None

    def render_samples(self, name: str, samples: Iterable[object], emit: Callable[[np.ndarray], None]) -> None:
        """For each of ``samples`` (from :meth:`render_sample` of this simulator), in order,
        ``emit(image)`` with the image that ``render(name)`` gave in the state the sample was taken
        in, bit for bit. Returns with the world exactly as it found it: nothing the contract reads
        has changed and the steps that follow are those that would have followed without the call
        (``emit`` must not use the simulator)."""
        raise NotImplementedError(f"{type(self).__name__} does not render from samples")

    # -- state --------------------------------------------------------------------------------
    @abstractmethod
    def save_state(self) -> SimState: ...

    @abstractmethod
    def restore_state(self, state: SimState) -> None:
        """Restore exactly; stepping after a restore reproduces the same trajectory."""

    # -- provenance ---------------------------------------------------------------------------
    @abstractmethod
    def versions(self) -> dict[str, str]:
        """Simulator, renderer (device, driver) and anything else that changes results."""
