"""Isolation conformance: bodies far away change nothing.

A world's own bodies must move the same whether or not other bodies, touching none of them, are in
the scene (an attempt under ``randomize=distractors`` adds some; a verdict must not change because
of them). Physics engines do not promise bit-identical results: adding bodies changes the order in
which a solver visits its contacts, and float32 rounding then differs in the last bit. What must
hold is that such differences stay at rounding size: a simulator whose contacts amplify them (a
contact that throws a body when a penetration crosses a threshold) turns them into a different
outcome (issue 26: three small bodies 30 cm away decided whether a pinched vessel was thrown off
the table, because a wrong deep contact was removed at unbounded speed).

:func:`check_isolation` builds one world twice, once as given and once with :func:`far_bodies`
added (boxes, cylinders, spheres and a small stack, dynamic, resting on the ground at least
``FAR_M`` beyond the reach of everything in the scene, found from the scene description alone),
drives the same motion in both and requires every body and articulated object of the world to
follow the same trajectory within ``TOLERANCE_M`` (position) and ``TOLERANCE_RAD`` (orientation) at
every sample. In the simulator conformance run (``pytest --cab-conformance=sims``,
``sim_conformance.check_isolation``) the world is :mod:`cab_core.testing.sim_conformance`'s with a
tower of three boxes and a ball in a box-walled tray on its table (:func:`isolation_scene`: resting
and nested contacts), its arm sweeping and opening and closing the gripper; 1-6 s per simulator.
By hand::

    from cab_core.testing import sim_conformance as sc

    sc.check_isolation(lambda: MySimulator({"render": False}))
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from cab_core.contracts.scene import Body, Box, Capsule, Cylinder, Material, Mesh, SceneSpec, Shape, Sphere
from cab_core.contracts.simulator import Simulator
from cab_core.geometry import quat_angle

SimFactory = Callable[[], Simulator]

FAR_M = 0.5  # extra bodies stand this far beyond the reach of every body of the world
TOLERANCE_M = 1e-3  # largest allowed difference of a world body's position at any sample
TOLERANCE_RAD = 1e-2  # ... and of its orientation
STEPS = 500  # physics steps of the motion (2 s at 1/250 s)
SAMPLE_EVERY = 25  # steps between two comparisons
_MESH_REACH_M = 0.5  # a mesh's reach, unknown without reading the file: assumed, times its scale


def _shape_reach(shape: Shape) -> float:
    """Distance from the body's origin that ``shape`` reaches at most."""
    g = shape.geometry
    if isinstance(g, Box):
        r = float(np.linalg.norm(g.half_size))
    elif isinstance(g, Sphere):
        r = float(g.radius)
    elif isinstance(g, (Cylinder, Capsule)):
        r = float(math.hypot(g.radius, g.half_length + (g.radius if isinstance(g, Capsule) else 0.0)))
    elif isinstance(g, Mesh):
        r = _MESH_REACH_M * float(max(abs(s) for s in g.scale))
    else:  # a geometry this check does not know: keep well clear
        r = 1.0
    return r + float(np.linalg.norm(shape.pose[:3]))


def world_extent(scene: SceneSpec, also: Sequence[tuple[float, float]] = ()) -> tuple[np.ndarray, float]:
    """Centre (x, y) and radius of a vertical cylinder holding every body and articulated object of
    ``scene`` (articulated objects: ``_MESH_REACH_M`` around their root) and the points ``also``."""
    pts, radii = [], []
    for b in scene.bodies:
        pts.append(np.asarray(b.pose[:2], float))
        radii.append(max((_shape_reach(s) for s in b.shapes), default=0.0))
    for a in scene.articulations:
        pts.append(np.asarray(a.pose[:2], float))
        radii.append(_MESH_REACH_M)
    for p in also:
        pts.append(np.asarray(p[:2], float))
        radii.append(0.0)
    if not pts:
        return np.zeros(2), 0.0
    centre = np.mean(pts, axis=0)
    return centre, max(float(np.linalg.norm(p - centre)) + r for p, r in zip(pts, radii))


def far_bodies(scene: SceneSpec, also: Sequence[tuple[float, float]] = (), far: float = FAR_M,
               prefix: str = "isolation_extra") -> list[Body]:
    """Dynamic bodies resting on the ground (``scene.ground_z``), each at least ``far`` beyond the
    reach of everything in ``scene`` and of the points ``also`` (e.g. the robot's base): a box, a
    cylinder, a sphere, and a box standing on a box, spread around the world."""
    centre, radius = world_extent(scene, also)
    ring = radius + far + 0.1  # 0.1: the extra bodies' own reach
    z = float(scene.ground_z)
    mat = Material(color=(0.8, 0.5, 0.2, 1.0), static_friction=0.8, dynamic_friction=0.8)
    up = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)  # a cylinder's x axis -> world z
    kinds = [
        [(Shape(Box((0.03, 0.03, 0.03)), material=mat), 0.03, (1.0, 0.0, 0.0, 0.0))],
        [(Shape(Cylinder(0.03, 0.04), material=mat), 0.03, up)],
        [(Shape(Sphere(0.03), material=mat), 0.03, (1.0, 0.0, 0.0, 0.0))],
        [(Shape(Box((0.04, 0.04, 0.02)), material=mat), 0.02, (1.0, 0.0, 0.0, 0.0)),
         (Shape(Box((0.02, 0.02, 0.02)), material=mat), 0.06, (1.0, 0.0, 0.0, 0.0))],
    ]
    out = []
    for i, parts in enumerate(kinds):
        a = 2 * math.pi * i / len(kinds) + math.pi / 4
        xy = centre + ring * np.array([math.cos(a), math.sin(a)])
        for j, (shape, h, q) in enumerate(parts):  # h: the centre's height above the ground
            name = f"{prefix}_{i}" + (f"_{j}" if j else "")
            out.append(Body(name, [shape], pose=(float(xy[0]), float(xy[1]), z + h + 0.0005, *q),
                            kind="dynamic", density=500.0))
    return out


def with_far_bodies(scene: SceneSpec, also: Sequence[tuple[float, float]] = (), far: float = FAR_M) -> SceneSpec:
    """A copy of ``scene`` with :func:`far_bodies` appended (the original is left as it is)."""
    names = set(scene.names())
    extra = [b for b in far_bodies(scene, also, far) if b.name not in names]
    return replace(scene, bodies=list(scene.bodies) + extra)


def isolation_scene(scene: SceneSpec, table_top: float) -> SceneSpec:
    """``scene`` (the simulator conformance world) plus resting and nested contacts on its table
    (top at ``table_top``), out of its arm's reach: a tower of three boxes and a ball in a tray of
    four box walls on a floor."""
    top = table_top
    wood = Material(color=(0.6, 0.5, 0.3, 1.0), static_friction=0.6, dynamic_friction=0.5)
    tower = [Body(f"tower_{k}", [Shape(Box((0.02, 0.02, 0.015)), material=wood)],
                  pose=(0.28, 0.02, top + 0.015 + 0.03 * k + 0.0005 * (k + 1), 1, 0, 0, 0), mass=0.03)
             for k in range(3)]
    tray = Body("tray", [Shape(Box((0.05, 0.05, 0.004)), material=wood, pose=(0, 0, 0.004, 1, 0, 0, 0))]
                + [Shape(Box(h), material=wood, pose=(*xy, 0.02, 1, 0, 0, 0)) for h, xy in (
                    ((0.004, 0.05, 0.02), (0.046, 0.0)), ((0.004, 0.05, 0.02), (-0.046, 0.0)),
                    ((0.05, 0.004, 0.02), (0.0, 0.046)), ((0.05, 0.004, 0.02), (0.0, -0.046)))],
                pose=(-0.33, -0.08, top + 0.0005, 1, 0, 0, 0), mass=0.08)
    marble = Body("marble", [Shape(Sphere(0.015), material=wood)], pose=(-0.33, -0.08, top + 0.024, 1, 0, 0, 0),
                  mass=0.02, angular_damping=0.2)
    return replace(scene, bodies=list(scene.bodies) + tower + [tray, marble])


def _trajectory(sim: Simulator, names: list[str], motion: Callable[[Simulator, int, int], None] | None,
                steps: int, every: int) -> list[dict[str, np.ndarray]]:
    out = []
    for start in range(0, steps, every):
        n = min(every, steps - start)
        if motion is None:
            sim.step(n)
        else:
            motion(sim, n, start)
        out.append({name: np.asarray(sim.get_object_pose(name), float) for name in names})
    return out


def check_isolation(factory: SimFactory, scene: SceneSpec, embodiment,
                    motion: Callable[[Simulator, int, int], None] | None = None, steps: int = STEPS,
                    every: int = SAMPLE_EVERY, tolerance_m: float = TOLERANCE_M,
                    tolerance_rad: float = TOLERANCE_RAD) -> dict:
    """The world ``scene`` + ``embodiment``'s bodies follow the same trajectory with and without
    far-away extra bodies. ``motion(sim, n, start)`` drives ``n`` steps from step ``start`` (None:
    the world just runs). Compares every body and articulated object of ``scene`` each ``every``
    steps. Returns the largest differences seen (``max_m``, ``max_rad``, ``body``).
    :func:`cab_core.testing.sim_conformance.check_isolation` runs it on the conformance world
    (:func:`isolation_scene`, the arm driven by its motion script)."""
    crowded = with_far_bodies(scene, also=[tuple(embodiment.base_pose[:2])])
    names = scene.names()
    runs = []
    for spec in (scene, crowded):
        sim = factory()
        try:
            sim.build(spec, embodiment)
            assert sim.object_names()[:len(scene.bodies)] == names[:len(scene.bodies)], sim.object_names()
            runs.append(_trajectory(sim, names, motion, steps, every))
        finally:
            sim.close()
    worst_m, worst_rad, where = 0.0, 0.0, ""
    for k, (a, b) in enumerate(zip(*runs)):
        for name in names:
            dm = float(np.linalg.norm(a[name][:3] - b[name][:3]))
            dr = float(quat_angle(a[name][3:], b[name][3:]))
            if dm > tolerance_m or dr > tolerance_rad:
                raise AssertionError(
                    f"{name} moved differently with far-away bodies in the scene: {dm * 1000:.3f} mm and "
                    f"{math.degrees(dr):.3f} deg apart after step {min((k + 1) * every, steps)} (tolerance "
                    f"{tolerance_m * 1000:g} mm, {math.degrees(tolerance_rad):g} deg)")
            if dm > worst_m or dr > worst_rad:
                worst_m, worst_rad, where = max(dm, worst_m), max(dr, worst_rad), name
    return {"max_m": worst_m, "max_rad": worst_rad, "body": where}
