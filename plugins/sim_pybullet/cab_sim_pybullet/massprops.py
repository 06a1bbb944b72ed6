"""Mass properties of a rigid body from its collision shapes and density.

PyBullet derives a compound body's inertia from the bounding box of its shapes, which overstates
it for anything but a box. SAPIEN (PhysX) integrates each shape exactly; doing the same here keeps
the masses and inertias of the two backends equal for the same scene: primitives in closed form,
convex meshes by integrating over the tetrahedra of their convex hull.

Everything is in the body frame; :func:`combine` returns the mass, the centre of mass and the 3x3
inertia tensor about it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from cab_core.contracts.scene import Box, Capsule, Cylinder, Geometry, Mesh, Sphere
from cab_core.geometry import quat_to_mat


@dataclass(frozen=True)
class MassProps:
    """Mass (kg), centre of mass (m) and inertia tensor about it (kg m^2), in one frame."""
    mass: float
    com: np.ndarray
    inertia: np.ndarray


def read_obj_vertices(path: str, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The scaled vertices of an OBJ file (``v`` lines only)."""
    rows = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith("v "):
                rows.append([float(v) for v in line.split()[1:4]])
    if len(rows) < 4:
        raise ValueError(f"{path}: a mesh needs at least 4 vertices, found {len(rows)}")
    return np.asarray(rows, dtype=float) * np.asarray(scale, dtype=float)


def _hull_unit_density(vertices: np.ndarray) -> MassProps:
    """Volume, centroid and inertia (density 1) of the convex hull of ``vertices``."""
    hull = ConvexHull(vertices)
    ref = vertices[hull.vertices].mean(axis=0)
    volume = 0.0
    first = np.zeros(3)
    second = np.zeros((3, 3))  # integral of r r^T over the solid, about ``ref``
    for simplex in hull.simplices:
        a, b, c = (vertices[i] - ref for i in simplex)
        v = abs(np.dot(a, np.cross(b, c))) / 6.0
        volume += v
        first += v * (a + b + c) / 4.0
        s = a + b + c
        second += v / 20.0 * (np.outer(a, a) + np.outer(b, b) + np.outer(c, c) + np.outer(s, s))
    com_rel = first / volume
    second_com = second - volume * np.outer(com_rel, com_rel)
    inertia = np.trace(second_com) * np.eye(3) - second_com
    return MassProps(volume, ref + com_rel, inertia)


def shape_props(geometry: Geometry, density: float) -> MassProps:
    """Mass properties of one shape in its own frame (capsule and cylinder axes along x)."""
    g = geometry
    if isinstance(g, Box):
        hx, hy, hz = g.half_size
        m = density * 8.0 * hx * hy * hz
        inertia = np.diag([hy * hy + hz * hz, hx * hx + hz * hz, hx * hx + hy * hy]) * m / 3.0
        return MassProps(m, np.zeros(3), inertia)
    if isinstance(g, Sphere):
        m = density * 4.0 / 3.0 * math.pi * g.radius ** 3
        return MassProps(m, np.zeros(3), np.eye(3) * 0.4 * m * g.radius ** 2)
    if isinstance(g, Cylinder):
        r, h = g.radius, g.half_length
        m = density * math.pi * r * r * 2.0 * h
        across = m * (3.0 * r * r + 4.0 * h * h) / 12.0
        return MassProps(m, np.zeros(3), np.diag([0.5 * m * r * r, across, across]))
    if isinstance(g, Capsule):
        r, h = g.radius, g.half_length
        mc = density * math.pi * r * r * 2.0 * h  # the cylinder
        ms = density * 4.0 / 3.0 * math.pi * r ** 3  # the two half spheres together
        axial = 0.5 * mc * r * r + 0.4 * ms * r * r
        # each half sphere: 83/320 m r^2 about its centroid, which sits 3r/8 beyond the cylinder end
        across = (mc * (3.0 * r * r + 4.0 * h * h) / 12.0
                  + ms * (0.4 * r * r + h * h + 0.75 * h * r))
        return MassProps(mc + ms, np.zeros(3), np.diag([axial, across, across]))
    if isinstance(g, Mesh):
        unit = _hull_unit_density(read_obj_vertices(g.path, g.scale))
        return MassProps(unit.mass * density, unit.com, unit.inertia * density)
    raise TypeError(f"unsupported geometry {type(g).__name__}")


def transformed(p: MassProps, pose) -> MassProps:
    """``p`` expressed in the parent frame where its own frame sits at ``pose`` (7-vector, wxyz)."""
    R = quat_to_mat(pose[3:7])
    return MassProps(p.mass, R @ p.com + np.asarray(pose[:3], float), R @ p.inertia @ R.T)


def combine(parts: list[MassProps]) -> MassProps:
    """Total mass, centre of mass and inertia about it (parallel-axis theorem)."""
    m = sum(p.mass for p in parts)
    if m <= 0:
        raise ValueError("a body needs a positive mass")
    com = sum(p.mass * p.com for p in parts) / m
    inertia = np.zeros((3, 3))
    for p in parts:
        d = p.com - com
        inertia += p.inertia + p.mass * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
    return MassProps(m, com, inertia)


def principal(p: MassProps) -> tuple[np.ndarray, np.ndarray]:
    """(principal moments, rotation whose columns are the principal axes, right-handed)."""
    moments, axes = np.linalg.eigh(0.5 * (p.inertia + p.inertia.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return np.maximum(moments, 1e-9), axes
