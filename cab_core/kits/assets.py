"""Generated assets of a task's scene: meshes (OBJ) and articulated objects (URDF) written to
cab's cache, content-addressed, and the text helpers that build a URDF. Lengths in metres, masses
in kilograms, angles in radians."""
from __future__ import annotations

import hashlib
import os
import re
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from cab_core.contracts.scene import Mesh, Shape, cache_dir


def trimesh_module() -> Any:
    """``trimesh``, imported on first use: only building a scene's assets needs it, and importing it
    costs start-up time every other command would pay."""
    import trimesh

    return trimesh


def assets_dir() -> Path:
    """``<cache>/assets``, created if missing."""
    p = cache_dir() / "assets"
    p.mkdir(parents=True, exist_ok=True)
    return p


def write_asset(stem: str, data: bytes, suffix: str) -> Path:
    """Store ``data`` as ``<cache>/assets/<stem>-<sha256[:12]><suffix>``: content-addressed (the same
    content always gets the same name) and written atomically (temp file + rename), so concurrent
    builders never see a partial file."""
    digest = hashlib.sha256(data).hexdigest()[:12]
    path = assets_dir() / f"{stem}-{digest}{suffix}"
    if path.is_file() and path.stat().st_size == len(data):
        return path
    fd, tmp = tempfile.mkstemp(prefix=f".{stem}-", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def mesh_asset(stem: str, mesh: Any) -> str:
    """Write a ``trimesh.Trimesh`` as an OBJ asset; returns its path (for :class:`Mesh`)."""
    data = mesh.export(file_type="obj", include_normals=True).encode("utf-8")
    return str(write_asset(stem, data, ".obj"))


def mesh_shape(stem: str, mesh: Any, *, convex: bool = True, **shape_kw: Any) -> Shape:
    """A :class:`Shape` of the mesh ``mesh`` (written by :func:`mesh_asset`)."""
    return Shape(Mesh(mesh_asset(stem, mesh), convex=convex), **shape_kw)


def urdf_asset(stem: str, text: str) -> str:
    """Write a URDF (which refers to other assets by bare file name, in the same folder)."""
    return str(write_asset(stem, text.encode("utf-8"), ".urdf"))


# --- URDF text helpers --------------------------------------------------------------------------
def _f(v: Iterable[float]) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def urdf_geometry(kind: str, dims: Sequence[float]) -> str:
    """A URDF ``<box>`` (full sizes), ``<cylinder>`` (radius, length; along the link's z) or
    ``<sphere>`` (radius) element."""
    if kind == "box":
        return f'<box size="{_f(dims)}"/>'
    if kind == "cylinder":  # URDF cylinders lie along the link's z axis
        return f'<cylinder radius="{float(dims[0]):.6g}" length="{float(dims[1]):.6g}"/>'
    if kind == "sphere":
        return f'<sphere radius="{float(dims[0]):.6g}"/>'
    raise ValueError(kind)


def urdf_part(kind: str, dims: Sequence[float], xyz: Sequence[float], *, rgba: Sequence[float],
              rpy: Sequence[float] = (0.0, 0.0, 0.0), material: str, collision: bool = True,
              visual: bool = True) -> str:
    """One primitive of a link, as visual and/or collision elements."""
    origin = f'<origin xyz="{_f(xyz)}" rpy="{_f(rpy)}"/>'
    geom = f"<geometry>{urdf_geometry(kind, dims)}</geometry>"
    out = []
    if visual:
        out.append(f'<visual>{origin}{geom}<material name="{material}"><color rgba="{_f(rgba)}"/>'
                   f"</material></visual>")
    if collision:
        out.append(f"<collision>{origin}{geom}</collision>")
    return "\n    ".join(out)


def urdf_inertial(mass: float, com: Sequence[float], diag: Sequence[float]) -> str:
    """A URDF ``<inertial>`` element: the mass, the centre of mass and a diagonal inertia (each
    at least 1e-7 kg m^2)."""
    ixx, iyy, izz = (max(float(v), 1e-7) for v in diag)
    return (f'<inertial><origin xyz="{_f(com)}" rpy="0 0 0"/><mass value="{mass:.6g}"/>'
            f'<inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{izz:.6g}"/></inertial>')


def hinged_urdf(robot: str, *, base_inertial: str, base_parts: Sequence[str], child: str, child_inertial: str,
                child_parts: Sequence[str], joint: str, origin: Sequence[float], axis: str, upper: float,
                velocity: float, damping: float, friction: float) -> str:
    """A two-link URDF: a ``base`` link and a ``child`` link on one revolute ``joint`` (lower limit 0)."""
    nl = "\n    "
    ox, oy, oz = origin
    _one_colour_per_material(robot, [*base_parts, *child_parts])
    return f"""<?xml version="1.0"?>
<robot name="{robot}">
  <link name="base">
    {base_inertial}
    {nl.join(base_parts)}
  </link>
  <link name="{child}">
    {child_inertial}
    {nl.join(child_parts)}
  </link>
  <joint name="{joint}" type="revolute">
    <parent link="base"/>
    <child link="{child}"/>
    <origin xyz="{ox:.6g} {oy:.6g} {oz:.6g}" rpy="0 0 0"/>
    <axis xyz="{axis}"/>
    <limit lower="0" upper="{upper}" effort="100" velocity="{velocity}"/>
    <dynamics damping="{damping}" friction="{friction}"/>
  </joint>
</robot>
"""


def _one_colour_per_material(robot: str, parts: Sequence[str]) -> None:
    """A URDF material name is global to the robot: simulators keep the first or the last colour
    given under a name, so two colours under one name would render differently per simulator."""
    seen: dict[str, str] = {}
    for name, rgba in re.findall(r'<material name="([^"]+)"><color rgba="([^"]+)"/>', "".join(parts)):
        if seen.setdefault(name, rgba) != rgba:
            raise ValueError(f"{robot}: material {name!r} is given two colours ({seen[name]} and {rgba}); "
                             "name each colour's material apart")


def box_inertia(mass: float, size: Sequence[float]) -> tuple[float, float, float]:
    """The diagonal inertia (kg m^2) of a solid box of full sizes ``size`` about its centre."""
    x, y, z = size
    return (mass * (y * y + z * z) / 12, mass * (x * x + z * z) / 12, mass * (x * x + y * y) / 12)
