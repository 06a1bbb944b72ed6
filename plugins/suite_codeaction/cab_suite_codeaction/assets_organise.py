"""Generated assets of the "organise" tasks: thin-walled vessels of revolution (the bowls of
stack_bowls_three, the mug of hanging_mug) with collision shapes a gripper can pinch and that nest.

A vessel's frame: origin at the centre of its bottom (it stands on a table at origin z = table top),
+z along the axis. Visuals are smooth meshes of revolution; collisions are convex pieces (PhysX
dynamic bodies collide as convex shapes only): the wall as ``segments`` identical wedges of the
conical shell (one OBJ, rotated about z), the bottom as a flat cylinder, so the inside stays open
and one vessel can sit inside another.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cab_core.contracts.scene import Capsule, Cylinder, Material, Mesh, Shape
from cab_core.geometry import axis_angle_quat, quat_to_mat
from cab_core.kits.assets import mesh_asset


@dataclass(frozen=True)
class Vessel:
    """An open vessel of revolution: a (possibly conical) wall and a flat bottom."""
    r_bottom: float  # outer radius at the bottom edge
    r_rim: float  # outer radius at the rim
    height: float  # bottom to rim top
    wall: float  # wall thickness, normal to the wall
    base: float  # bottom thickness
    band: float = 0.0  # height of an upright (cylindrical) band at the top of the wall
    segments: int = 24  # wall wedges in the collision shape

    @property
    def knee(self) -> float:
        """Height where the conical wall meets the upright band."""
        return self.height - self.band

    @property
    def slope(self) -> float:
        """dr/dz of the conical wall (0 for a cylinder)."""
        return (self.r_rim - self.r_bottom) / self.knee

    @property
    def wall_horizontal(self) -> float:
        """The conical wall's thickness measured horizontally."""
        return self.wall * float(np.sqrt(1.0 + self.slope ** 2))

    def r_outer(self, z: float) -> float:
        return self.r_bottom + self.slope * min(z, self.knee)

    def r_inner(self, z: float) -> float:
        cone = self.r_bottom + self.slope * z - self.wall_horizontal
        return min(cone, self.r_rim - self.wall) if self.band > 0 else cone

    @property
    def inner_knee(self) -> float:
        """Height where the inner surface of the cone meets the band's (a little above the outer
        knee: the cone's wall is thicker measured horizontally)."""
        return self.knee + (self.wall_horizontal - self.wall) / self.slope if self.band > 0 else self.knee

    @property
    def rim_mid_radius(self) -> float:
        """Radius of the middle of the wall at the rim: where a pinch of the rim centres."""
        return self.r_rim - 0.5 * (self.wall if self.band > 0 else self.wall_horizontal)

    @property
    def nest_rise(self) -> float:
        """How much higher an identical vessel sits when nested in this one: its outer wall meets
        this one's inner wall (an upright band adds its height), or its bottom meets this one's
        floor, whichever comes first."""
        if self.slope <= 1e-9:
            return float("inf")
        if self.band > 0:  # the upper cone clears the lower band's inside: d >= band + wall / slope
            return max(self.base, self.wall_horizontal / self.slope, self.band + self.wall / self.slope)
        return max(self.base, self.wall_horizontal / self.slope)

    def profile(self, rim_round: int = 6) -> np.ndarray:
        """The closed cross-section (r, z) from the bottom centre, outward, up the outer wall, over
        a rounded rim, down the inner wall, to the floor's centre."""
        th = self.wall if self.band > 0 else self.wall_horizontal
        pts = [(0.0, 0.0), (self.r_bottom - 0.002, 0.0), (self.r_bottom, 0.002)]
        top = self.height - th / 2
        if self.band > 0:
            pts.append((self.r_rim, self.knee))
        pts.append((self.r_outer(top), top))
        c = (self.r_rim - th / 2, top)  # rim: a half circle over the wall's top
        for a in np.linspace(0.0, np.pi, rim_round + 2)[1:-1]:
            pts.append((c[0] + th / 2 * np.cos(a), c[1] + th / 2 * np.sin(a)))
        pts.append((self.r_inner(top), top))
        if self.band > 0:
            pts.append((self.r_inner(self.inner_knee), self.inner_knee))
        floor = self.base
        pts.append((self.r_inner(floor) - 0.003, floor + 0.002))
        pts.append((self.r_inner(floor) - 0.006, floor))
        pts.append((0.0, floor))
        return np.asarray(pts, float)


def revolved(profile: np.ndarray, sections: int = 64):
    """A mesh of revolution about z from an (r, z) profile that starts and ends on the axis."""
    import trimesh

    m = trimesh.creation.revolve(np.asarray(profile, float), sections=sections)
    m.merge_vertices()
    m.fix_normals()
    return m


def ring_band(r_of_z, z0: float, z1: float, proud: float = 0.0006, sections: int = 64):
    """A thin visual band on a surface of revolution r(z) between heights z0 and z1 (a glaze
    stripe), standing ``proud`` outside it."""
    zs = np.linspace(z0, z1, 4)
    outer = [(r_of_z(z) + proud, z) for z in zs]
    inner = [(r_of_z(z) - 0.0005, z) for z in zs[::-1]]
    prof = np.asarray(outer + inner + [outer[0]], float)
    import trimesh

    return trimesh.creation.revolve(prof, sections=sections)


def wedge_hull(v: Vessel, z0: float, z1: float):
    """The wall between heights z0 and z1 over the angle [-pi/n, pi/n] as a convex hull (8 points:
    inner and outer surface, bottom and top, both edges): its corners lie on the round surfaces,
    its flat faces at most r (1 - cos(pi/n)) inside them."""
    import trimesh

    half = np.pi / v.segments
    pts = []
    for z in (z0, z1):
        for r in (v.r_inner(z), v.r_outer(z)):
            for a in (-half, half):
                pts.append((r * np.cos(a), r * np.sin(a), z))
    return trimesh.convex.convex_hull(np.asarray(pts, float))


def vessel_collision(stem: str, v: Vessel, material: Material, wall_from: float | None = None,
                     wall_to: float | None = None) -> list[Shape]:
    """Collision shapes of a vessel (no visuals): the bottom disc and ``segments`` wall wedges
    from ``wall_from`` (default: just above the bottom's lower edge) to the rim."""
    z0 = 0.001 if wall_from is None else wall_from
    z1 = v.height if wall_to is None else wall_to
    pieces = [(z0, min(z1, v.knee))] + ([(v.knee, z1)] if z1 > v.knee else [])
    paths = [mesh_asset(f"{stem}-wedge{i}", wedge_hull(v, a, b)) for i, (a, b) in enumerate(pieces)]
    r_disc = v.r_inner(v.base) + 0.5 * v.wall_horizontal  # under the wall's middle at the floor
    up = tuple(float(c) for c in axis_angle_quat([0.0, 1.0, 0.0], -np.pi / 2))  # cylinder axis x -> z
    shapes = [Shape(Cylinder(min(r_disc, v.r_bottom), v.base / 2), pose=(0.0, 0.0, v.base / 2, *up),
                    material=material, visual=False)]
    for i in range(v.segments):
        q = axis_angle_quat([0.0, 0.0, 1.0], 2 * np.pi * i / v.segments)
        for path in paths:
            shapes.append(Shape(Mesh(path, convex=True), pose=(0.0, 0.0, 0.0, *(float(c) for c in q)),
                                material=material, visual=False))
    return shapes


def visual(stem: str, mesh, material: Material, pose=(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)) -> Shape:
    return Shape(Mesh(mesh_asset(stem, mesh), convex=False), pose=tuple(float(c) for c in pose),
                 material=material, collision=False)


def x_to(direction) -> tuple[float, float, float, float]:
    """The quaternion turning local +x onto ``direction`` (capsules and cylinders lie along x)."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    k = np.cross([1.0, 0.0, 0.0], d)
    s = float(np.linalg.norm(k))
    if s < 1e-9:
        return (1.0, 0.0, 0.0, 0.0) if d[0] > 0 else (0.0, 0.0, 0.0, 1.0)
    q = axis_angle_quat(k / s, float(np.arctan2(s, d[0])))
    return tuple(float(c) for c in q)


def rod(p0, p1, radius: float, material: Material, *, capsule: bool = True, **kw) -> Shape:
    """A round bar from ``p0`` to ``p1`` (capsule: rounded ends, reaching ``radius`` beyond them;
    cylinder: flat ends at the points)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    half = float(np.linalg.norm(p1 - p0)) / 2
    geom = Capsule(radius, half) if capsule else Cylinder(radius, half)
    return Shape(geom, pose=(*(float(c) for c in (p0 + p1) / 2), *x_to(p1 - p0)), material=material, **kw)


def tilt_correction(axis) -> np.ndarray:
    """The rotation (3x3) that turns the direction ``axis`` to world +z about a horizontal axis."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.cross(a, [0.0, 0.0, 1.0])
    s = float(np.linalg.norm(k))
    if s < 1e-9:
        return np.eye(3)
    return quat_to_mat(axis_angle_quat(k / s, float(np.arctan2(s, a[2]))))
