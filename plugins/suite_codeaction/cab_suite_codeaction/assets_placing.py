"""Generated assets of the placing tasks (place_bread_basket, place_bread_skillet,
place_cans_plasticbox, place_object_basket): bread, a wicker bread basket, a skillet, drink cans, a
plastic storage box, a handled shopping basket, a toy car and a pack of playing cards.

Every object is one rigid body of primitives and convex meshes (a container's walls are separate
boxes, so it stays hollow while dynamic). Each builder returns the shapes plus the dimensions a task
puts into ``info``; body frames are documented per builder. Sizes are real-world ones chosen to fit
the 9.2 cm pad clearance of the open gripper where an object is to be grasped.
"""
from __future__ import annotations

import copy
import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cab_core.contracts.scene import Box, Capsule, Cylinder, Material, Mesh, Shape, cache_dir
from cab_core.geometry import axis_angle_quat, mat_to_quat, quat_mul
from cab_core.kits.assets import mesh_asset, trimesh_module
from cab_core.kits.scene import body_pose, material

_BUILT: dict[tuple, tuple[list[Shape], dict[str, Any]]] = {}


def _memo(fn: Callable[[int], tuple[list[Shape], dict[str, Any]]]):
    """Build a model's shapes once per process and cache folder (its mesh files still there):
    scene builds then cost only their random draws."""
    @functools.wraps(fn)
    def wrapper(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
        key = (fn.__name__, int(model_id), str(cache_dir()))
        hit = _BUILT.get(key)
        if hit is None or not all(os.path.isfile(s.geometry.path) for s in hit[0] if isinstance(s.geometry, Mesh)):
            hit = _BUILT[key] = fn(model_id)
        return list(hit[0]), copy.deepcopy(hit[1])

    return wrapper


_mat = functools.partial(material, roughness=0.6)  # this module's default finish


def _rz(theta: float) -> tuple[float, ...]:
    return tuple(float(v) for v in axis_angle_quat([0.0, 0.0, 1.0], theta))


def _ry(theta: float) -> tuple[float, ...]:
    return tuple(float(v) for v in axis_angle_quat([0.0, 1.0, 0.0], theta))


# --- mesh helpers -------------------------------------------------------------------------------
def prism_mesh(outline: np.ndarray, z0: float, z1: float):
    """The convex prism over a convex 2-D outline (N x 2), from z0 to z1."""
    tm = trimesh_module()
    pts = np.concatenate([np.c_[outline, np.full(len(outline), z0)], np.c_[outline, np.full(len(outline), z1)]])
    return tm.convex.convex_hull(pts)


def ellipse(a: float, b: float, n: int) -> np.ndarray:
    """n points (CCW) on the ellipse with semi-axes a (x) and b (y)."""
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.c_[a * np.cos(t), b * np.sin(t)]


def rounded_rect(a: float, b: float, r: float, n_corner: int = 4) -> np.ndarray:
    """CCW outline of a rectangle with half-sizes a, b and corner radius r."""
    pts = []
    for cx, cy, t0 in ((a - r, b - r, 0.0), (-a + r, b - r, 0.5 * np.pi), (-a + r, -b + r, np.pi),
                       (a - r, -b + r, 1.5 * np.pi)):
        for t in np.linspace(t0, t0 + 0.5 * np.pi, n_corner + 1):
            pts.append((cx + r * np.cos(t), cy + r * np.sin(t)))
    out = [pts[0]]
    for p in pts[1:]:
        if np.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) > 1e-6:
            out.append(p)
    if np.hypot(out[0][0] - out[-1][0], out[0][1] - out[-1][1]) < 1e-6:
        out.pop()
    return np.asarray(out, float)


def offset_outline(outline: np.ndarray, d: float) -> np.ndarray:
    """A closed CCW outline moved outward by ``d`` (mitred vertices)."""
    n = len(outline)
    out = np.empty_like(outline)
    for i in range(n):
        e1 = outline[i] - outline[i - 1]
        e2 = outline[(i + 1) % n] - outline[i]
        n1 = np.array([e1[1], -e1[0]]) / np.hypot(*e1)
        n2 = np.array([e2[1], -e2[0]]) / np.hypot(*e2)
        m = n1 + n2
        m /= np.linalg.norm(m)
        out[i] = outline[i] + m * d / max(float(np.dot(m, n1)), 0.2)
    return out


def shell_mesh(outline: np.ndarray, *, z0: float, z1: float, thickness: float, flare: float):
    """Visual mesh of a band (z0..z1) of a flared container wall whose inner bottom edge is
    ``outline`` at z = 0: inner and outer faces plus top and bottom caps."""
    tm = trimesh_module()
    t = np.tan(flare)
    rings = [offset_outline(outline, z0 * t), offset_outline(outline, z0 * t + thickness),
             offset_outline(outline, z1 * t + thickness), offset_outline(outline, z1 * t)]
    zs = [z0, z0, z1, z1]
    n = len(outline)
    verts = np.concatenate([np.c_[r, np.full(n, z)] for r, z in zip(rings, zs)])
    faces = []
    for k in range(4):  # inner-bottom -> outer-bottom -> outer-top -> inner-top -> inner-bottom
        a, b = k * n, ((k + 1) % 4) * n
        for i in range(n):
            j = (i + 1) % n
            faces += [[a + i, a + j, b + j], [a + i, b + j, b + i]]
    m = tm.Trimesh(verts, np.asarray(faces), process=True)
    m.fix_normals()
    return m


def wall_shapes(outline: np.ndarray, *, z0: float, height: float, thickness: float, flare: float,
                material: Material, overlap: float = 0.004) -> list[Shape]:
    """Invisible collision boxes along a closed CCW outline (the wall's inner bottom edge), each
    tilted outward by ``flare`` rad."""
    shapes = []
    n = len(outline)
    for i in range(n):
        p0, p1 = outline[i], outline[(i + 1) % n]
        d = p1 - p0
        length = float(np.hypot(*d))
        t = np.array([d[0], d[1], 0.0]) / length
        nrm = np.array([t[1], -t[0], 0.0])  # outward for a CCW outline
        up = np.array([0.0, 0.0, 1.0])
        r0 = np.stack([-t, nrm, up], axis=1)  # right-handed: (-t) x nrm = up
        c, s = np.cos(-flare), np.sin(-flare)
        rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        r = r0 @ rx
        # the outer bottom edge would dip below z0 by thickness * sin(flare): lift the segment
        mid = np.array([(p0[0] + p1[0]) / 2, (p0[1] + p1[1]) / 2, z0 + thickness * np.sin(abs(flare))])
        centre = mid + r @ np.array([0.0, thickness / 2, height / 2])
        half_len = length / 2 + overlap
        shapes.append(Shape(Box((float(half_len), thickness / 2, height / 2)), pose=body_pose(centre, mat_to_quat(r)),
                            material=material, visual=False))
    return shapes


def container_shapes(stem: str, outline: np.ndarray, *, height: float, wall: float, floor: float, flare: float,
                     wall_mats: Sequence[Material], floor_mat: Material, bands: int = 1,
                     rim_mat: Material | None = None, rim_height: float = 0.0) -> list[Shape]:
    """An open container standing on z = 0: a convex floor slab (0..floor) under the outline
    widened by the wall, flared walls from z = 0 to ``height`` (collision boxes; visual shell in
    ``bands`` horizontal bands of alternating materials) and an optional visual rim band."""
    shapes = [Shape(Mesh(mesh_asset(f"{stem}_floor", prism_mesh(offset_outline(outline, wall), 0.0, floor)),
                         convex=True), material=floor_mat)]
    shapes += wall_shapes(outline, z0=0.0, height=height, thickness=wall, flare=flare, material=wall_mats[0])
    edges = np.linspace(0.0, height, bands + 1)
    for k in range(bands):
        m = shell_mesh(outline, z0=float(edges[k]), z1=float(edges[k + 1]), thickness=wall, flare=flare)
        shapes.append(Shape(Mesh(mesh_asset(f"{stem}_band{k}", m), convex=False),
                            material=wall_mats[k % len(wall_mats)], collision=False))
    if rim_mat is not None and rim_height > 0:
        m = shell_mesh(offset_outline(outline, -0.001), z0=height - rim_height, z1=height + 0.002,
                       thickness=wall + 0.003, flare=flare)
        shapes.append(Shape(Mesh(mesh_asset(f"{stem}_rim", m), convex=False), material=rim_mat, collision=False))
    return shapes


# =================================================================================================
# bread
# =================================================================================================
@dataclass(frozen=True)
class BreadVariant:
    kind: str
    length: float  # x
    width: float  # y (the grasp is across it)
    height: float  # z
    crust: tuple[float, float, float]
    score: tuple[float, float, float]  # colour of the slashes on top
    slashes: int
    squareness: float  # p-norm of the horizontal section (2: ellipse, larger: boxier)


#: upstream's bread model ids {0, 1, 3, 5, 6}
BREADS: dict[int, BreadVariant] = {
    0: BreadVariant("bread roll", 0.110, 0.068, 0.052, (0.80, 0.55, 0.26), (0.93, 0.80, 0.55), 1, 2.2),
    1: BreadVariant("small tin loaf", 0.120, 0.070, 0.060, (0.72, 0.46, 0.20), (0.90, 0.74, 0.48), 0, 4.0),
    3: BreadVariant("round bun", 0.085, 0.080, 0.050, (0.83, 0.58, 0.28), (0.95, 0.85, 0.62), 2, 2.0),
    5: BreadVariant("baguette piece", 0.130, 0.058, 0.048, (0.86, 0.62, 0.30), (0.96, 0.86, 0.62), 3, 2.4),
    6: BreadVariant("rye loaf", 0.115, 0.072, 0.058, (0.45, 0.28, 0.14), (0.66, 0.52, 0.36), 3, 3.0),
}
BREAD_MASS = 0.06  # kg: a bread roll
BREAD_FRICTION = 0.8  # dry crust against the rubber finger pads


def loaf_mesh(v: BreadVariant, subdivisions: int = 3):
    """A domed loaf with a flat bottom, centred on its bounding box: x length, y width, z up."""
    tm = trimesh_module()
    s = tm.creation.icosphere(subdivisions=subdivisions)
    d = s.vertices.copy()
    p = v.squareness
    horiz = (np.abs(d[:, 0]) ** p + np.abs(d[:, 1]) ** p) ** (1.0 / p)
    rho = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2)
    scale = np.where(rho > 1e-9, rho / np.maximum(horiz, 1e-9), 1.0)
    x = d[:, 0] * scale * v.length / 2
    y = d[:, 1] * scale * v.width / 2
    z_top = 0.72 * v.height
    z_bot = 0.28 * v.height
    z = np.where(d[:, 2] >= 0, d[:, 2] * z_top, np.maximum(d[:, 2] * z_bot * 1.6, -z_bot))
    verts = np.c_[x, y, z - (z_top - z_bot) / 2]
    return tm.Trimesh(verts, s.faces, process=True)


@_memo
def bread_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Bread ``model_id``: body frame at the centre of its bounding box, x along its length,
    z up. Collision: the loaf's convex hull (the loaf is convex). Visual: the loaf and its
    slashes."""
    v = BREADS[model_id]
    crust = _mat(v.crust, friction=BREAD_FRICTION, roughness=0.8)
    mesh = loaf_mesh(v)
    shapes = [Shape(Mesh(mesh_asset(f"bread{model_id}", mesh), convex=True), material=crust)]
    verts = np.asarray(mesh.vertices)
    if v.slashes:
        tm = trimesh_module()
        cut = tm.creation.icosphere(subdivisions=2)
        cut.apply_scale([0.0055, 0.24 * v.width, 0.0035])
        cut_path = mesh_asset("bread_slash", cut)
    for k in range(v.slashes):
        fx = (k - (v.slashes - 1) / 2) * v.length / (v.slashes + 1.2)
        near = verts[np.abs(verts[:, 0] - fx) < 0.006]
        near = near[np.abs(near[:, 1]) < 0.006]
        zz = float(near[:, 2].max()) - 0.0012 if len(near) else v.height / 2 - 0.003
        shapes.append(Shape(Mesh(cut_path, convex=True), pose=body_pose((fx, 0.0, zz), _rz(0.45)),
                            material=_mat(v.score, roughness=0.9), collision=False))
    dims = {"model_id": model_id, "kind": v.kind, "size": [v.length, v.width, v.height], "mass_kg": BREAD_MASS}
    return shapes, dims


# =================================================================================================
# bread basket (wicker)
# =================================================================================================
@dataclass(frozen=True)
class BreadBasketVariant:
    shape: str  # "oval" | "rect"
    half_x: float  # inner half-sizes at the floor
    half_y: float
    height: float  # wall height above the floor's top
    wicker: tuple[float, float, float]
    wicker_alt: tuple[float, float, float]
    rim: tuple[float, float, float]


#: upstream's bread basket model ids 0-4
BREAD_BASKETS: dict[int, BreadBasketVariant] = {
    0: BreadBasketVariant("oval", 0.140, 0.100, 0.060, (0.78, 0.60, 0.36), (0.68, 0.50, 0.29), (0.55, 0.38, 0.20)),
    1: BreadBasketVariant("oval", 0.145, 0.105, 0.065, (0.56, 0.38, 0.22), (0.47, 0.31, 0.17), (0.36, 0.23, 0.12)),
    2: BreadBasketVariant("rect", 0.135, 0.100, 0.055, (0.84, 0.70, 0.47), (0.74, 0.60, 0.39), (0.60, 0.46, 0.28)),
    3: BreadBasketVariant("oval", 0.150, 0.105, 0.055, (0.70, 0.45, 0.28), (0.60, 0.37, 0.22), (0.45, 0.27, 0.15)),
    4: BreadBasketVariant("rect", 0.140, 0.105, 0.065, (0.62, 0.50, 0.34), (0.53, 0.42, 0.27), (0.40, 0.30, 0.18)),
}
BREAD_BASKET_MASS = 0.35  # kg
BASKET_WALL = 0.008
BASKET_FLOOR = 0.008
BASKET_FLARE = 0.18  # rad: the walls lean outward


@_memo
def bread_basket_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Bread basket ``model_id``: body frame at the centre of its bottom face (on the table), x
    along its long axis, z up. Collision: a convex floor slab and flared wall segments."""
    v = BREAD_BASKETS[model_id]
    if v.shape == "oval":
        outline = ellipse(v.half_x, v.half_y, 32)
    else:
        outline = rounded_rect(v.half_x, v.half_y, 0.035, 4)
    h = v.height + BASKET_FLOOR
    shapes = container_shapes(f"breadbasket{model_id}", outline, height=h, wall=BASKET_WALL, floor=BASKET_FLOOR,
                              flare=BASKET_FLARE, wall_mats=[_mat(v.wicker, roughness=0.9),
                                                             _mat(v.wicker_alt, roughness=0.9)],
                              floor_mat=_mat(v.wicker_alt, roughness=0.9), bands=7,
                              rim_mat=_mat(v.rim, roughness=0.9), rim_height=0.012)
    top_shift = h * np.tan(BASKET_FLARE)
    dims = {
        "model_id": model_id, "shape": v.shape,
        "inner_half_size": [v.half_x, v.half_y],  # at the floor
        "floor_top_z": BASKET_FLOOR,  # in the body frame
        "rim_z": round(h, 6),
        "outer_half_size": [round(v.half_x + BASKET_WALL + top_shift + 0.002, 6),
                            round(v.half_y + BASKET_WALL + top_shift + 0.002, 6)],
        "mass_kg": BREAD_BASKET_MASS,
    }
    return shapes, dims


# =================================================================================================
# skillet
# =================================================================================================
@dataclass(frozen=True)
class SkilletVariant:
    kind: str
    floor_radius: float  # inner floor
    top_radius: float  # inner rim
    height: float  # rim above the table
    handle_length: float
    body: tuple[float, float, float]  # outside
    inside: tuple[float, float, float]
    handle: tuple[float, float, float]
    metallic: float


#: upstream's skillet model ids 0-3
SKILLETS: dict[int, SkilletVariant] = {
    0: SkilletVariant("black non-stick frying pan", 0.085, 0.105, 0.045, 0.15, (0.10, 0.10, 0.11), (0.20, 0.20, 0.22),
                      (0.06, 0.06, 0.06), 0.3),
    1: SkilletVariant("cast-iron skillet", 0.080, 0.098, 0.042, 0.14, (0.16, 0.16, 0.17), (0.24, 0.24, 0.25),
                      (0.16, 0.16, 0.17), 0.5),
    2: SkilletVariant("red frying pan", 0.088, 0.108, 0.045, 0.15, (0.72, 0.12, 0.10), (0.18, 0.18, 0.20),
                      (0.08, 0.08, 0.08), 0.2),
    3: SkilletVariant("steel pan with a wooden handle", 0.082, 0.100, 0.043, 0.145, (0.70, 0.71, 0.73),
                      (0.62, 0.63, 0.65), (0.55, 0.36, 0.20), 0.8),
}
SKILLET_MASS = 0.25  # kg: a light aluminium pan
SKILLET_FLOOR = 0.005
SKILLET_WALL = 0.004
HANDLE_PITCH = np.deg2rad(25.0)  # the handle rises from the rim
HANDLE_HALF = (0.011, 0.008)  # half width (y), half thickness (z, perpendicular to the handle)
HANDLE_FRICTION = 1.0  # silicone-coated handle


@_memo
def skillet_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Skillet ``model_id``: body frame at the centre of the pan's bottom face (on the table), +x
    along the handle (seen from above), z up. Collision: convex floor slab, flared wall segments
    and the handle as a box rising at 25 deg from the rim."""
    v = SKILLETS[model_id]
    flare = float(np.arctan2(v.top_radius - v.floor_radius, v.height))
    outline = ellipse(v.floor_radius, v.floor_radius, 28)
    body = _mat(v.body, roughness=0.4, metallic=v.metallic)
    inside = _mat(v.inside, roughness=0.5, metallic=v.metallic)
    shapes = container_shapes(f"skillet{model_id}", outline, height=v.height, wall=SKILLET_WALL, floor=SKILLET_FLOOR,
                              flare=flare, wall_mats=[body], floor_mat=inside, bands=1)
    # a visual disc for the inside of the floor
    shapes.append(Shape(Cylinder(v.floor_radius - 0.002, 0.0005),
                        pose=body_pose((0, 0, SKILLET_FLOOR + 0.0004), _ry(np.pi / 2)), material=inside,
                        collision=False))
    # handle: centre line from just inside the rim, rising at HANDLE_PITCH
    d = np.array([np.cos(HANDLE_PITCH), 0.0, np.sin(HANDLE_PITCH)])
    p0 = np.array([v.top_radius + SKILLET_WALL - 0.006, 0.0, v.height - 0.010])
    centre = p0 + d * v.handle_length / 2
    qh = _ry(-HANDLE_PITCH)  # local x -> d
    hmat = _mat(v.handle, friction=HANDLE_FRICTION, roughness=0.6)
    shapes.append(Shape(Box((v.handle_length / 2, *HANDLE_HALF)), pose=body_pose(centre, qh), material=hmat))
    # visual: rivet plate where the handle meets the pan, and a hanging hole at the end
    shapes.append(Shape(Box((0.012, 0.016, 0.012)), pose=body_pose(p0 + d * 0.006, qh), material=body, collision=False))
    end = p0 + d * v.handle_length
    shapes.append(Shape(Cylinder(0.0045, HANDLE_HALF[1] + 0.0004),
                        pose=body_pose(end - d * 0.018, quat_mul(qh, _ry(np.pi / 2))),
                        material=_mat((0.02, 0.02, 0.02)), collision=False))
    grasp_along = v.handle_length - 0.040  # the TCP 4 cm in from the handle's end
    grasp = p0 + d * grasp_along
    dims = {
        "model_id": model_id, "kind": v.kind,
        "floor_radius": v.floor_radius, "rim_radius": v.top_radius, "rim_height": v.height,
        "pan_point": [0.0, 0.0, SKILLET_FLOOR],  # functional point: centre of the inner floor
        "handle_start": [round(float(c), 6) for c in p0],
        "handle_axis": [round(float(c), 6) for c in d],
        "handle_length": v.handle_length,
        "handle_section": [2 * HANDLE_HALF[0], 2 * HANDLE_HALF[1]],
        "handle_grasp_point": [round(float(c), 6) for c in grasp],
        "mass_kg": SKILLET_MASS,
    }
    return shapes, dims


# =================================================================================================
# drink cans
# =================================================================================================
@dataclass(frozen=True)
class CanVariant:
    kind: str
    radius: float
    height: float
    label: tuple[float, float, float]
    band: tuple[float, float, float]  # a second label colour (a stripe)


#: upstream's can model ids {0, 1, 2, 3, 5, 6}
CANS: dict[int, CanVariant] = {
    0: CanVariant("red cola can (330 ml)", 0.033, 0.122, (0.80, 0.08, 0.08), (0.95, 0.95, 0.95)),
    1: CanVariant("slim blue energy-drink can (250 ml)", 0.027, 0.134, (0.10, 0.25, 0.75), (0.75, 0.78, 0.80)),
    2: CanVariant("green lemonade can (330 ml)", 0.033, 0.115, (0.15, 0.60, 0.20), (0.95, 0.90, 0.20)),
    3: CanVariant("silver beer can (500 ml)", 0.033, 0.168, (0.78, 0.79, 0.82), (0.10, 0.20, 0.55)),
    5: CanVariant("yellow food tin", 0.037, 0.105, (0.95, 0.80, 0.15), (0.75, 0.20, 0.10)),
    6: CanVariant("orange soda can (330 ml)", 0.033, 0.122, (0.95, 0.50, 0.08), (0.98, 0.98, 0.98)),
}
CAN_MASS = 0.10  # kg: a part-full can
ALUMINIUM = (0.80, 0.81, 0.83)


@_memo
def can_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Can ``model_id``: body frame at the can's centre, z along its axis (up when standing).
    Collision: one cylinder. Visual: label, stripe, aluminium top and bottom with a pull tab."""
    v = CANS[model_id]
    along_z = _ry(np.pi / 2)  # the cylinder's local x onto z
    h2 = v.height / 2
    label = _mat(v.label, roughness=0.35, metallic=0.3)
    metal = _mat(ALUMINIUM, roughness=0.25, metallic=0.9)
    shapes = [Shape(Cylinder(v.radius, h2), pose=body_pose((0, 0, 0), along_z), material=label, visual=False)]
    neck = 0.010
    shapes += [
        Shape(Cylinder(v.radius, h2 - neck), pose=body_pose((0, 0, 0), along_z), material=label, collision=False),
        Shape(Cylinder(v.radius + 0.0003, 0.010), pose=body_pose((0, 0, 0.18 * v.height), along_z),
              material=_mat(v.band, roughness=0.35), collision=False),
        Shape(Cylinder(v.radius - 0.0015, neck / 2), pose=body_pose((0, 0, h2 - neck / 2), along_z), material=metal,
              collision=False),
        Shape(Cylinder(v.radius - 0.0015, neck / 2), pose=body_pose((0, 0, -h2 + neck / 2), along_z), material=metal,
              collision=False),
        Shape(Cylinder(v.radius - 0.004, 0.0008), pose=body_pose((0, 0, h2 + 0.0002), along_z),
              material=_mat((0.62, 0.63, 0.66), roughness=0.3, metallic=0.9), collision=False),
    ]
    if "tin" not in v.kind:
        shapes.append(Shape(Box((0.009, 0.0055, 0.0008)), pose=body_pose((0.009, 0, h2 + 0.0012)), material=metal,
                            collision=False))
    dims = {"model_id": model_id, "kind": v.kind, "radius": v.radius, "height": v.height, "mass_kg": CAN_MASS}
    return shapes, dims


# =================================================================================================
# plastic storage box
# =================================================================================================
@dataclass(frozen=True)
class PlasticBoxVariant:
    half_x: float  # inner half-sizes at the floor
    half_y: float
    height: float
    color: tuple[float, float, float]
    rim: tuple[float, float, float]


#: upstream's plastic box model ids {3, 5}
PLASTIC_BOXES: dict[int, PlasticBoxVariant] = {
    3: PlasticBoxVariant(0.100, 0.074, 0.070, (0.45, 0.70, 0.90), (0.30, 0.55, 0.80)),
    5: PlasticBoxVariant(0.100, 0.072, 0.065, (0.60, 0.82, 0.62), (0.42, 0.66, 0.46)),
}
PLASTIC_BOX_MASS = 0.2  # kg
PLASTIC_WALL = 0.004
PLASTIC_FLOOR = 0.004
PLASTIC_FLARE = 0.04
CAN_SLOT_X = 0.05  # the box's functional points, either side of its centre


@_memo
def plastic_box_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Plastic box ``model_id``: body frame at the centre of its bottom face, x along its long side,
    z up. Functional points 0 and 1 at (-+0.05, 0) on the floor's top: one can each."""
    v = PLASTIC_BOXES[model_id]
    outline = rounded_rect(v.half_x, v.half_y, 0.02, 4)
    shapes = container_shapes(f"plasticbox{model_id}", outline, height=v.height, wall=PLASTIC_WALL,
                              floor=PLASTIC_FLOOR, flare=PLASTIC_FLARE,
                              wall_mats=[_mat(v.color, roughness=0.3)], floor_mat=_mat(v.rim, roughness=0.3),
                              bands=1, rim_mat=_mat(v.rim, roughness=0.3), rim_height=0.008)
    top_shift = v.height * np.tan(PLASTIC_FLARE)
    dims = {
        "model_id": model_id,
        "inner_half_size": [v.half_x, v.half_y],
        "outer_half_size": [round(v.half_x + PLASTIC_WALL + top_shift, 6),
                            round(v.half_y + PLASTIC_WALL + top_shift, 6)],
        "height": v.height,
        "floor_top_z": PLASTIC_FLOOR,
        "functional_points": [[-CAN_SLOT_X, 0.0, PLASTIC_FLOOR], [CAN_SLOT_X, 0.0, PLASTIC_FLOOR]],
        "mass_kg": PLASTIC_BOX_MASS,
    }
    return shapes, dims


# =================================================================================================
# handled basket (place_object_basket)
# =================================================================================================
@dataclass(frozen=True)
class HandledBasketVariant:
    kind: str
    body: tuple[float, float, float]
    body_alt: tuple[float, float, float]
    handle: tuple[float, float, float]
    bands: int


#: upstream's basket model ids {0, 1}
HANDLED_BASKETS: dict[int, HandledBasketVariant] = {
    0: HandledBasketVariant("wicker basket", (0.72, 0.54, 0.32), (0.62, 0.45, 0.26), (0.45, 0.30, 0.16), 8),
    1: HandledBasketVariant("red plastic shopping basket", (0.80, 0.12, 0.12), (0.70, 0.09, 0.09),
                            (0.12, 0.12, 0.13), 3),
}
HB_HALF = (0.120, 0.107)  # inner half-sizes at the floor (x: along the handle)
HB_HEIGHT = 0.080  # wall height
HB_WALL = 0.006
HB_FLOOR = 0.006
HB_FLARE = 0.08
HB_BAR_ABOVE_RIM = 0.090  # handle bar centre above the rim
HB_BAR_HALF = (0.008, 0.007)  # bar half-sections: y (across, the grasp), z
HB_MASS = 0.40  # kg
HB_HANDLE_FRICTION = 1.0  # a rubber-gripped handle


@_memo
def handled_basket_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Basket ``model_id`` with a fixed handle arching over it from end to end: body frame at the
    centre of its bottom face, x along its long side and the handle, z up. Collision: floor slab,
    flared walls, two handle posts on the end walls and the handle's top bar (a flat-sided bar,
    grasped from above across it)."""
    v = HANDLED_BASKETS[model_id]
    outline = rounded_rect(HB_HALF[0], HB_HALF[1], 0.03, 4)
    mats = [_mat(v.body, roughness=0.8), _mat(v.body_alt, roughness=0.8)]
    shapes = container_shapes(f"handledbasket{model_id}", outline, height=HB_HEIGHT, wall=HB_WALL, floor=HB_FLOOR,
                              flare=HB_FLARE, wall_mats=mats, floor_mat=mats[1], bands=v.bands,
                              rim_mat=_mat(v.handle, roughness=0.7), rim_height=0.010)
    hmat = _mat(v.handle, friction=HB_HANDLE_FRICTION, roughness=0.6)
    shift = HB_HEIGHT * np.tan(HB_FLARE)
    x_post = HB_HALF[0] + shift + HB_WALL / 2  # on top of the end walls
    bar_z = HB_HEIGHT + HB_BAR_ABOVE_RIM
    post_h = bar_z - HB_HEIGHT + HB_BAR_HALF[1] + 0.015  # from 1.5 cm down the wall to the bar's top
    for sx in (-1.0, 1.0):
        shapes.append(Shape(Box((0.007, 0.011, post_h / 2)),
                            pose=body_pose((sx * x_post, 0.0, bar_z + HB_BAR_HALF[1] - post_h / 2)), material=hmat))
    shapes.append(Shape(Box((x_post + 0.007, HB_BAR_HALF[0], HB_BAR_HALF[1])), pose=body_pose((0.0, 0.0, bar_z)),
                        material=hmat))
    # visual: a padded grip in the middle of the bar
    shapes.append(Shape(Capsule(HB_BAR_HALF[0] + 0.0015, 0.045), pose=body_pose((0.0, 0.0, bar_z)),
                        material=_mat((0.10, 0.10, 0.10), roughness=0.8), collision=False))
    dims = {
        "model_id": model_id, "kind": v.kind,
        "inner_half_size": list(HB_HALF),
        "outer_half_size": [round(HB_HALF[0] + HB_WALL + shift, 6), round(HB_HALF[1] + HB_WALL + shift, 6)],
        "rim_z": HB_HEIGHT,
        "floor_top_z": HB_FLOOR,
        "handle_bar_point": [0.0, 0.0, round(bar_z, 6)],  # grasp point: the middle of the bar
        "handle_bar_axis": [1.0, 0.0, 0.0],
        "handle_bar_section": [2 * HB_BAR_HALF[0], 2 * HB_BAR_HALF[1]],
        "handle_bar_half_length": round(x_post, 6),
        "mass_kg": HB_MASS,
    }
    return shapes, dims


# =================================================================================================
# toy car and playing cards (place_object_basket)
# =================================================================================================
@dataclass(frozen=True)
class ToyCarVariant:
    kind: str
    length: float
    width: float
    height: float  # overall, wheels to roof
    cabin: tuple[float, float]  # cabin length fraction, cabin height fraction
    color: tuple[float, float, float]


#: upstream's toy car model ids 0-5
TOY_CARS: dict[int, ToyCarVariant] = {
    0: ToyCarVariant("red toy sedan", 0.084, 0.040, 0.034, (0.50, 0.40), (0.85, 0.10, 0.10)),
    1: ToyCarVariant("blue toy sports car", 0.088, 0.042, 0.029, (0.40, 0.35), (0.10, 0.30, 0.85)),
    2: ToyCarVariant("yellow toy van", 0.080, 0.042, 0.042, (0.75, 0.55), (0.95, 0.80, 0.10)),
    3: ToyCarVariant("green toy pickup", 0.086, 0.041, 0.036, (0.35, 0.42), (0.15, 0.60, 0.25)),
    4: ToyCarVariant("white toy police car", 0.084, 0.040, 0.034, (0.50, 0.40), (0.92, 0.92, 0.92)),
    5: ToyCarVariant("orange toy hatchback", 0.078, 0.040, 0.036, (0.55, 0.45), (0.95, 0.50, 0.10)),
}
TOY_CAR_MASS = 0.05
WHEEL_R = 0.0085


@_memo
def toy_car_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Toy car ``model_id``: body frame at the centre of its bounding box, x forward along the car,
    z up. Collision: the body box (down to the wheels' bottom, so the car does not roll) and the
    cabin box. Visual: body, cabin with dark windows, four wheels, lights."""
    v = TOY_CARS[model_id]
    L, W, H = v.length, v.width, v.height
    z0 = -H / 2
    body_h = (1 - v.cabin[1]) * H
    paint = _mat(v.color, roughness=0.35, metallic=0.2)
    dark = _mat((0.05, 0.05, 0.06), roughness=0.5)
    glass = _mat((0.12, 0.16, 0.22), roughness=0.2)
    cab_l = v.cabin[0] * L
    cab_h = v.cabin[1] * H
    cab_x = -0.08 * L if v.cabin[0] < 0.7 else -0.05 * L
    shapes = [
        # collision: body from the ground up (the wheels are visual), cabin on top
        Shape(Box((L / 2, W / 2, body_h / 2)), pose=body_pose((0, 0, z0 + body_h / 2)), material=paint, visual=False),
        Shape(Box((cab_l / 2, W / 2 - 0.003, cab_h / 2)), pose=body_pose((cab_x, 0, z0 + body_h + cab_h / 2)),
              material=paint, visual=False),
        # visual
        Shape(Box((L / 2, W / 2 - 0.001, (body_h - WHEEL_R * 0.9) / 2)),
              pose=body_pose((0, 0, z0 + WHEEL_R * 0.9 + (body_h - WHEEL_R * 0.9) / 2)), material=paint,
              collision=False),
        Shape(Box((cab_l / 2, W / 2 - 0.003, cab_h / 2)), pose=body_pose((cab_x, 0, z0 + body_h + cab_h / 2)),
              material=paint, collision=False),
        Shape(Box((cab_l / 2 + 0.0008, W / 2 - 0.0055, cab_h / 2 - 0.003)),
              pose=body_pose((cab_x, 0, z0 + body_h + cab_h / 2 - 0.001)), material=glass, collision=False),
        Shape(Box((cab_l / 2 - 0.006, W / 2 - 0.0022, cab_h / 2 - 0.004)),
              pose=body_pose((cab_x, 0, z0 + body_h + cab_h / 2 - 0.001)), material=glass, collision=False),
    ]
    for sx in (-1, 1):
        for sy in (-1, 1):
            shapes.append(Shape(Cylinder(WHEEL_R, 0.004),
                                pose=body_pose((sx * 0.32 * L, sy * (W / 2 - 0.003), z0 + WHEEL_R), _rz(np.pi / 2)),
                                material=dark, collision=False))
    for sy in (-1, 1):
        shapes.append(Shape(Box((0.001, 0.005, 0.003)),
                            pose=body_pose((L / 2 + 0.0005, sy * (W / 2 - 0.008), z0 + body_h - 0.006)),
                            material=_mat((0.98, 0.95, 0.70), roughness=0.2), collision=False))
    dims = {"model_id": model_id, "kind": v.kind, "size": [L, W, H], "mass_kg": TOY_CAR_MASS}
    return shapes, dims


@dataclass(frozen=True)
class CardsVariant:
    kind: str
    color: tuple[float, float, float]


#: upstream's playing-card model ids 0-2
PLAYING_CARDS: dict[int, CardsVariant] = {
    0: CardsVariant("red pack of playing cards", (0.75, 0.10, 0.12)),
    1: CardsVariant("blue pack of playing cards", (0.12, 0.22, 0.70)),
    2: CardsVariant("green pack of playing cards", (0.10, 0.50, 0.25)),
}
CARDS_SIZE = (0.089, 0.064, 0.020)  # a poker deck in its tuck box, lying flat
CARDS_MASS = 0.09


@_memo
def playing_cards_shapes(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """Pack of playing cards ``model_id`` lying flat: body frame at the box's centre, x along its
    length, z up. Collision: the box. Visual: printed back with a white border and a pip."""
    v = PLAYING_CARDS[model_id]
    L, W, H = CARDS_SIZE
    paper = _mat((0.96, 0.96, 0.94), roughness=0.6)
    ink = _mat(v.color, roughness=0.6)
    shapes = [
        Shape(Box((L / 2, W / 2, H / 2)), material=paper),
        Shape(Box((L / 2 - 0.005, W / 2 - 0.005, 0.0004)), pose=body_pose((0, 0, H / 2 + 0.0002)), material=ink,
              collision=False),
        Shape(Box((0.010, 0.010, 0.0004)), pose=body_pose((0, 0, H / 2 + 0.0005), _rz(np.pi / 4)), material=paper,
              collision=False),
        Shape(Box((L / 2 - 0.004, 0.0004, H / 2 - 0.002)), pose=body_pose((0, -W / 2 - 0.0002, 0)), material=ink,
              collision=False),
        Shape(Box((L / 2 - 0.004, 0.0004, H / 2 - 0.002)), pose=body_pose((0, W / 2 + 0.0002, 0)), material=ink,
              collision=False),
    ]
    dims = {"model_id": model_id, "kind": v.kind, "size": list(CARDS_SIZE), "mass_kg": CARDS_MASS}
    return shapes, dims
