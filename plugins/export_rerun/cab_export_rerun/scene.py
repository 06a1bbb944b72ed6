"""The scene's geometry in the Rerun export: every body's visual shapes, logged once (static) in the
body's own frame under the entity whose transform is the body's recorded pose, so that the 3D view
replays the attempt.

Where the geometry comes from: the task's scene instance rebuilt from the record's task, seed and
embodiment (:func:`cab_core.kits.registry.task_instance`, no simulator), plus the distractors an
appearance randomisation added (their shape, size and colour are in ``privileged/scene_info.json``).
A perturbation moves objects and scales physical parameters, never a shape, and the poses come from
the snapshots anyway. Articulated objects are read from their URDF (one entity per link, under the
link's recorded pose). The robot is not drawn: the snapshots hold each arm's TCP pose, no link poses.

Entity paths::

    world/objects/<body>/shape_<i>                 shape i of the body (its local pose: static)
    world/object_links/<object>/<link>/visual_<i>  visual i of an articulated object's link
    world/objects/<object>/<root link>/visual_<i>  the root link's visuals (a root link has no recorded pose
                                                   of its own: it is the object's)

Shapes: a box as ``Boxes3D``, a sphere as ``Ellipsoids3D``, a capsule as ``Capsules3D``, a cylinder as
``Cylinders3D`` and a mesh (an OBJ file, read with trimesh) as ``Mesh3D``, all solid, in the shape's colour.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cab_core.contracts.scene import Body, Box, Capsule, Cylinder, Material, Mesh, Shape, Sphere
from cab_core.errors import RecordError
from cab_core.geometry import euler_quat
from cab_core.kits.assets import trimesh_module
from cab_core.kits.registry import task_instance

#: the rotation that takes +z to +x: Rerun's capsules and cylinders lie along z, the scene description's
#: along x. (x, y, z, w): 90 degrees about +y
Z_TO_X = np.array([0.0, math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4)])
DEFAULT_RGBA = (0.7, 0.7, 0.7, 1.0)


@dataclass
class Part:
    """One visual shape to log: ``kind`` box | sphere | capsule | cylinder | mesh; ``size``: the box's
    half sizes, (radius,), (radius, half length) along x, or the mesh's scale; ``pose`` in the frame
    of the entity above it (cab's ``[x, y, z, qw, qx, qy, qz]``); ``mesh``: the OBJ file."""
    kind: str
    size: tuple[float, ...]
    pose: tuple[float, ...]
    rgba: tuple[float, ...]
    mesh: str | None = None
    axis: str = "x"  # a cylinder's axis: x (the scene description), z (URDF)


def _srgb(rgba) -> list[float]:
    """Linear RGBA (the scene description's colours) as the sRGB values Rerun shows."""
    out = [float(c) * 12.92 if c <= 0.0031308 else 1.055 * float(c) ** (1 / 2.4) - 0.055 for c in rgba[:3]]
    return [min(max(c, 0.0), 1.0) for c in out] + [float(rgba[3]) if len(rgba) > 3 else 1.0]


def _xyzw(pose) -> np.ndarray:
    w, x, y, z = (float(v) for v in pose[3:7])
    return np.array([x, y, z, w])


def shape_part(shape: Shape) -> Part | None:
    """The part of a scene shape (None: a collision-only shape, not drawn)."""
    if not shape.visual:
        return None
    g, rgba, pose = shape.geometry, tuple(shape.material.color), tuple(shape.pose)
    if isinstance(g, Box):
        return Part("box", tuple(g.half_size), pose, rgba)
    if isinstance(g, Sphere):
        return Part("sphere", (g.radius,), pose, rgba)
    if isinstance(g, Capsule):
        return Part("capsule", (g.radius, g.half_length), pose, rgba)
    if isinstance(g, Cylinder):
        return Part("cylinder", (g.radius, g.half_length), pose, rgba)
    if isinstance(g, Mesh):
        return Part("mesh", tuple(g.scale), pose, rgba, mesh=g.path)
    raise TypeError(f"a shape of an unknown geometry: {g!r}")


def distractor_bodies(scene_info: dict) -> list[Body]:
    """The distractors an appearance randomisation placed (``randomization.distractors.placed``:
    name, shape, drawn size and colour), as the randomisation builds them."""
    placed = ((scene_info.get("randomization") or {}).get("distractors") or {}).get("placed") or []
    out = []
    for d in placed:
        s, rgb = float(d["size_m"]), tuple(float(c) for c in d["color"])
        geom = {"box": Box((s, s, s)), "cylinder": Cylinder(s, s), "sphere": Sphere(s)}[str(d["shape"])]
        out.append(Body(str(d["name"]), [Shape(geom, material=Material(color=(*rgb, 1.0)))]))
    return out


# -- URDF --------------------------------------------------------------------------------------
def _floats(text: str | None, n: int, default: float = 0.0) -> tuple[float, ...]:
    vals = [float(v) for v in (text or "").split()]
    return tuple(vals + [default] * (n - len(vals)))[:n]


def urdf_links(urdf: str) -> tuple[str | None, dict[str, list[Part]]]:
    """``(root link, {link: its visual parts})`` of a URDF file: boxes, cylinders (along the link's z),
    spheres and meshes, each at its ``<origin>``, in its ``<material>``'s colour (inline or named at the
    robot's level)."""
    robot = ET.parse(urdf).getroot()
    named = {m.get("name"): _floats(c.get("rgba"), 4, 1.0) for m in robot.findall("material")
             if (c := m.find("color")) is not None}
    links: dict[str, list[Part]] = {}
    for link in robot.findall("link"):
        parts = links.setdefault(str(link.get("name")), [])
        for vis in link.findall("visual"):
            o = vis.find("origin")
            xyz = _floats(o.get("xyz") if o is not None else None, 3)
            rpy = _floats(o.get("rpy") if o is not None else None, 3)
            pose = (*xyz, *(float(v) for v in euler_quat(*rpy)))
            mat, rgba = vis.find("material"), DEFAULT_RGBA
            if mat is not None:
                c = mat.find("color")
                rgba = _floats(c.get("rgba"), 4, 1.0) if c is not None else named.get(mat.get("name"), DEFAULT_RGBA)
            geom = vis.find("geometry")
            for g in list(geom) if geom is not None else []:
                if g.tag == "box":
                    parts.append(Part("box", tuple(v / 2 for v in _floats(g.get("size"), 3)), pose, rgba))
                elif g.tag == "sphere":
                    parts.append(Part("sphere", (float(g.get("radius", 0)),), pose, rgba))
                elif g.tag == "cylinder":
                    parts.append(Part("cylinder", (float(g.get("radius", 0)), float(g.get("length", 0)) / 2),
                                      pose, rgba, axis="z"))
                elif g.tag == "mesh":
                    path = str(Path(urdf).parent / str(g.get("filename", "")).removeprefix("file://"))
                    parts.append(Part("mesh", _floats(g.get("scale"), 3, 1.0), pose, rgba, mesh=path))
    children = {j.find("child").get("link") for j in robot.findall("joint") if j.find("child") is not None}
    roots = [name for name in links if name not in children]
    return (roots[0] if roots else None), links


# -- logging -----------------------------------------------------------------------------------
def _mesh(path: str, scale) -> Any:
    m = trimesh_module().load(path, force="mesh")
    m.apply_scale(np.asarray(scale, float))
    return m


def part_archetype(rr, p: Part):
    """The Rerun archetype that draws ``p`` in its own frame."""
    color = [_srgb(p.rgba)]
    if p.kind == "box":
        return rr.Boxes3D(half_sizes=[p.size], colors=color, fill_mode="solid")
    if p.kind == "sphere":
        return rr.Ellipsoids3D(half_sizes=[[p.size[0]] * 3], colors=color, fill_mode="solid")
    if p.kind == "capsule":  # from its origin along +z: moved back by half its length
        r, hl = p.size
        return rr.Capsules3D(lengths=[2 * hl], radii=[r], translations=[[-hl, 0.0, 0.0]], quaternions=[Z_TO_X],
                             colors=color, fill_mode="solid")
    if p.kind == "cylinder":  # centred on its origin, along +z
        r, hl = p.size
        return rr.Cylinders3D(lengths=[2 * hl], radii=[r], colors=color, fill_mode="solid",
                              **({"quaternions": [Z_TO_X]} if p.axis == "x" else {}))
    m = _mesh(str(p.mesh), p.size)
    return rr.Mesh3D(vertex_positions=np.asarray(m.vertices, np.float32),
                     triangle_indices=np.asarray(m.faces, np.uint32),
                     vertex_normals=np.asarray(m.vertex_normals, np.float32), albedo_factor=color[0])


def log_parts(w, entity: str, parts: list[Part], prefix: str) -> int:
    """Each part under ``<entity>/<prefix>_<i>`` (static): its local pose and its geometry."""
    rr = w.rr
    for i, p in enumerate(parts):
        path = f"{entity}/{prefix}_{i}"
        w.log(path, rr.Transform3D(translation=np.asarray(p.pose[:3], float), quaternion=_xyzw(p.pose)), static=True)
        w.log(path, part_archetype(rr, p), static=True)
    return len(parts)


def log_scene(w, result: dict, scene_info: dict, snapshots: list[dict]) -> dict[str, int]:
    """Log the scene's geometry; returns ``{entity: parts logged}``. A body that no snapshot poses
    (a record without snapshots) gets its built pose as a static transform."""
    rr = w.rr
    task, seed = scene_info.get("task") or result.get("task"), scene_info.get("seed", result.get("seed"))
    embodiment = result.get("embodiment")
    if not task or seed is None or not embodiment:
        raise RecordError("the record does not name its task, seed and embodiment (result.json, "
                          "privileged/scene_info.json): the scene cannot be rebuilt")
    scene = task_instance(str(task), int(seed), str(embodiment)).scene
    posed = {n for s in snapshots for n in (s.get("objects") or {})}
    posed_links = {(n, link) for s in snapshots for n, o in (s.get("objects") or {}).items() for link in o.get("links") or {}}
    w.rec.reset_time()
    out: dict[str, int] = {}
    for body in [*scene.bodies, *distractor_bodies(scene_info)]:
        entity = f"world/objects/{body.name}"
        if body.name not in posed:
            w.log(entity, rr.Transform3D(translation=np.asarray(body.pose[:3], float), quaternion=_xyzw(body.pose)),
                  static=True)
        out[entity] = log_parts(w, entity, [p for s in body.shapes if (p := shape_part(s)) is not None], "shape")
    for art in scene.articulations:
        obj = f"world/objects/{art.name}"
        if art.name not in posed:
            w.log(obj, rr.Transform3D(translation=np.asarray(art.pose[:3], float), quaternion=_xyzw(art.pose)),
                  static=True)
        root, links = urdf_links(art.urdf)
        for link, parts in links.items():
            if (art.name, link) in posed_links:
                entity = f"world/object_links/{art.name}/{link}"
            elif link == root:
                entity = f"{obj}/{link}"
            else:
                continue  # a link the simulator does not report (none of cab's backends leaves one out)
            out[entity] = log_parts(w, entity, parts, "visual")
    return out
