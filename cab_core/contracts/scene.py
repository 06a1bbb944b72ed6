"""Simulator-agnostic scene description.

A task builds a :class:`SceneSpec` from its seed; every simulator backend builds the same world from
it. Geometry is primitives or mesh files (OBJ) and URDF files for articulated objects, all generated
by the project's own code into a cache directory; nothing is downloaded.

Names are the privileged identities of objects. They reach the simulator, the verifier and the
records, never the agent.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

IDENTITY_POSE = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Material:
    color: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)  # linear RGBA, 0..1
    static_friction: float = 0.5
    dynamic_friction: float = 0.5
    restitution: float = 0.0
    roughness: float = 0.6
    metallic: float = 0.0
    #: an RGB image file (PNG, sRGB values) shown on the shape's surface instead of the plain colour,
    #: or None; on a primitive (box, sphere, cylinder, capsule) repeated every 0.3 m of surface as
    #: :mod:`cab_core.contracts.texturing` maps it; a mesh keeps the plain colour. Visual only
    texture: str | None = None


@dataclass(frozen=True)
class Box:
    half_size: tuple[float, float, float]


@dataclass(frozen=True)
class Sphere:
    radius: float


@dataclass(frozen=True)
class Capsule:
    """Axis along local x (the scene description's convention); backends convert."""
    radius: float
    half_length: float


@dataclass(frozen=True)
class Cylinder:
    """Axis along local x (the scene description's convention); backends convert."""
    radius: float
    half_length: float


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh file (OBJ). ``convex=True`` collides as its convex hull."""
    path: str
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    convex: bool = True


Geometry = Box | Sphere | Capsule | Cylinder | Mesh


@dataclass(frozen=True)
class Shape:
    geometry: Geometry
    pose: tuple[float, ...] = IDENTITY_POSE  # local pose in the body frame
    material: Material = field(default_factory=Material)
    collision: bool = True
    visual: bool = True


@dataclass
class Body:
    """A rigid body. ``kind``: static (never moves), dynamic, or kinematic (moved by code only)."""
    name: str
    shapes: list[Shape]
    pose: tuple[float, ...] = IDENTITY_POSE
    kind: Literal["static", "dynamic", "kinematic"] = "dynamic"
    mass: float | None = None  # None: from density
    density: float = 500.0
    linear_damping: float = 0.0
    angular_damping: float = 0.05


@dataclass
class ArticulatedObject:
    """An articulated object loaded from a URDF (laptop, microwave, stapler...)."""
    name: str
    urdf: str
    pose: tuple[float, ...] = IDENTITY_POSE
    fix_root: bool = True
    qpos: tuple[float, ...] | None = None  # initial joint positions, URDF active-joint order
    joint_friction: float = 0.0
    joint_damping: float = 0.0


@dataclass(frozen=True)
class CameraSpec:
    """An RGB camera. Poses are in the OpenCV convention: +x right, +y down, +z forward.

    A fixed camera has a world ``pose``. A mounted camera follows ``mount_link`` of the robot with
    ``pose`` given in that link's frame.
    """
    name: str
    width: int
    height: int
    fovy_deg: float
    pose: tuple[float, ...] = IDENTITY_POSE
    mount_link: str | None = None
    near: float = 0.1
    far: float = 100.0


@dataclass(frozen=True)
class Lighting:
    ambient: tuple[float, float, float] = (0.5, 0.5, 0.5)
    directional: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
        ((0.0, 0.5, -1.0), (0.5, 0.5, 0.5)),
    )
    points: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
        ((1.0, 0.0, 1.8), (1.0, 1.0, 1.0)),
        ((-1.0, 0.0, 1.8), (1.0, 1.0, 1.0)),
    )


@dataclass
class SceneSpec:
    """Everything a backend needs to build the world, minus the robot (see ``EmbodimentSpec``)."""
    bodies: list[Body] = field(default_factory=list)
    articulations: list[ArticulatedObject] = field(default_factory=list)
    cameras: list[CameraSpec] = field(default_factory=list)  # scene cameras (e.g. the head camera)
    lighting: Lighting = field(default_factory=Lighting)
    timestep: float = 1.0 / 250.0
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    ground_z: float = 0.0
    ground_color: tuple[float, float, float, float] = (0.55, 0.55, 0.52, 1.0)
    default_material: Material = field(default_factory=Material)

    def body(self, name: str) -> Body:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(name)

    def names(self) -> list[str]:
        return [b.name for b in self.bodies] + [a.name for a in self.articulations]


def as_pose(p) -> tuple[float, ...]:
    """Validate and normalise a 7-vector pose (wxyz quaternion) into a tuple."""
    a = np.asarray(p, dtype=float).reshape(-1)
    if a.shape != (7,) or not np.all(np.isfinite(a)):
        raise ValueError(f"a pose is 7 finite numbers [x,y,z,qw,qx,qy,qz], got {p!r}")
    n = np.linalg.norm(a[3:])
    if n < 1e-9:
        raise ValueError(f"pose quaternion is zero: {p!r}")
    a[3:] /= n
    return tuple(float(v) for v in a)


def cache_dir() -> Path:
    """Where generated assets go: $CAB_CACHE_DIR, else ~/.cache/cab (never the source tree)."""
    import os

    root = os.environ.get("CAB_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "cab")
    p = Path(root)
    p.mkdir(parents=True, exist_ok=True)
    return p
