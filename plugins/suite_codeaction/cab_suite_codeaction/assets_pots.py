"""Generated assets of the kitchen tasks (lift_pot, grab_roller_dual_contact, move_can_pot): a
kitchen pot with two side handles, a rolling pin with a handle at each end, and a sauce can.

All three are rigid bodies built from primitives (collision) plus a few trimesh meshes (visual
only, for round walls); nothing is downloaded. Each model comes in a few variants (upstream's
model ids pick among meshes of one category; sizes here are chosen to be plausible and graspable by
the 8 cm parallel gripper).

Frames
    pot:    origin at the centre of the bottom (resting on the table), +z up along the pot's axis,
            the two handles along local -x (handle 0) and +x (handle 1).
    roller: origin at the centre of the roller's axis, the axis along local x; handle 0 at -x,
            handle 1 at +x.
    can:    origin at the centre of the bottom, the can's axis along local +y (upstream's
            ``105_sauce-can`` frame: it stands upright with the quaternion [0.707, 0.707, 0, 0],
            whose transforms3d Euler angles are (90 deg, 0, 0)).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache, partial
from typing import Any

import numpy as np

from cab_core.contracts.scene import Box, Cylinder, Mesh, Shape
from cab_core.kits.assets import assets_dir, mesh_asset
from cab_core.kits.scene import IDENTITY_Q, material

# quaternions that turn a primitive's local x axis (SAPIEN's cylinder axis) onto z or y
X_TO_Z = (float(np.cos(-np.pi / 4)), 0.0, float(np.sin(-np.pi / 4)), 0.0)
X_TO_Y = (float(np.cos(np.pi / 4)), 0.0, 0.0, float(np.sin(np.pi / 4)))
GRIP_FRICTION = 0.8  # rubber finger pads on handles / a can's steel wall (plausible, firm grasps)


_mat = partial(material, roughness=0.5)  # this module's default finish


# --- the kitchen pot ------------------------------------------------------------------------------
@dataclass(frozen=True)
class PotVariant:
    radius: float  # outer radius of the body
    height: float  # bottom to rim
    body_rgb: tuple[float, float, float]
    handle_rgb: tuple[float, float, float]
    metallic: bool
    mass: float  # kg (an empty pot)
    handle_len: float = 0.040  # radial: from the wall to the tab's rounded end
    handle_width: float = 0.030  # tangential (what the fingers close on)
    handle_thick: float = 0.016  # vertical
    wall: float = 0.006
    bottom: float = 0.008


POT_VARIANTS = (
    # sizes keep handle end to handle end <= 25 cm, so that a sauce can fits beside the pot within
    # move_can_pot's 0.2 m of its centre
    PotVariant(0.085, 0.095, (0.78, 0.12, 0.10), (0.08, 0.08, 0.08), False, 0.75),  # red enamel
    PotVariant(0.080, 0.085, (0.72, 0.73, 0.75), (0.55, 0.56, 0.58), True, 0.65),  # stainless steel
    PotVariant(0.075, 0.100, (0.12, 0.22, 0.50), (0.10, 0.10, 0.10), False, 0.65),  # blue enamel
    PotVariant(0.085, 0.088, (0.92, 0.88, 0.76), (0.50, 0.33, 0.18), False, 0.80),  # cream, wooden handles
)
POT_WALL_SEGMENTS = 20


def pot_geometry(v: PotVariant) -> dict[str, Any]:
    """Privileged facts in the pot frame: handle centres (contact points 0 and 1), sizes."""
    hz = v.height - 0.012 - v.handle_thick / 2  # handle top 12 mm below the rim
    hx = v.radius + v.handle_len / 2
    return {
        "radius": v.radius,
        "height": v.height,
        "handle_points": [[-hx, 0.0, hz], [hx, 0.0, hz]],  # contact points 0 (left, -x) and 1 (+x)
        "handle_size": [v.handle_len, v.handle_width, v.handle_thick],  # radial, tangential, vertical
        "span_with_handles": 2 * (v.radius + v.handle_len),
        "mass_kg": v.mass,
        "up_axis": [0.0, 0.0, 1.0],
    }


@lru_cache(maxsize=64)
def _pot_meshes(v: PotVariant, model_id: int, where: str) -> dict[str, str]:
    """The pot's round visual meshes (outer wall, inner lining, rolled rim, inner floor) as OBJ
    assets, written once per variant and cache folder (exporting them dominates a scene build)."""
    import trimesh

    R, H, t = v.radius, v.height, v.wall
    outer = trimesh.creation.annulus(R - t * 0.5, R, H, sections=64)
    outer.apply_translation((0.0, 0.0, H / 2))
    lining = trimesh.creation.annulus(R - t, R - t * 0.5, H - v.bottom - 0.002, sections=64)
    lining.apply_translation((0.0, 0.0, v.bottom + (H - v.bottom - 0.002) / 2))
    rim = trimesh.creation.annulus(R - t - 0.001, R + 0.003, 0.006, sections=64)  # a rolled lip, 1 mm proud
    rim.apply_translation((0.0, 0.0, H - 0.002))
    floor = trimesh.creation.cylinder(R - t, 0.001, sections=64)
    floor.apply_translation((0.0, 0.0, v.bottom + 0.0005))
    return {name: mesh_asset(f"pot{model_id}_{name}", mesh)
            for name, mesh in (("wall", outer), ("lining", lining), ("rim", rim), ("floor", floor))}


def pot_shapes(v: PotVariant, model_id: int) -> list[Shape]:
    """Bottom disc and a ring of wall boxes (collision), a smooth wall and rim (visual meshes), and
    the two handle tabs (boxes) with a rounded end."""
    body = _mat(v.body_rgb, roughness=0.3 if v.metallic else 0.35, metallic=0.85 if v.metallic else 0.0)
    inner = _mat(tuple(min(1.0, c * 1.1 + 0.05) for c in v.body_rgb) if v.metallic else (0.85, 0.85, 0.83),
                 roughness=0.4, metallic=0.6 if v.metallic else 0.0)
    handle = _mat(v.handle_rgb, roughness=0.5, metallic=0.7 if v.metallic else 0.0, friction=GRIP_FRICTION)
    R, H, t = v.radius, v.height, v.wall
    shapes = [Shape(Cylinder(R, v.bottom / 2), pose=(0.0, 0.0, v.bottom / 2, *X_TO_Z), material=body, visual=False),
              Shape(Cylinder(R - 0.0015, v.bottom / 2), pose=(0.0, 0.0, v.bottom / 2, *X_TO_Z), material=body,
                    collision=False)]
    # collision wall: boxes around the circle (tangential width covers the chord with overlap)
    n = POT_WALL_SEGMENTS
    seg_w = 2 * R * np.tan(np.pi / n) * 1.05
    wall_h = H - v.bottom
    for i in range(n):
        a = 2 * np.pi * i / n
        c, s = np.cos(a / 2), np.sin(a / 2)
        shapes.append(Shape(Box((t / 2, seg_w / 2, wall_h / 2)),
                            pose=((R - t / 2) * np.cos(a), (R - t / 2) * np.sin(a), v.bottom + wall_h / 2,
                                  float(c), 0.0, 0.0, float(s)), material=body, visual=False))
    meshes = _pot_meshes(v, model_id, str(assets_dir()))
    if not all(os.path.isfile(m) for m in meshes.values()):  # the cache folder was emptied meanwhile
        _pot_meshes.cache_clear()
        meshes = _pot_meshes(v, model_id, str(assets_dir()))
    for name, mat in (("wall", body), ("lining", inner), ("rim", body), ("floor", inner)):
        shapes.append(Shape(Mesh(meshes[name]), material=mat, collision=False))
    g = pot_geometry(v)
    w = v.handle_width
    for sign, point in zip((-1, 1), g["handle_points"]):
        # a flat tab with a rounded end (reaching R + handle_len), 5 mm into the wall so that it is
        # one piece with it, and a rivet plate on the wall (visual)
        x0, x1 = R - 0.005, R + v.handle_len - w / 2
        shapes.append(Shape(Box(((x1 - x0) / 2, w / 2, v.handle_thick / 2)),
                            pose=(sign * (x0 + x1) / 2, 0.0, point[2], *IDENTITY_Q), material=handle))
        shapes.append(Shape(Cylinder(w / 2, v.handle_thick / 2), pose=(sign * x1, 0.0, point[2], *X_TO_Z),
                            material=handle))
        shapes.append(Shape(Box((0.002, w / 2 + 0.006, v.handle_thick / 2 + 0.006)),
                            pose=(sign * (R + 0.001), 0.0, point[2], *IDENTITY_Q), material=handle, collision=False))
    return shapes


# --- the rolling pin ------------------------------------------------------------------------------
@dataclass(frozen=True)
class RollerVariant:
    barrel_radius: float
    barrel_len: float
    handle_radius: float
    handle_len: float
    barrel_rgb: tuple[float, float, float]
    handle_rgb: tuple[float, float, float]
    density: float  # kg/m^3
    neck_len: float = 0.010
    neck_radius: float = 0.008


ROLLER_VARIANTS = {
    0: RollerVariant(0.025, 0.200, 0.014, 0.070, (0.86, 0.70, 0.48), (0.55, 0.34, 0.17), 650.0),  # beech
    # painted white, walnut handles
    2: RollerVariant(0.028, 0.220, 0.015, 0.075, (0.93, 0.93, 0.91), (0.40, 0.24, 0.12), 900.0),
}


def roller_geometry(v: RollerVariant) -> dict[str, Any]:
    hx = v.barrel_len / 2 + v.neck_len + v.handle_len / 2
    return {
        "barrel_radius": v.barrel_radius,
        "barrel_length": v.barrel_len,
        "handle_radius": v.handle_radius,
        "handle_length": v.handle_len,
        "length": v.barrel_len + 2 * (v.neck_len + v.handle_len),
        "handle_points": [[-hx, 0.0, 0.0], [hx, 0.0, 0.0]],  # contact points 0 (-x end) and 1 (+x end)
        "axis": [1.0, 0.0, 0.0],
    }


def roller_shapes(v: RollerVariant) -> list[Shape]:
    """Barrel, two necks and two handles, cylinders along local x, with rounded handle ends."""
    barrel = _mat(v.barrel_rgb, roughness=0.7)
    handle = _mat(v.handle_rgb, roughness=0.6, friction=GRIP_FRICTION)
    shapes = [Shape(Cylinder(v.barrel_radius, v.barrel_len / 2), material=barrel)]
    for sign in (-1, 1):
        neck_x = v.barrel_len / 2 + v.neck_len / 2
        hx = v.barrel_len / 2 + v.neck_len + v.handle_len / 2
        shapes.append(Shape(Cylinder(v.neck_radius, v.neck_len / 2 + 0.002), pose=(sign * neck_x, 0, 0, *IDENTITY_Q),
                            material=handle))
        shapes.append(Shape(Cylinder(v.handle_radius, v.handle_len / 2), pose=(sign * hx, 0, 0, *IDENTITY_Q),
                            material=handle))
        # a flat cap ring marks each handle's end (visual)
        shapes.append(Shape(Cylinder(v.handle_radius + 0.0015, 0.003),
                            pose=(sign * (hx + v.handle_len / 2 - 0.003), 0, 0, *IDENTITY_Q), material=handle,
                            collision=False))
    return shapes


# --- the sauce can --------------------------------------------------------------------------------
@dataclass(frozen=True)
class CanVariant:
    radius: float
    height: float
    label_rgb: tuple[float, float, float]
    band_rgb: tuple[float, float, float]
    mass: float


CAN_VARIANTS = {
    0: CanVariant(0.033, 0.105, (0.80, 0.10, 0.08), (0.95, 0.85, 0.20), 0.40),  # tomato sauce
    2: CanVariant(0.031, 0.095, (0.15, 0.50, 0.20), (0.95, 0.95, 0.90), 0.32),  # pesto
    4: CanVariant(0.034, 0.110, (0.95, 0.65, 0.10), (0.55, 0.10, 0.10), 0.42),  # curry sauce
    5: CanVariant(0.032, 0.100, (0.35, 0.12, 0.10), (0.90, 0.80, 0.60), 0.36),  # barbecue sauce
    6: CanVariant(0.030, 0.090, (0.90, 0.90, 0.85), (0.20, 0.35, 0.75), 0.30),  # white sauce
}


def can_geometry(v: CanVariant) -> dict[str, Any]:
    return {
        "radius": v.radius,
        "height": v.height,
        "axis_local": [0.0, 1.0, 0.0],
        "center_local": [0.0, v.height / 2, 0.0],
        "top_local": [0.0, v.height, 0.0],
        "mass_kg": v.mass,
    }


def can_shapes(v: CanVariant) -> list[Shape]:
    """A steel cylinder (axis local +y) with a paper label, a coloured band and rolled rims."""
    steel = _mat((0.74, 0.75, 0.77), roughness=0.3, metallic=0.9, friction=GRIP_FRICTION)
    label = _mat(v.label_rgb, roughness=0.6)
    band = _mat(v.band_rgb, roughness=0.6)
    r, h = v.radius, v.height
    rim = 0.004
    shapes = [
        Shape(Cylinder(r - 0.001, h / 2), pose=(0.0, h / 2, 0.0, *X_TO_Y), material=steel),
        # rims (collision: what the can stands on and what the fingers meet first)
        Shape(Cylinder(r, rim / 2), pose=(0.0, rim / 2, 0.0, *X_TO_Y), material=steel),
        Shape(Cylinder(r, rim / 2), pose=(0.0, h - rim / 2, 0.0, *X_TO_Y), material=steel),
        # label and band (visual, a hair outside the wall)
        Shape(Cylinder(r - 0.0002, (h - 2 * rim - 0.006) / 2), pose=(0.0, h / 2, 0.0, *X_TO_Y), material=label,
              collision=False),
        Shape(Cylinder(r, 0.009), pose=(0.0, h * 0.58, 0.0, *X_TO_Y), material=band, collision=False),
    ]
    return shapes
