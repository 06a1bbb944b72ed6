"""The scene vocabulary of a table-top task: the world's constants, colours and materials, the
base scene (table, wall, lighting), the seeded pose sampler and small pose helpers.

World frame: metres, z up, the ground at z = 0, +y away from the robot toward the wall, -x on the
left arm's side; poses are [x, y, z, qw, qx, qy, qz] (quaternions w first, as in
:mod:`cab_core.geometry`); angles in radians. The head camera and the robot belong to the
embodiment, not to the task's scene.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from cab_core.contracts.scene import Body, Box, Capsule, Cylinder, Lighting, Material, SceneSpec, Shape, Sphere
from cab_core.errors import CabError
from cab_core.geometry import euler_quat, quat_mul, quat_normalize, quat_to_mat

# --- world constants -----------------------------------------------------------------------------
TABLE_TOP_Z = 0.74
TABLE_SIZE = (1.2, 0.7, 0.05)  # x, y, thickness
WALL_CENTER = (0.0, 1.0, 1.5)
WALL_HALF_SIZE = (3.0, 0.6, 1.5)  # near face at y = 0.4
DEFAULT_SPAWN_Z = 0.741  # rand_pose's default z
DESTRUCTIVE_DROP = 0.08  # a guarded object below table_z - 0.08 is knocked off
ARMS = ("left", "right")
IDENTITY_Q = (1.0, 0.0, 0.0, 0.0)


class LayoutError(CabError):
    """No layout satisfying a task's placement constraints was found."""


# --- colours -----------------------------------------------------------------------------------
def srgb(r: float, g: float, b: float, a: float = 1.0) -> tuple[float, float, float, float]:
    """Linear RGBA (what :class:`Material` holds) from display sRGB components in 0..1."""
    def lin(c: float) -> float:
        return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4

    return (round(lin(r), 5), round(lin(g), 5), round(lin(b), 5), a)


def material(rgb: Sequence[float], *, roughness: float = 0.6, metallic: float = 0.0, friction: float = 0.5) -> Material:
    """A material of the display-sRGB colour ``rgb`` whose static and dynamic friction are both
    ``friction`` (the defaults are :class:`Material`'s)."""
    return Material(color=srgb(*rgb), roughness=roughness, metallic=metallic, static_friction=friction,
                    dynamic_friction=friction)


WOOD = Material(color=srgb(0.66, 0.47, 0.30), roughness=0.7)
WOOD_DARK = Material(color=srgb(0.42, 0.28, 0.16), roughness=0.7)
WALL = Material(color=srgb(0.86, 0.86, 0.84), roughness=0.9)
RED = Material(color=srgb(0.85, 0.10, 0.10), roughness=0.5)
GREEN = Material(color=srgb(0.10, 0.70, 0.15), roughness=0.5)
BLUE = Material(color=srgb(0.10, 0.25, 0.90), roughness=0.5)


# --- table, wall, lighting ---------------------------------------------------------------------
def table_top_z(z_bias: float = 0.0) -> float:
    """The height of the table's top surface (m), raised by ``z_bias``."""
    return TABLE_TOP_Z + z_bias


def table(x_bias: float = 0.0, z_bias: float = 0.0, legs: bool = True) -> Body:
    """The static table ``"table"``: a 1.2 x 0.7 x 0.05 m top whose surface is at 0.74 + z_bias,
    centred at (x_bias, 0); optional legs down to the ground (same body)."""
    sx, sy, th = TABLE_SIZE
    top = table_top_z(z_bias)
    shapes = [Shape(Box((sx / 2, sy / 2, th / 2)), material=WOOD)]
    if legs:
        leg_h = top - th
        for lx in (-1, 1):
            for ly in (-1, 1):
                shapes.append(Shape(
                    Box((0.025, 0.025, leg_h / 2)),
                    pose=(lx * (sx / 2 - 0.06), ly * (sy / 2 - 0.06), -th / 2 - leg_h / 2, 1.0, 0.0, 0.0, 0.0),
                    material=WOOD_DARK))
    return Body("table", shapes, pose=(x_bias, 0.0, top - th / 2, 1.0, 0.0, 0.0, 0.0), kind="static")


def wall() -> Body:
    """The static back wall ``"wall"``: centre (0, 1, 1.5), half-size (3, 0.6, 1.5); near face y = 0.4."""
    return Body("wall", [Shape(Box(WALL_HALF_SIZE), material=WALL)], pose=(*WALL_CENTER, 1.0, 0.0, 0.0, 0.0),
                kind="static")


def lighting() -> Lighting:
    """Ambient 0.5, one directional light, point lights at (+-1, 0, 1.8)."""
    return Lighting(
        ambient=(0.5, 0.5, 0.5),
        directional=(((0.0, 0.5, -1.0), (0.5, 0.5, 0.5)),),
        points=(((1.0, 0.0, 1.8), (1.0, 1.0, 1.0)), ((-1.0, 0.0, 1.8), (1.0, 1.0, 1.0))),
    )


def base_scene(table_x: float = 0.0, table_z_bias: float = 0.0, legs: bool = True) -> SceneSpec:
    """Table + wall + lighting at the benchmark's 1/250 s timestep."""
    return SceneSpec(bodies=[table(table_x, table_z_bias, legs), wall()], lighting=lighting(),
                     timestep=1.0 / 250.0)


# --- sampling ----------------------------------------------------------------------------------
def rand_pose(rng: np.random.Generator, xlim: Sequence[float], ylim: Sequence[float],
              zlim: Sequence[float] = (DEFAULT_SPAWN_Z,), *, ylim_prop: bool = False,
              rotate_rand: bool = False, rotate_lim: Sequence[float] = (0.0, 0.0, 0.0),
              qpos: Sequence[float] = IDENTITY_Q) -> np.ndarray:
    """RoboTwin's ``rand_pose`` over ``rng``: uniform x, y, z in their limits (a one-element limit
    is fixed); with ``ylim_prop``, while |x| < 0.15 and y > 0, y is redrawn in [ylim[0], 0]; the
    random Euler rotation (static x-y-z, each within +-rotate_lim radians) is composed after the
    base quaternion ``qpos`` (in its local frame). Returns [x, y, z, qw, qx, qy, qz]."""
    def uni(lim: Sequence[float]) -> float:
        lim = tuple(float(v) for v in lim)
        return lim[0] if len(lim) == 1 else float(rng.uniform(lim[0], lim[1]))

    x, y = uni(xlim), uni(ylim)
    while ylim_prop and abs(x) < 0.15 and y > 0:
        y = float(rng.uniform(float(ylim[0]), 0.0))
    z = uni(zlim)
    q = quat_normalize(qpos)
    if rotate_rand:
        angles = [float(rng.uniform(-lim, lim)) if lim > 0 else 0.0 for lim in rotate_lim]
        q = quat_normalize(quat_mul(q, euler_quat(*angles)))
    if q[0] < 0:
        q = -q
    return np.array([x, y, z, *q], dtype=float)


def draw_variant(rng: np.random.Generator, variants: Any, ids: Sequence[int] | None = None) -> tuple[int, Any]:
    """A model id drawn uniformly from ``ids`` (by default every index of the sequence ``variants``)
    with one ``rng.integers`` draw, and its entry in ``variants``."""
    ids = range(len(variants)) if ids is None else ids
    model_id = int(ids[int(rng.integers(0, len(ids)))])
    return model_id, variants[model_id]


def sample_until(draw: Callable[[], np.ndarray], accept: Callable[[np.ndarray], bool], *,
                 what: str, max_tries: int = 10_000) -> np.ndarray:
    """Redraw until ``accept`` holds (RoboTwin's resample-until loops), failing loudly
    (:class:`LayoutError`)."""
    for _ in range(max_tries):
        p = draw()
        if accept(p):
            return p
    raise LayoutError(f"no valid placement for {what} after {max_tries} draws")


# --- poses -------------------------------------------------------------------------------------
def yaw_of(q: Sequence[float]) -> float:
    """Heading (rotation about world z, radians) of the body's local x axis."""
    m = quat_to_mat(q)
    return float(np.arctan2(m[1, 0], m[0, 0]))


def pose_list(p: Iterable[float]) -> list[float]:
    """A pose (or any vector) as a JSON-friendly list of floats rounded to the micrometre."""
    return [round(float(v), 6) for v in p]


vec = pose_list


def body_pose(xyz: Sequence[float], quat: Sequence[float] = IDENTITY_Q) -> tuple[float, ...]:
    """A pose (x, y, z, qw, qx, qy, qz) as a tuple of floats."""
    return tuple(float(v) for v in (*xyz, *quat))


# --- geometry of shape lists -------------------------------------------------------------------
def lowest_point_z(shapes: Sequence[Shape], quat: Sequence[float] = IDENTITY_Q) -> float:
    """Lowest z, in a frame rotated by ``quat`` about the body origin, over all collision shapes
    (boxes, spheres, capsules, cylinders). The body rests on a plane at height h when its origin
    is at h - lowest_point_z(...)."""
    r_body = quat_to_mat(quat)
    low = np.inf
    for s in shapes:
        if not s.collision:
            continue
        r = r_body @ quat_to_mat(s.pose[3:7])
        c = r_body @ np.asarray(s.pose[:3], dtype=float)
        g = s.geometry
        if isinstance(g, Box):
            h = np.asarray(g.half_size)
            low = min(low, c[2] - float(np.abs(r[2, :]) @ h))
        elif isinstance(g, Sphere):
            low = min(low, c[2] - g.radius)
        elif isinstance(g, Capsule):
            low = min(low, c[2] - abs(r[2, 0]) * g.half_length - g.radius)
        elif isinstance(g, Cylinder):
            az = abs(r[2, 0])  # axis along local x
            low = min(low, c[2] - az * g.half_length - g.radius * np.sqrt(max(0.0, 1 - az * az)))
        else:
            raise TypeError(f"lowest_point_z does not handle {type(g).__name__}")
    return float(low)


def body_reach(body: Body) -> float:
    """How far a body reaches from its origin in the table plane, roughly (a mesh: 0.15 m)."""
    r = 0.0
    for s in body.shapes:
        g = s.geometry
        off = float(np.linalg.norm(np.asarray(s.pose[:2], float)))
        if isinstance(g, Box):
            r = max(r, off + float(np.linalg.norm(g.half_size[:2])))
        elif isinstance(g, (Cylinder, Sphere, Capsule)):
            r = max(r, off + float(g.radius) + (float(g.half_length) if isinstance(g, Capsule) else 0.0))
        else:
            r = max(r, off + 0.15)
    return r
