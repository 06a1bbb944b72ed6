"""Generated assets of the ``articulated`` task group: the laptop of ``open_laptop_setup_arm`` (a
two-link URDF on a friction hinge) and the shoe box and shoes of ``place_dual_shoes`` (primitive
and convex-mesh rigid bodies). Everything is built from code; nothing is downloaded.

Frames are documented per asset; quaternions are (w, x, y, z); metres and kilograms.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache, partial
from typing import Any

import numpy as np

from cab_core.contracts.scene import Box, Shape, cache_dir
from cab_core.kits.assets import box_inertia, hinged_urdf, mesh_shape, trimesh_module, urdf_inertial, urdf_part
from cab_core.kits.scene import material, srgb


# =================================================================================================
# laptop
# =================================================================================================
@dataclass(frozen=True)
class LaptopVariant:
    """One laptop model (as upstream's ``015_laptop`` ids, several sizes and finishes)."""
    width: float  # x, base and lid
    depth: float  # y, base and lid (hinge to front edge)
    base_t: float  # base thickness
    lid_t: float  # lid thickness
    shell_rgb: tuple[float, float, float]
    keys_rgb: tuple[float, float, float]
    logo_rgb: tuple[float, float, float]


LAPTOP_VARIANTS = (
    LaptopVariant(0.31, 0.215, 0.017, 0.007, (0.78, 0.79, 0.81), (0.12, 0.12, 0.13), (0.95, 0.95, 0.97)),  # silver 13"
    LaptopVariant(0.325, 0.225, 0.019, 0.008, (0.30, 0.31, 0.34), (0.08, 0.08, 0.09), (0.70, 0.72, 0.75)),  # grey 14"
    LaptopVariant(0.345, 0.235, 0.021, 0.009, (0.10, 0.10, 0.11), (0.04, 0.04, 0.05), (0.85, 0.10, 0.10)),  # black 15"
    LaptopVariant(0.30, 0.21, 0.016, 0.007, (0.86, 0.74, 0.68), (0.93, 0.93, 0.92), (0.98, 0.92, 0.88)),  # rose 13"
)
LID_UPPER = 2.2  # rad (126 deg): the hinge's full range is [0, LID_UPPER]
LID_MASS = 0.12  # kg (upstream sets 0.01 kg for the whole model)
BASE_MASS = 1.2  # kg (the root is fixed)
# A laptop's friction hinge holds the lid at any angle. PhysX's articulation joint friction is
# Coulomb-like (proportional to the joint's constraint force), so 1.0 holds the lid at every angle
# independently of its mass (measured: no drift in 5 s from 0.1 to 1.9 rad), while a push of a few
# newtons at the front edge opens it; a little damping stops a flung lid.
HINGE_FRICTION = 1.0
HINGE_DAMPING = 0.05


def laptop_geometry(v: LaptopVariant) -> dict[str, Any]:
    """Frames. Base link: origin at the bottom centre of the base, +x to the right, +y toward the
    hinge (back), +z up; the front edge is at y = -depth/2. Lid link: origin on the hinge axis (the
    base's back top edge), axes equal to the base's when closed; the closed lid spans
    y in [-depth, 0], z in [0, lid_t]; its inner face (screen) is z = 0, its front edge y = -depth.
    The hinge axis is the lid's -x: a positive angle lifts the front edge."""
    return {
        "hinge_base": (0.0, v.depth / 2, v.base_t),
        "edge_lid": (0.0, -v.depth, v.lid_t / 2),  # centre of the lid's front edge (contact point 1)
        "lid_center_lid": (0.0, -v.depth / 2, v.lid_t / 2),
    }


def lid_rotation(q: float) -> np.ndarray:
    """Rotation of the lid frame relative to the base frame at hinge angle ``q`` (about -x)."""
    c, s = np.cos(q), np.sin(q)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def laptop_urdf(v: LaptopVariant) -> str:
    """The laptop as a two-link URDF of primitives: ``base`` (body, keyboard deck, trackpad,
    hinge barrel) and ``lid`` (shell, screen, bezel, logo) on the revolute joint ``lid_hinge``."""
    W, D, B, T = v.width, v.depth, v.base_t, v.lid_t
    shell = srgb(*v.shell_rgb)
    keys = srgb(*v.keys_rgb)
    pad = srgb(*(np.asarray(v.shell_rgb) * 0.9 + 0.05))
    screen = srgb(0.05, 0.09, 0.16)
    bezel = srgb(0.03, 0.03, 0.035)
    logo = srgb(*v.logo_rgb)
    parts: list[str] = []

    def add(name: str, *a: Any, **k: Any) -> None:
        parts.append(urdf_part(*a, material=name, **k))

    add("shell", "box", (W, D, B), (0, 0, B / 2), rgba=shell)
    # keyboard: a dark deck with rows of keys (visual only, 0.5 mm proud of the top)
    kw, kd = W - 0.05, D * 0.42
    ky = D / 2 - 0.025 - kd / 2
    add("deck", "box", (kw, kd, 0.0006), (0, ky, B + 0.0003), rgba=srgb(*(np.asarray(v.keys_rgb) * 0.6)),
        collision=False)
    rows, cols = 5, 14
    key = (kw - 0.01) / cols
    for r in range(rows):
        for c in range(cols):
            if r == rows - 1 and 3 <= c < 10:
                continue  # the space bar goes here
            add("key", "box", (key * 0.8, kd / rows * 0.78, 0.0012),
                (-kw / 2 + 0.005 + key * (c + 0.5), ky + kd / 2 - kd / rows * (r + 0.5), B + 0.0006), rgba=keys,
                collision=False)
    add("key", "box", (key * 7 * 0.95, kd / rows * 0.78, 0.0012),
        (-kw / 2 + 0.005 + key * 6.5, ky + kd / 2 - kd / rows * (rows - 0.5), B + 0.0006), rgba=keys,
        collision=False)
    add("pad", "box", (W * 0.34, D * 0.28, 0.0006), (0, -D / 2 + 0.018 + D * 0.14, B + 0.0003), rgba=pad,
        collision=False)
    add("hinge", "cylinder", (B * 0.45, W * 0.7), (0, D / 2 - B * 0.4, B * 0.8), rpy=(0, np.pi / 2, 0),
        rgba=bezel, collision=False)
    base_inertial = urdf_inertial(BASE_MASS, (0, 0, B / 2), box_inertia(BASE_MASS, (W, D, B)))

    lparts: list[str] = []

    def ladd(name: str, *a: Any, **k: Any) -> None:
        lparts.append(urdf_part(*a, material=name, **k))

    ladd("shell", "box", (W, D, T), (0, -D / 2, T / 2), rgba=shell)
    # inner face: a black bezel with the screen, 0.5 mm below the lid's inner face (visual only)
    ladd("bezel", "box", (W - 0.004, D - 0.004, 0.0006), (0, -D / 2, -0.0003), rgba=bezel, collision=False)
    ladd("screen", "box", (W - 0.03, D - 0.035, 0.0008), (0, -D / 2 - 0.003, -0.0005), rgba=screen,
         collision=False)
    # outer face: a logo in the middle
    ladd("logo", "cylinder", (0.022, 0.0008), (0, -D / 2, T + 0.0004), rgba=logo, collision=False)
    lid_inertial = urdf_inertial(LID_MASS, (0, -D / 2, T / 2), box_inertia(LID_MASS, (W, D, T)))
    hx, hy, hz = laptop_geometry(v)["hinge_base"]
    return hinged_urdf("laptop", base_inertial=base_inertial, base_parts=parts, child="lid",
                       child_inertial=lid_inertial, child_parts=lparts, joint="lid_hinge", origin=(hx, hy, hz),
                       axis="-1 0 0", upper=LID_UPPER, velocity=10, damping=HINGE_DAMPING,
                       friction=HINGE_FRICTION)


# =================================================================================================
# shoes and the shoe box
# =================================================================================================
# Shoe body frame (upstream's ``041_shoe`` convention, so that the verifier's target quaternion
# [0.5, 0.5, -0.5, -0.5] reads as "sole down, toe toward world -x"): origin on the sole's bottom at
# the middle of the shoe's length and width; +y up (out of the sole), +z toward the toe, +x toward
# the shoe's left side. The geometry is designed in a "design frame" (X toe, Y left, Z up, same
# origin) and mapped with (X, Y, Z) -> body (Y, Z, X), a rotation.
@dataclass(frozen=True)
class ShoeStyle:
    """A sneaker: the sole, a solid toe box / vamp over the front, and a collar (thin walls around
    an open heel cavity) over the back, where a gripper can pinch the heel counter."""
    length: float
    sole_t: float
    heel_h: float  # collar top at the heel (above the ground)
    upper_rgb: tuple[float, float, float]
    accent_rgb: tuple[float, float, float]
    sole_rgb: tuple[float, float, float]
    lace_rgb: tuple[float, float, float]


SHOE_STYLES = (
    ShoeStyle(0.19, 0.014, 0.064, (0.10, 0.25, 0.75), (0.95, 0.95, 0.95), (0.95, 0.95, 0.93), (0.95, 0.95, 0.95)),
    ShoeStyle(0.19, 0.014, 0.064, (0.80, 0.12, 0.12), (0.12, 0.12, 0.12), (0.95, 0.95, 0.93), (0.95, 0.95, 0.95)),
    ShoeStyle(0.185, 0.015, 0.062, (0.15, 0.15, 0.16), (0.90, 0.45, 0.10), (0.92, 0.90, 0.85), (0.85, 0.85, 0.85)),
    ShoeStyle(0.195, 0.014, 0.065, (0.90, 0.90, 0.88), (0.10, 0.55, 0.35), (0.35, 0.25, 0.18), (0.90, 0.90, 0.88)),
    ShoeStyle(0.19, 0.016, 0.063, (0.95, 0.75, 0.15), (0.20, 0.20, 0.60), (0.95, 0.95, 0.93), (0.20, 0.20, 0.60)),
)
SHOE_MASS = 0.16  # kg (a child's sneaker)
SHOE_FRICTION = 0.9  # rubber and canvas
SHOE_WALL_T = 0.006  # collar wall thickness
SHOE_OPEN_U = 0.48  # the collar opening spans this fraction of the length from the heel
SHOE_HEEL_FLAT = 0.012  # half-width of the flat back of the heel counter (where the pads close)
# half-widths (lateral, medial) along the length, u = 0 at the heel, 1 at the toe
_SHOE_U = (0.0, 0.03, 0.08, 0.2, 0.45, 0.65, 0.8, 0.9, 0.96, 1.0)
_SHOE_LAT = (SHOE_HEEL_FLAT, 0.021, 0.025, 0.027, 0.030, 0.033, 0.033, 0.028, 0.019, 0.004)
_SHOE_MED = (SHOE_HEEL_FLAT, 0.021, 0.025, 0.026, 0.023, 0.032, 0.033, 0.030, 0.022, 0.006)
# upper height (above the ground) along the length: collar over the back, vamp over the front
_SHOE_TOP_U = (0.0, 0.12, 0.3, 0.48, 0.65, 0.8, 0.92, 1.0)
_SHOE_TOP = (1.0, 0.97, 0.82, 0.90, 0.80, 0.68, 0.52, 0.34)  # fractions of heel_h


def _d2b(p) -> np.ndarray:
    """Design frame (X toe, Y left, Z up) -> shoe body frame (+z toe, +x left, +y up)."""
    p = np.asarray(p, float)
    return p[..., [1, 2, 0]]


def shoe_outline(style: ShoeStyle, foot: str, n: int = 24) -> np.ndarray:
    """The footprint (design frame X, Y), counter-clockwise from the heel's centre: lateral side
    from heel to toe, then the medial side back. A left shoe's medial side is -Y."""
    u = np.concatenate([np.linspace(0.0, 0.2, n // 3, endpoint=False), np.linspace(0.2, 1.0, n - n // 3)])
    lat = np.interp(u, _SHOE_U, _SHOE_LAT)
    med = np.interp(u, _SHOE_U, _SHOE_MED)
    x = -style.length / 2 + u * style.length
    s = 1.0 if foot == "left" else -1.0  # lateral side is +Y on a left shoe
    side_a = np.stack([x, s * lat], axis=1)
    side_b = np.stack([x, -s * med], axis=1)[::-1]
    pts = np.concatenate([side_a, side_b])
    if s < 0:  # keep counter-clockwise order
        pts = pts[::-1]
    return pts


def _prism(poly: np.ndarray, z0: float, z1: float):
    """A closed prism over a star-shaped polygon (fan triangulation from its centroid)."""
    trimesh = trimesh_module()
    n = len(poly)
    c = poly.mean(axis=0)
    verts = [[*c, z0], [*c, z1]] + [[*p, z0] for p in poly] + [[*p, z1] for p in poly]
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces.append([0, 2 + j, 2 + i])  # bottom (facing down)
        faces.append([1, 2 + n + i, 2 + n + j])  # top
        faces.append([2 + i, 2 + j, 2 + n + j])
        faces.append([2 + i, 2 + n + j, 2 + n + i])
    m = trimesh.Trimesh(np.asarray(verts), np.asarray(faces), process=True)
    m.fix_normals()
    return m


def _hull(points):
    return trimesh_module().convex.convex_hull(np.asarray(points, float))


def _to_body(mesh):
    m = mesh.copy()
    m.vertices = _d2b(m.vertices)
    return m


_mat = partial(material, roughness=0.6)  # this module's default finish


def shoe_geometry(style: ShoeStyle) -> dict[str, Any]:
    """Privileged facts in the shoe body frame: the heel-counter pinch point (the centre of the flat
    back wall at the collar's mid-height), the inward direction from it, sizes."""
    L, t = style.length, SHOE_WALL_T
    top = style.heel_h
    return {
        "length": L,
        "width": float(max(_SHOE_LAT) + max(_SHOE_MED)),
        "heel_height": top,
        "sole_thickness": style.sole_t,
        "wall_thickness": t,
        # design (X, Y, Z) -> body (Y, Z, X)
        "heel_wall_center": _d2b([-L / 2 + t / 2, 0.0, (style.sole_t + top) / 2]).tolist(),
        "heel_wall_top": _d2b([-L / 2 + t / 2, 0.0, top]).tolist(),
        "toe_dir": [0.0, 0.0, 1.0],
        "up_dir": [0.0, 1.0, 0.0],
        "opening_length": SHOE_OPEN_U * L,
    }


def shoe_shapes(style: ShoeStyle, foot: str, stem: str) -> list:
    """Convex collision pieces (each also drawn): the sole, the toe box / vamp (solid), and collar
    wall segments around the heel cavity; plus visual details (insole, laces, heel tab). Generated
    once per process and asset cache folder (the meshes are content-addressed files)."""
    return list(_shoe_shapes(style, foot, stem, str(cache_dir())))


@lru_cache(maxsize=64)
def _shoe_shapes(style: ShoeStyle, foot: str, stem: str, _cache: str) -> tuple:
    L, st, H, t = style.length, style.sole_t, style.heel_h, SHOE_WALL_T
    outline = shoe_outline(style, foot)
    n = len(outline)
    u_of = (outline[:, 0] + L / 2) / L
    upper = _mat(style.upper_rgb, friction=SHOE_FRICTION)
    accent = _mat(style.accent_rgb, friction=SHOE_FRICTION)
    sole = _mat(style.sole_rgb, roughness=0.8, friction=SHOE_FRICTION)
    shapes = []

    # sole (the hull collides; the drawn prism keeps the arch)
    shapes.append(mesh_shape(f"{stem}-sole", _to_body(_prism(outline, 0.0, st)), material=sole))

    def top_at(u):
        return float(np.interp(u, _SHOE_TOP_U, _SHOE_TOP)) * H

    # toe box / vamp: a dome over the outline in front of the collar opening
    front = outline[u_of >= SHOE_OPEN_U - 1e-9]
    pts = [[p[0], p[1], st - 0.002] for p in front]
    lat_y, med_y = {}, {}
    for uu in np.linspace(SHOE_OPEN_U, 0.985, 10):
        x = -L / 2 + uu * L
        ys = outline[np.abs(u_of - uu) < 0.09][:, 1]
        ya, yb = float(np.max(ys)), float(np.min(ys))
        yc, ry = (ya + yb) / 2, (ya - yb) / 2 * 0.96
        h = top_at(uu)
        for ph in np.linspace(0.0, np.pi, 9):
            pts.append([x, yc + ry * np.cos(ph), st + (h - st) * np.sin(ph) ** 0.6])
        lat_y[uu], med_y[uu] = ya, yb
    vamp = _hull(pts)
    shapes.append(mesh_shape(f"{stem}-vamp", _to_body(vamp), material=upper))

    # collar walls: segments along the outline behind the opening, inset by the wall thickness
    back_idx = [i for i in range(n) if u_of[i] <= SHOE_OPEN_U + 1e-9]
    # walk the outline around the heel: order the back points by their angle around the cavity
    cav_c = np.array([-L / 2 + SHOE_OPEN_U * L / 2, 0.0])
    back_idx.sort(key=lambda i: np.arctan2(outline[i, 1] - cav_c[1], -(outline[i, 0] - cav_c[0])))
    back = outline[back_idx]
    step = max(1, len(back) // 10)
    keep = list(range(0, len(back), step))
    if keep[-1] != len(back) - 1:
        keep.append(len(back) - 1)
    poly = back[keep]
    for k in range(len(poly) - 1):
        p0, p1 = poly[k], poly[k + 1]
        if np.linalg.norm(p1 - p0) < 1e-4:
            continue
        d = (p1 - p0) / np.linalg.norm(p1 - p0)
        inward = np.array([-d[1], d[0]])
        if np.dot(inward, cav_c - (p0 + p1) / 2) < 0:
            inward = -inward
        h0, h1 = top_at((p0[0] + L / 2) / L), top_at((p1[0] + L / 2) / L)
        quad = [p0, p1, p1 + t * inward, p0 + t * inward]
        seg = []
        for q, h in zip(quad, (h0, h1, h1, h0)):
            seg += [[q[0], q[1], st - 0.002], [q[0], q[1], h]]
        is_heel = abs(p0[1]) <= SHOE_HEEL_FLAT + 1e-6 and abs(p1[1]) <= SHOE_HEEL_FLAT + 1e-6
        shapes.append(mesh_shape(f"{stem}-wall{k}", _to_body(_hull(seg)), material=accent if is_heel else upper))

    trimesh = trimesh_module()
    # visual details: insole, laces, heel tab
    inner = back + 0.0  # the cavity floor: the outline behind the opening, shrunk toward its centre
    insole = (inner - cav_c) * 0.85 + cav_c
    shapes.append(mesh_shape(f"{stem}-insole", _to_body(_prism(insole, st, st + 0.0015)),
                             material=_mat((0.12, 0.12, 0.13)), collision=False))
    for k, uu in enumerate(np.linspace(SHOE_OPEN_U + 0.04, 0.74, 4)):
        x = -L / 2 + uu * L
        w = (lat_y[min(lat_y, key=lambda v: abs(v - uu))] - med_y[min(med_y, key=lambda v: abs(v - uu))]) * 0.5
        lace = trimesh.creation.box((0.006, w, 0.003))
        lace.apply_translation([x, 0.0, top_at(uu) + 0.0008])
        shapes.append(mesh_shape(f"{stem}-lace{k}", _to_body(lace), material=_mat(style.lace_rgb), collision=False))
    tab = trimesh.creation.box((0.004, 0.016, 0.016))
    tab.apply_translation([-L / 2 - 0.0015, 0.0, H - 0.004])
    shapes.append(mesh_shape(f"{stem}-tab", _to_body(tab), material=_mat(style.accent_rgb), collision=False))
    return tuple(shapes)


# the shoe box: a static open cardboard box; body frame: origin at the bottom centre, +x along the
# box's length, +z up; the inner floor is FLOOR_T above the origin
@dataclass(frozen=True)
class ShoeBoxStyle:
    inner: tuple[float, float]  # inner length (x), width (y)
    height: float
    wall_t: float
    floor_t: float
    rgb: tuple[float, float, float]
    inner_rgb: tuple[float, float, float]
    band_rgb: tuple[float, float, float]


SHOE_BOX = ShoeBoxStyle((0.30, 0.18), 0.085, 0.008, 0.01, (0.72, 0.52, 0.32), (0.86, 0.80, 0.70), (0.15, 0.15, 0.15))


def shoe_box_shapes(style: ShoeBoxStyle = SHOE_BOX) -> list:
    """Floor and four walls (boxes), a printed band round the outside and tissue paper inside."""
    (li, wi), h, t, f = style.inner, style.height, style.wall_t, style.floor_t
    lo, wo = li + 2 * t, wi + 2 * t
    card = _mat(style.rgb, roughness=0.9)
    inner = _mat(style.inner_rgb, roughness=0.95)
    band = _mat(style.band_rgb, roughness=0.7)
    idq = (1.0, 0.0, 0.0, 0.0)
    shapes = [
        Shape(Box((lo / 2, wo / 2, f / 2)), pose=(0.0, 0.0, f / 2, *idq), material=card),
        Shape(Box((lo / 2, t / 2, h / 2)), pose=(0.0, -(wi + t) / 2, h / 2, *idq), material=card),
        Shape(Box((lo / 2, t / 2, h / 2)), pose=(0.0, (wi + t) / 2, h / 2, *idq), material=card),
        Shape(Box((t / 2, wi / 2, h / 2)), pose=(-(li + t) / 2, 0.0, h / 2, *idq), material=card),
        Shape(Box((t / 2, wi / 2, h / 2)), pose=((li + t) / 2, 0.0, h / 2, *idq), material=card),
        # tissue paper on the floor, inner wall lining (visual)
        Shape(Box((li / 2 - 0.002, wi / 2 - 0.002, 0.0005)), pose=(0.0, 0.0, f + 0.0005, *idq),
              material=_mat((0.97, 0.97, 0.95), roughness=0.95), collision=False),
    ]
    for sx, sy, hx, hy in ((0, -1, lo / 2, 0.0005), (0, 1, lo / 2, 0.0005), (-1, 0, 0.0005, wo / 2),
                           (1, 0, 0.0005, wo / 2)):
        shapes.append(Shape(Box((hx, hy, 0.012)), pose=(sx * (lo / 2 + 0.0005), sy * (wo / 2 + 0.0005), h * 0.62,
                                                        *idq), material=band, collision=False))
        shapes.append(Shape(Box((max(hx - t, 0.0005), max(hy - t, 0.0005), h / 2 - 0.002)),
                            pose=(sx * (li / 2 - 0.0005), sy * (wi / 2 - 0.0005), f + h / 2, *idq),
                            material=inner, collision=False))
    return shapes
