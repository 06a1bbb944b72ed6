"""Generated assets of the bins group (pick_diverse_bottles, put_bottles_dustbin, dump_bin_bigbin):
bottles of several shapes, the big floor-standing dustbin, the small table bin and its balls.

Everything is built from code: bottles are surfaces of revolution (trimesh ``revolve``) written as OBJ
files; a bottle collides as the convex hull of its outline (a bottle's hull differs from the bottle
only around the neck, where nothing is grasped). Hollow containers collide as boxes (floor and wall
panels), so their insides are open; their visual meshes are revolved shells.

Frames
    bottle: origin on the bottle's axis at half its height (functional point 0, the point the
        verifiers read), +z along the axis toward the cap; the bottle stands on its flat base at
        z = -height/2.
    big dustbin: origin on the ground at the centre of its footprint, +z up; walls along x and y.
    small table bin: origin on its axis at half its height, +z up (toward the opening).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from cab_core.contracts.scene import Body, Box, Material, Shape, Sphere
from cab_core.geometry import axis_angle_quat, quat_mul
from cab_core.kits.assets import assets_dir, mesh_shape, trimesh_module
from cab_core.kits.scene import IDENTITY_Q, material, srgb

_SHAPES: dict[tuple, tuple[Shape, ...]] = {}


def _memo(key: tuple, make) -> list[Shape]:
    """Shapes of a generated asset, made once per process and cache folder (building meshes and
    hulls is the slow part of a scene build)."""
    k = (str(assets_dir()),) + key
    if k not in _SHAPES:
        _SHAPES[k] = tuple(make())
    return list(_SHAPES[k])


_mat = partial(material, roughness=0.45)  # this module's default finish


# =================================================================================================
# bottles
# =================================================================================================
@dataclass(frozen=True)
class BottleStyle:
    """A bottle outline: a body of radius ``radius`` from the base to ``body_top`` (a fraction of the
    height; ``waist`` narrows its middle by that fraction of the radius), a shoulder easing to the
    neck of radius ``neck_radius`` by ``neck_start``, the neck up to the cap, and a cylindrical cap
    of radius ``cap_radius`` and height ``cap_height`` on top. ``label`` = (z0, z1) fractions of a
    paper label band, or None."""
    kind: str
    radius: float
    height: float
    body_top: float
    neck_start: float
    neck_radius: float
    cap_radius: float
    cap_height: float
    body_rgb: tuple[float, float, float]
    cap_rgb: tuple[float, float, float]
    label_rgb: tuple[float, float, float] | None = None
    label: tuple[float, float] | None = None
    waist: float = 0.0
    taper: float = 0.0  # the body narrows upward by this fraction of the radius
    mass: float = 0.15  # kg
    glossy: bool = True

    @property
    def grasp_z(self) -> float:
        """Height (bottle frame) of the middle of the straight body: where a side grasp closes."""
        return self.height * self.body_top * 0.5 - self.height / 2

    @property
    def grasp_width(self) -> float:
        """Body diameter at the grasp height."""
        return 2 * self.radius_at(self.height * self.body_top * 0.5)

    def radius_at(self, z_from_base: float) -> float:
        h = self.height
        zb = self.body_top * h
        if z_from_base <= zb:
            s = z_from_base / zb
            r = self.radius * (1 - self.taper * s)
            if self.waist:
                r *= 1 - self.waist * np.sin(np.pi * s) ** 2
            return float(r)
        return float(self.neck_radius)


def bottle_profile(s: BottleStyle, n_body: int = 14, n_shoulder: int = 10) -> np.ndarray:
    """(radius, z) outline from the base centre (0, 0) to the top of the neck (0, h - cap), z from
    the base."""
    h = s.height
    zb, zn, zc = s.body_top * h, s.neck_start * h, h - s.cap_height
    fillet = min(0.006, 0.2 * s.radius)
    pts = [(0.0, 0.0), (s.radius * (1 - 0.0) - fillet, 0.0)]
    for k in range(1, 4):  # rounded base edge
        a = k / 3 * np.pi / 2
        pts.append((s.radius - fillet + fillet * np.sin(a), fillet - fillet * np.cos(a)))
    for k in range(1, n_body + 1):
        z = fillet + (zb - fillet) * k / n_body
        pts.append((s.radius_at(z), z))
    r_top = s.radius_at(zb)
    for k in range(1, n_shoulder + 1):  # shoulder: cosine ease from the body to the neck
        t = k / n_shoulder
        r = s.neck_radius + (r_top - s.neck_radius) * 0.5 * (1 + np.cos(np.pi * t))
        pts.append((r, zb + (zn - zb) * t))
    pts.append((s.neck_radius, zc + 0.003))  # the neck runs up into the cap
    pts.append((0.0, zc + 0.003))
    return np.asarray(pts, float)


def bottle_shapes(style: BottleStyle, stem: str, friction: float = 0.8) -> list[Shape]:
    """Visual meshes (body, cap, label) and one convex collision hull, in the bottle frame."""
    return _memo(("bottle", style, stem, friction), lambda: _bottle_shapes(style, stem, friction))


def _bottle_shapes(style: BottleStyle, stem: str, friction: float) -> list[Shape]:
    tm = trimesh_module()
    h = style.height
    shift = np.eye(4)
    shift[2, 3] = -h / 2
    prof = bottle_profile(style)
    body = tm.creation.revolve(prof, sections=40)
    body.apply_transform(shift)
    cap = tm.creation.cylinder(radius=style.cap_radius, height=style.cap_height, sections=32)
    cap.apply_translation([0, 0, h / 2 - style.cap_height / 2])
    hull_pts = np.vstack([body.vertices, cap.vertices])
    hull = tm.convex.convex_hull(hull_pts)
    grip = _mat((0.5, 0.5, 0.5), friction=friction)
    body_mat = _mat(style.body_rgb, roughness=0.15 if style.glossy else 0.55)
    cap_mat = _mat(style.cap_rgb, roughness=0.5)
    shapes = [
        mesh_shape(f"{stem}-hull", hull, material=grip, visual=False),
        mesh_shape(f"{stem}-body", body, material=body_mat, collision=False),
        mesh_shape(f"{stem}-cap", cap, material=cap_mat, collision=False),
    ]
    if style.label is not None and style.label_rgb is not None:
        z0, z1 = (f * h for f in style.label)
        zs = np.linspace(z0, z1, 6)
        r_out = [style.radius_at(z) + 0.0008 for z in zs]
        lab_prof = [(r_out[0] - 0.0008, zs[0])] + list(zip(r_out, zs)) + [(r_out[-1] - 0.0008, zs[-1])]
        # a closed thin band: outer surface plus an inner return (revolve needs a closed outline)
        band = tm.creation.revolve(np.asarray(lab_prof + [(lab_prof[0][0] - 1e-4, zs[0])], float), sections=40)
        band.apply_transform(shift)
        shapes.append(mesh_shape(f"{stem}-label", band, material=_mat(style.label_rgb, roughness=0.7),
                                 collision=False))
    return shapes


def _b(kind, radius, height, body_top, neck_start, neck_radius, cap_radius, cap_height, body, cap, label_rgb=None,
       label=None, **kw) -> BottleStyle:
    return BottleStyle(kind, radius, height, body_top, neck_start, neck_radius, cap_radius, cap_height, body, cap,
                       label_rgb, label, **kw)


#: 20 bottles (as upstream's ``001_bottle`` ids 0-19): ten kinds in two sizes / colourings
DIVERSE_BOTTLES: tuple[BottleStyle, ...] = (
    _b("water", 0.032, 0.215, 0.62, 0.86, 0.0135, 0.0155, 0.020, (0.62, 0.80, 0.92), (0.15, 0.35, 0.85),
       (0.20, 0.45, 0.85), (0.30, 0.50), mass=0.12),
    _b("water", 0.029, 0.185, 0.60, 0.84, 0.0130, 0.0150, 0.018, (0.70, 0.86, 0.90), (0.90, 0.90, 0.92),
       (0.10, 0.60, 0.75), (0.28, 0.50), mass=0.10),
    _b("wine", 0.034, 0.250, 0.55, 0.72, 0.0140, 0.0150, 0.030, (0.10, 0.28, 0.12), (0.55, 0.08, 0.10),
       (0.92, 0.88, 0.76), (0.15, 0.40), mass=0.30),
    _b("wine", 0.032, 0.235, 0.52, 0.70, 0.0135, 0.0145, 0.028, (0.45, 0.08, 0.12), (0.80, 0.70, 0.35),
       (0.95, 0.93, 0.85), (0.16, 0.38), mass=0.28),
    _b("beer", 0.030, 0.215, 0.52, 0.72, 0.0125, 0.0140, 0.010, (0.45, 0.25, 0.08), (0.80, 0.75, 0.30),
       (0.90, 0.80, 0.20), (0.18, 0.42), mass=0.22),
    _b("beer", 0.031, 0.200, 0.55, 0.74, 0.0130, 0.0145, 0.010, (0.15, 0.45, 0.18), (0.75, 0.75, 0.78),
       (0.95, 0.95, 0.95), (0.20, 0.42), mass=0.22),
    _b("soda", 0.030, 0.190, 0.68, 0.84, 0.0135, 0.0150, 0.018, (0.30, 0.15, 0.10), (0.85, 0.10, 0.10),
       (0.85, 0.10, 0.10), (0.35, 0.55), waist=0.12, mass=0.15),
    _b("soda", 0.033, 0.225, 0.66, 0.84, 0.0140, 0.0155, 0.020, (0.40, 0.75, 0.35), (0.10, 0.50, 0.15),
       (0.95, 0.85, 0.20), (0.35, 0.55), waist=0.10, mass=0.18),
    _b("milk", 0.036, 0.175, 0.72, 0.86, 0.0200, 0.0220, 0.020, (0.96, 0.96, 0.94), (0.20, 0.35, 0.80),
       (0.25, 0.50, 0.85), (0.25, 0.55), mass=0.25, glossy=False),
    _b("juice", 0.035, 0.185, 0.74, 0.86, 0.0190, 0.0210, 0.022, (0.98, 0.65, 0.15), (0.10, 0.55, 0.20),
       (0.95, 0.90, 0.30), (0.25, 0.60), mass=0.25),
    _b("sauce", 0.028, 0.170, 0.78, 0.88, 0.0110, 0.0160, 0.026, (0.80, 0.12, 0.08), (0.95, 0.95, 0.95),
       (0.95, 0.90, 0.80), (0.30, 0.62), taper=0.08, mass=0.15, glossy=False),
    _b("sauce", 0.030, 0.180, 0.78, 0.88, 0.0120, 0.0170, 0.028, (0.95, 0.80, 0.15), (0.80, 0.15, 0.10),
       (0.30, 0.20, 0.10), (0.30, 0.62), taper=0.08, mass=0.15, glossy=False),
    _b("pills", 0.030, 0.115, 0.78, 0.86, 0.0260, 0.0285, 0.026, (0.95, 0.60, 0.15), (0.97, 0.97, 0.97),
       (0.97, 0.97, 0.95), (0.22, 0.65), mass=0.08),
    _b("pills", 0.027, 0.105, 0.78, 0.86, 0.0230, 0.0255, 0.024, (0.97, 0.97, 0.97), (0.20, 0.45, 0.85),
       (0.35, 0.65, 0.90), (0.22, 0.65), mass=0.07, glossy=False),
    _b("sports", 0.034, 0.210, 0.70, 0.82, 0.0200, 0.0220, 0.032, (0.20, 0.65, 0.85), (0.15, 0.15, 0.15),
       None, None, waist=0.14, mass=0.12, glossy=False),
    _b("sports", 0.033, 0.200, 0.70, 0.82, 0.0195, 0.0215, 0.030, (0.90, 0.30, 0.55), (0.95, 0.95, 0.95),
       None, None, waist=0.14, mass=0.12, glossy=False),
    _b("oil", 0.027, 0.240, 0.66, 0.80, 0.0110, 0.0130, 0.020, (0.85, 0.75, 0.25), (0.15, 0.45, 0.20),
       (0.20, 0.45, 0.20), (0.25, 0.50), mass=0.25),
    _b("oil", 0.028, 0.225, 0.64, 0.80, 0.0115, 0.0135, 0.020, (0.60, 0.65, 0.20), (0.85, 0.70, 0.20),
       (0.95, 0.92, 0.80), (0.25, 0.50), mass=0.23),
    _b("lotion", 0.026, 0.140, 0.80, 0.86, 0.0140, 0.0150, 0.030, (0.85, 0.80, 0.95), (0.50, 0.35, 0.70),
       (0.95, 0.95, 0.98), (0.25, 0.65), mass=0.10, glossy=False),
    _b("lotion", 0.025, 0.130, 0.80, 0.86, 0.0135, 0.0145, 0.028, (0.55, 0.85, 0.80), (0.95, 0.95, 0.95),
       (0.20, 0.50, 0.45), (0.25, 0.65), mass=0.09, glossy=False),
)

#: the three plastic drink bottles of put_bottles_dustbin (as upstream's ``114_bottle`` ids 1, 2, 3)
DRINK_BOTTLES: dict[int, BottleStyle] = {
    1: _b("drink", 0.031, 0.205, 0.64, 0.85, 0.0135, 0.0150, 0.019, (0.72, 0.88, 0.95), (0.15, 0.40, 0.85),
          (0.15, 0.45, 0.85), (0.30, 0.52), mass=0.06),
    2: _b("drink", 0.033, 0.190, 0.66, 0.85, 0.0140, 0.0155, 0.019, (0.55, 0.85, 0.55), (0.10, 0.55, 0.20),
          (0.95, 0.85, 0.15), (0.30, 0.52), waist=0.10, mass=0.06),
    3: _b("drink", 0.030, 0.175, 0.62, 0.84, 0.0130, 0.0150, 0.018, (0.98, 0.80, 0.55), (0.90, 0.45, 0.10),
          (0.90, 0.35, 0.10), (0.30, 0.52), mass=0.05),
}


def bottle_body(name: str, style: BottleStyle, stem: str, pose, friction: float = 0.8) -> Body:
    return Body(name, bottle_shapes(style, stem, friction), pose=tuple(pose), kind="dynamic", mass=style.mass,
                angular_damping=0.1)


def bottle_info(style: BottleStyle, model_id: int, family: str) -> dict[str, Any]:
    h = style.height
    return {
        "model": family,
        "model_id": int(model_id),
        "kind": style.kind,
        "frame": "bottle: origin on the axis at half the height (functional point 0); +z along the axis "
                 "toward the cap; the flat base at z = -height/2",
        "height": round(h, 6),
        "body_radius": round(style.radius, 6),
        "grasp_point": [0.0, 0.0, round(style.grasp_z, 6)],  # middle of the straight body, on the axis
        "grasp_width": round(style.grasp_width, 6),
        "functional_point": [0.0, 0.0, 0.0],
        "top_point": [0.0, 0.0, round(h / 2, 6)],
        "base_point": [0.0, 0.0, round(-h / 2, 6)],
        "mass_kg": style.mass,
    }


# =================================================================================================
# the big dustbin (upstream's ``011_dustbin`` id 0): a tall pedal bin standing on the floor
# =================================================================================================
BIG_BIN_HALF = (0.17, 0.25)  # outer half-size x, y
BIG_BIN_HEIGHT = 0.62  # rim; the table top (0.74) and its underside (0.69) stay above it
BIG_BIN_FLOOR = 0.20  # top of the bucket's floor: the bucket rests on a 0.2 m pedal housing
BIG_BIN_WALL = 0.015

BIN_SHELL = Material(color=srgb(0.22, 0.42, 0.30), roughness=0.5)
BIN_INNER = Material(color=srgb(0.30, 0.33, 0.33), roughness=0.8)
BIN_BASE = Material(color=srgb(0.15, 0.15, 0.16), roughness=0.6)
BIN_RIM = Material(color=srgb(0.12, 0.28, 0.18), roughness=0.45)
PEDAL = Material(color=srgb(0.55, 0.56, 0.58), roughness=0.3, metallic=0.7)


def big_dustbin(name: str, pose) -> Body:
    """An open rectangular bin 0.34 x 0.50 m, 0.62 m tall; the bucket's floor is at 0.20 m (a pedal
    housing below it). Collides as floor, base and four wall panels (static)."""
    hx, hy = BIG_BIN_HALF
    t = BIG_BIN_WALL
    H = BIG_BIN_HEIGHT
    f = BIG_BIN_FLOOR
    wall_h = (H - f) / 2
    zc = f + wall_h
    s = [
        # base (pedal housing) up to the bucket floor
        Shape(Box((hx, hy, f / 2)), pose=(0, 0, f / 2, *IDENTITY_Q), material=BIN_BASE),
        # bucket walls from the floor to the rim
        Shape(Box((t / 2, hy, wall_h)), pose=(-hx + t / 2, 0, zc, *IDENTITY_Q), material=BIN_SHELL),
        Shape(Box((t / 2, hy, wall_h)), pose=(hx - t / 2, 0, zc, *IDENTITY_Q), material=BIN_SHELL),
        Shape(Box((hx - t, t / 2, wall_h)), pose=(0, -hy + t / 2, zc, *IDENTITY_Q), material=BIN_SHELL),
        Shape(Box((hx - t, t / 2, wall_h)), pose=(0, hy - t / 2, zc, *IDENTITY_Q), material=BIN_SHELL),
        # inside lining (visual) and the rim lip (visual)
        Shape(Box((hx - t, hy - t, 0.001)), pose=(0, 0, f + 0.001, *IDENTITY_Q), material=BIN_INNER,
              collision=False),
        Shape(Box((hx + 0.006, 0.012, 0.008)), pose=(0, -hy - 0.002, H - 0.008, *IDENTITY_Q), material=BIN_RIM,
              collision=False),
        Shape(Box((hx + 0.006, 0.012, 0.008)), pose=(0, hy + 0.002, H - 0.008, *IDENTITY_Q), material=BIN_RIM,
              collision=False),
        Shape(Box((0.012, hy + 0.006, 0.008)), pose=(-hx - 0.002, 0, H - 0.008, *IDENTITY_Q), material=BIN_RIM,
              collision=False),
        Shape(Box((0.012, hy + 0.006, 0.008)), pose=(hx + 0.002, 0, H - 0.008, *IDENTITY_Q), material=BIN_RIM,
              collision=False),
        # the pedal in front (toward the robot)
        Shape(Box((0.06, 0.03, 0.008)), pose=(0, -hy - 0.03, 0.05, *IDENTITY_Q), material=PEDAL, collision=False),
    ]
    for sx in (-1, 1):  # inner wall faces, a shade darker (visual)
        s.append(Shape(Box((0.001, hy - t, wall_h)), pose=(sx * (hx - t - 0.001), 0, zc, *IDENTITY_Q),
                       material=BIN_INNER, collision=False))
    for sy in (-1, 1):
        s.append(Shape(Box((hx - t, 0.001, wall_h)), pose=(0, sy * (hy - t - 0.001), zc, *IDENTITY_Q),
                       material=BIN_INNER, collision=False))
    return Body(name, s, pose=tuple(pose), kind="static")


def big_dustbin_info(pose) -> dict[str, Any]:
    hx, hy = BIG_BIN_HALF
    return {
        "name": "dustbin",
        "model": "011_dustbin",
        "model_id": 0,
        "pose": [round(float(v), 6) for v in pose],
        "frame": "dustbin: origin on the ground at the footprint centre, +z up, walls along x and y",
        "outer_half_size": [hx, hy],
        "inner_half_size": [round(hx - BIG_BIN_WALL, 6), round(hy - BIG_BIN_WALL, 6)],
        "rim_z": BIG_BIN_HEIGHT,
        "floor_z": BIG_BIN_FLOOR,
        "opening_center": [round(float(pose[0]), 6), round(float(pose[1]), 6), BIG_BIN_HEIGHT],
    }


# =================================================================================================
# the small table bin (upstream's ``063_tabletrashbin`` ids 0, 3, 7, 8, 9, 10) and its balls
# =================================================================================================
@dataclass(frozen=True)
class TableBinStyle:
    """A small round open bin, narrower at the bottom (``radius_bottom``) than at the top
    (``radius_top``: outer radii), with a rim band and a printed logo patch on its side (local +x)."""
    radius_bottom: float
    radius_top: float
    height: float
    rgb: tuple[float, float, float]
    rim_rgb: tuple[float, float, float]
    logo_rgb: tuple[float, float, float]
    mass: float = 0.08

    def radius_at(self, z_local: float) -> float:
        """Outer radius at height ``z_local`` of the bin frame (origin at half height)."""
        s = (z_local + self.height / 2) / self.height
        return self.radius_bottom + (self.radius_top - self.radius_bottom) * s


TABLE_BINS: dict[int, TableBinStyle] = {
    0: TableBinStyle(0.031, 0.037, 0.100, (0.55, 0.57, 0.60), (0.35, 0.36, 0.38), (0.95, 0.95, 0.95)),
    3: TableBinStyle(0.033, 0.036, 0.095, (0.95, 0.95, 0.93), (0.70, 0.70, 0.68), (0.20, 0.55, 0.30)),
    7: TableBinStyle(0.035, 0.036, 0.105, (0.12, 0.12, 0.13), (0.30, 0.30, 0.32), (0.85, 0.65, 0.15)),
    8: TableBinStyle(0.032, 0.037, 0.100, (0.20, 0.45, 0.85), (0.12, 0.28, 0.60), (0.95, 0.95, 0.95)),
    9: TableBinStyle(0.030, 0.036, 0.090, (0.35, 0.70, 0.35), (0.20, 0.45, 0.22), (0.95, 0.90, 0.30)),
    10: TableBinStyle(0.031, 0.037, 0.100, (0.95, 0.80, 0.20), (0.75, 0.55, 0.10), (0.25, 0.25, 0.25)),
}
TABLE_BIN_IDS = tuple(sorted(TABLE_BINS))
BIN_WALL = 0.004
BIN_FLOOR = 0.006
BIN_PANELS = 16  # the collision wall: a 16-sided polygon whose flats touch the round surface
BIN_FRICTION = 0.9  # textured plastic against rubber finger pads
BALL_RADIUS = 0.008
BALL_MASS = 0.001  # a 16 mm hollow plastic bead (upstream: 0.1 g)
BALL = Material(color=srgb(0.90, 0.08, 0.08), roughness=0.35, static_friction=0.5, dynamic_friction=0.5)


def table_bin_shapes(style: TableBinStyle, stem: str) -> list[Shape]:
    """A revolved shell, lining, rim band and logo (visual); a floor disc and 16 wall panels
    leaning out with the taper (collision). Origin at mid-height."""
    return _memo(("table_bin", style, stem), lambda: _table_bin_shapes(style, stem))


def _table_bin_shapes(style: TableBinStyle, stem: str) -> list[Shape]:
    tm = trimesh_module()
    h = style.height
    rb, rt, w = style.radius_bottom, style.radius_top, BIN_WALL
    prof = np.array([(0, 0), (rb, 0), (rt, h), (rt - w, h), (rb - w, BIN_FLOOR), (0, BIN_FLOOR)], float)
    shell = tm.creation.revolve(prof, sections=48)
    shell.apply_translation([0, 0, -h / 2])
    e = 0.0006  # a darker lining just inside the wall and on the floor (the inside reads as hollow)
    lin = tm.creation.revolve(np.array([(0, BIN_FLOOR + e), (rb - w - e, BIN_FLOOR + e), (rt - w - e, h - 0.002),
                                        (rt - w - 2 * e, h - 0.002), (rb - w - 2 * e, BIN_FLOOR + 2 * e),
                                        (0, BIN_FLOOR + 2 * e)], float), sections=48)
    lin.apply_translation([0, 0, -h / 2])
    rim = tm.creation.revolve(np.array([(rt - w - 0.001, h - 0.007), (rt + 0.0015, h - 0.007), (rt + 0.0015, h + 0.001),
                                        (rt - w - 0.001, h + 0.001)], float), sections=48)
    rim.apply_translation([0, 0, -h / 2])
    body_mat = Material(color=srgb(*style.rgb), roughness=0.6, static_friction=BIN_FRICTION,
                        dynamic_friction=BIN_FRICTION)
    lean = float(np.arctan2(rt - rb, h))
    q_lean = tuple(float(v) for v in axis_angle_quat([0, 1, 0], lean))
    shapes = [mesh_shape(f"{stem}-shell", shell, material=body_mat, collision=False),
              mesh_shape(f"{stem}-lining", lin, material=Material(color=srgb(*(0.55 * c for c in style.rgb)),
                                                                   roughness=0.8), collision=False),
              mesh_shape(f"{stem}-rim", rim, material=Material(color=srgb(*style.rim_rgb), roughness=0.5),
                         collision=False),
              # a printed logo on the +x side (shows the bin's turn about its axis)
              Shape(Box((0.0008, 0.014, 0.018)), pose=(style.radius_at(0.0) + 0.0004, 0.0, 0.0, *q_lean),
                    material=Material(color=srgb(*style.logo_rgb), roughness=0.5), collision=False)]
    floor = tm.creation.cylinder(radius=rb - w, height=BIN_FLOOR, sections=32)
    floor.apply_translation([0, 0, -h / 2 + BIN_FLOOR / 2])
    shapes.append(mesh_shape(f"{stem}-floor", floor, material=body_mat, visual=False))
    slant = float(np.hypot(h, rt - rb))
    mid = (rb + rt) / 2
    side_half = mid * np.tan(np.pi / BIN_PANELS) + w / 2
    for i in range(BIN_PANELS):
        th = 2 * np.pi * i / BIN_PANELS
        q = quat_mul(axis_angle_quat([0, 0, 1], th), axis_angle_quat([0, 1, 0], lean))
        r = mid - w / 2
        shapes.append(Shape(Box((w / 2, side_half, slant / 2)),
                            pose=(r * np.cos(th), r * np.sin(th), 0.0, *(float(v) for v in q)),
                            material=body_mat, visual=False))
    return shapes


def table_bin_body(name: str, style: TableBinStyle, stem: str, pose) -> Body:
    return Body(name, table_bin_shapes(style, stem), pose=tuple(pose), kind="dynamic", mass=style.mass,
                angular_damping=0.1)


def table_bin_info(style: TableBinStyle, model_id: int) -> dict[str, Any]:
    h = style.height
    return {
        "name": "small_bin",
        "model": "063_tabletrashbin",
        "model_id": int(model_id),
        "frame": "small bin: origin on its axis at half its height, +z toward the opening; the logo on +x",
        "height": h,
        "radius_bottom": style.radius_bottom,
        "radius_top": style.radius_top,
        "grasp_point": [0.0, 0.0, 0.0],  # mid-height on the axis: fingers close across the wall
        "grasp_width": round(2 * style.radius_at(0.0), 6),
        "opening_point": [0.0, 0.0, round(h / 2, 6)],
        "bottom_point": [0.0, 0.0, round(-h / 2, 6)],
        "floor_z_local": round(-h / 2 + BIN_FLOOR, 6),
        "inner_radius_floor": round(style.radius_bottom - BIN_WALL, 6),
        "mass_kg": style.mass,
    }


def ball_body(name: str, pose) -> Body:
    return Body(name, [Shape(Sphere(BALL_RADIUS), material=BALL)], pose=tuple(pose), kind="dynamic",
                mass=BALL_MASS, angular_damping=1.5, linear_damping=0.1)  # damping: rolling resistance
