"""Appearance conformance: every simulator shows each object in the colours its scene declares.

The camera-geometry checks (:mod:`cab_core.testing.sim_conformance`) say where things are in a
picture, not what they look like; an agent that finds objects by colour needs both. This check
renders a task's initial scene (its catalog seed, built as ``cab-gallery`` builds it, settled) from
the head camera and measures, for every visual material of every object, the mean colour of the
pixels that material covers; each must agree with the material's declared colour.

Which pixels are a material's, from the contracts alone (no simulator is named or imported):

1. *geometry*: every visual shape of every object (bodies: the scene's shapes; articulated objects:
   their URDF's ``<visual>`` elements, placed at :meth:`Simulator.get_object_link_pose`) is
   triangulated and rasterised with a depth buffer through the simulator's own camera pose and
   intrinsics (the pinhole model of :mod:`cab_core.geometry`, pixel centres at half-integers),
   which tells for each pixel the nearest object material. Every region is shrunk by
   :data:`ERODE_PX` pixels, so edges (tessellation, anti-aliasing) never count;
2. *visibility*: a second picture with every object teleported far below the ground
   (:meth:`Simulator.set_object_pose`) shows what lies behind them; a pixel counts only where the
   two pictures differ (the robot or anything else in front of an object leaves it unchanged).

A region with at least :data:`MIN_PIXELS` such pixels is measured: its pixels are decoded from sRGB
to linear values and averaged, ``m``, beside the declared linear colour ``d``. Lighting scales and
tints what a simulator shows, so the match is judged in two parts that lighting barely moves:

- *chromaticity*: the angle between ``m`` and ``d`` as RGB vectors (brightness drops out) is at
  most :data:`MAX_HUE_DEG` degrees. Catches a red wall drawn white, a blue cup drawn grey;
- *relative lightness*: ``g = (lum(m) + f) / (lum(d) + f)`` (``f`` = :data:`LIGHT_FLOOR`, so that
  near-black colours give stable figures) is the gain light puts on a surface. Within one picture,
  every region's gain lies within a factor :data:`MAX_GAIN_RATIO` of the picture's median gain.
  Catches a black handle drawn white or a white bowl drawn black, which chromaticity alone cannot
  tell apart (grey is grey).

Tolerances, from the three simulators shipped with the project on all 25 tasks of its suite (75
pictures, 510 measured regions; ``python -m cab_core.testing.appearance_conformance --tasks all``
prints each region's figures): the largest hue angle seen is 5.7 degrees (bound 15), the largest
lightness ratio 2.4 (bound 4: lit and shaded faces of one object differ that much), but for a
microwave's buttons at 3.1 on one simulator: its URDF gives two colours the same material name
(buttons and knob), and one simulator takes the last definition for both, another the first. A
simulator that drew a link's collision shapes in white over the body's own shapes (issue 26, item
13) failed four tasks: a pot's black handles at 32 times the picture's median lightness and its
red wall 24 degrees off in hue (a white band), another pot at 33 degrees and 7.6 times, a black
skillet at 29 times and a basket at 17 times. What the bounds cannot see: a colour off by less
than a factor 4 in lightness at the same hue (a mid grey drawn light grey). Shapes with a texture
image are not judged (``sim_conformance.check_textures`` is about them), nor is the robot.

Cost: a build, a settle and two renders per task and simulator, plus the rasterisation: 2 to 4 s a
task on a shared 2-core CPU; all 25 tasks on the three simulators took 3 min 45 s.
``pytest --cab-conformance=sims`` runs :func:`check_appearance` (check ``appearance``) on a representative
set (:func:`representative_tasks`: the fewest tasks whose initial scenes hold between them a body
of more collision shapes than some engines put on one link (one with a near-black colour too), a
body of more visual shapes than that, a body of three or more colours, an articulated object, a
near-black and a saturated colour, topped up to :data:`REPRESENTATIVE_COUNT` by the tasks with most
object materials); the environment variable ``CAB_APPEARANCE_TASKS=all`` (or a comma-separated list
of tasks) checks those instead. By hand::

    python -m cab_core.testing.appearance_conformance --sims SIM --tasks all
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from cab_core.config import default_selection
from cab_core.contracts import texturing as tx
from cab_core.contracts.scene import Box, Capsule, Cylinder, Mesh, SceneSpec, Sphere
from cab_core.contracts.simulator import Simulator
from cab_core.errors import ConfigError
from cab_core.geometry import euler_quat, pose_inv, pose_mul, pose_to_mat
from cab_core.plugins import all_tasks, create, registry

SimFactory = Callable[[], Simulator]

#: how many tasks ``pytest --cab-conformance`` renders by default (``CAB_APPEARANCE_TASKS`` overrides)
REPRESENTATIVE_COUNT = 6
#: shapes on one link beyond which some engines split a body into several links
LINK_SHAPES = 16
ENV_TASKS = "CAB_APPEARANCE_TASKS"
CAMERA = "head_camera"
#: pixels each region is shrunk by before it is measured
ERODE_PX = 2
#: fewest pixels a region needs to be measured
MIN_PIXELS = 40
#: largest angle (degrees) between the measured and the declared colour as linear RGB vectors
MAX_HUE_DEG = 15.0
#: largest factor between a region's light gain and the picture's median gain
MAX_GAIN_RATIO = 4.0
#: linear luminance added to measured and declared values before their ratio is taken (ambient
#: light and the renderers' black levels), so that near-black colours give stable gains
LIGHT_FLOOR = 0.01
#: a pixel belongs to an object only where removing the objects changes it by more than this
#: (sum over the three 8-bit channels)
DIFF_MIN = 12
_AWAY_DEPTH_M = 500.0  # how far below the ground the objects go for the background picture


@dataclass
class Region:
    """One material of one object, as measured in one picture."""
    obj: str
    declared: tuple[float, ...]  # linear RGB
    pixels: int = 0
    measured: tuple[float, ...] | None = None  # linear RGB, the mean over its pixels

    @property
    def hue_deg(self) -> float:
        """Angle between measured and declared colour as RGB vectors (degrees)."""
        m, d = np.asarray(self.measured, float), np.asarray(self.declared, float)
        nm, nd = np.linalg.norm(m), np.linalg.norm(d)
        if nm < 1e-6 or nd < 1e-6:
            return 0.0 if nm < 1e-6 and nd < 1e-6 else 90.0
        return math.degrees(math.acos(max(-1.0, min(1.0, float(m @ d / (nm * nd))))))

    @property
    def gain(self) -> float:
        """``(lum(m) + f) / (lum(d) + f)`` with f = :data:`LIGHT_FLOOR`: the light on the region."""
        return (_lum(self.measured) + LIGHT_FLOOR) / (_lum(self.declared) + LIGHT_FLOOR)

    def label(self) -> str:
        return f"{self.obj} {_rgb_text(self.declared)}"


def _lum(rgb) -> float:
    r, g, b = (float(x) for x in rgb)
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def _rgb_text(rgb) -> str:
    return "(" + ", ".join(f"{float(x):.2f}" for x in rgb) + ")"


def srgb_to_linear(img: np.ndarray) -> np.ndarray:
    """8-bit sRGB values to linear 0..1."""
    c = np.asarray(img, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# -- geometry: triangles of every visual shape ------------------------------------------------------

def _primitive_triangles(g) -> np.ndarray:
    """(T, 3, 3) triangles of a primitive in its shape frame (cab's conventions: cylinder and
    capsule axes along local x), or of an OBJ mesh (scaled)."""
    if isinstance(g, Mesh):
        v, f = _read_obj(g.path)
        return v[f] * np.asarray(g.scale, float)
    if isinstance(g, Box):
        v, _, _, t = tx._box(*(float(h) for h in g.half_size))
    elif isinstance(g, Sphere):
        v, _, _, t = tx._sphere(float(g.radius))
    elif isinstance(g, Cylinder):
        v, _, _, t = tx._cylinder(float(g.radius), float(g.half_length))
    elif isinstance(g, Capsule):
        v, _, _, t = tx._capsule(float(g.radius), float(g.half_length))
    else:
        raise TypeError(f"no triangles for {type(g).__name__}")
    return np.asarray(v, float)[np.asarray(t, int)]


_OBJ_CACHE: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def _read_obj(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) and triangles (T, 3) of an OBJ file (polygons as fans)."""
    if path not in _OBJ_CACHE:
        verts, faces = [], []
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                parts = line.split()
                if not parts:
                    continue
                if parts[0] == "v":
                    verts.append([float(x) for x in parts[1:4]])
                elif parts[0] == "f":
                    idx = [int(p.split("/")[0]) for p in parts[1:]]
                    idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                    faces += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
        _OBJ_CACHE[path] = (np.asarray(verts, float).reshape(-1, 3), np.asarray(faces, int).reshape(-1, 3))
    return _OBJ_CACHE[path]


def _transform(tris: np.ndarray, pose) -> np.ndarray:
    T = pose_to_mat(pose)
    return tris @ T[:3, :3].T + T[:3, 3]


def _urdf_visuals(urdf: str) -> list[tuple[str, object, tuple, tuple[float, ...] | None]]:
    """``(link, geometry, pose in the link frame, linear RGB or None)`` of every ``<visual>`` of a
    URDF (geometry as the scene's primitives; URDF cylinders lie along z)."""
    root = ET.parse(urdf).getroot()
    named: dict[str | None, tuple[float, ...]] = {}
    for m in root.findall("material"):
        c = m.find("color")
        if c is not None and m.get("name"):
            named[m.get("name")] = tuple(float(x) for x in c.attrib["rgba"].split()[:3])
    out: list[tuple[str, object, tuple, tuple[float, ...] | None]] = []
    folder = os.path.dirname(os.path.abspath(urdf))
    for link in root.findall("link"):
        for vis in link.findall("visual"):
            o = vis.find("origin")
            xyz = [float(x) for x in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
            rpy = [float(x) for x in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
            pose = tuple(xyz) + tuple(euler_quat(*rpy))
            color = None
            mat = vis.find("material")
            if mat is not None:
                c = mat.find("color")
                color = (tuple(float(x) for x in c.attrib["rgba"].split()[:3]) if c is not None
                         else named.get(mat.get("name")))
            geo = vis.find("geometry")
            if geo is None or len(geo) == 0:
                continue
            g = geo[0]
            shape: object
            if g.tag == "box":
                sx, sy, sz = (float(x) / 2 for x in g.attrib["size"].split())
                shape = Box((sx, sy, sz))
            elif g.tag == "sphere":
                shape = Sphere(float(g.attrib["radius"]))
            elif g.tag == "cylinder":  # along z: turn the scene's x-axis cylinder onto z
                shape = Cylinder(float(g.attrib["radius"]), float(g.attrib["length"]) / 2)
                pose = tuple(pose_mul(pose, (0, 0, 0, math.cos(-math.pi / 4), 0, math.sin(-math.pi / 4), 0)))
            elif g.tag == "mesh":
                fn = g.get("filename", "")
                fn = fn[len("file://"):] if fn.startswith("file://") else fn
                kx, ky, kz = (float(x) for x in g.get("scale", "1 1 1").split())
                shape = Mesh(fn if os.path.isabs(fn) else os.path.join(folder, fn), (kx, ky, kz))
            else:
                continue
            out.append((link.get("name", ""), shape, pose, color))  # a link without a name is no scene link
    return out


def object_triangles(sim: Simulator, scene: SceneSpec) -> list[tuple[str, tuple[float, ...], np.ndarray]]:
    """``(object, declared linear RGB, world triangles (T, 3, 3))`` of every untextured visual
    shape of every object, at the simulator's current poses."""
    out = []
    for body in scene.bodies:
        pose = sim.get_object_pose(body.name)
        for s in body.shapes:
            if not s.visual or s.material.texture is not None:
                continue
            tris = _transform(_primitive_triangles(s.geometry), pose_mul(pose, s.pose))
            out.append((body.name, tuple(float(c) for c in s.material.color[:3]), tris))
    for art in scene.articulations:
        links = set(sim.get_object_link_names(art.name))
        for link, shape, local, color in _urdf_visuals(art.urdf):
            if link not in links or color is None:
                continue
            pose = pose_mul(sim.get_object_link_pose(art.name, link), local)
            out.append((art.name, color, _transform(_primitive_triangles(shape), pose)))
    return out


# -- rasterisation ----------------------------------------------------------------------------------

def rasterize(K: np.ndarray, cam_pose, size: tuple[int, int], parts: list[np.ndarray]) -> np.ndarray:
    """Label image (h, w): for each pixel centre, the index in ``parts`` of the nearest triangle
    covering it (a depth buffer), or -1. ``parts``: world triangles (T, 3, 3) each; ``cam_pose``:
    the OpenCV-axes camera pose in the world."""
    w, h = size
    inv = pose_to_mat(pose_inv(cam_pose))
    pix, inv_z, lab = [], [], []
    for label, tris in enumerate(parts):
        pc = tris @ inv[:3, :3].T + inv[:3, 3]  # camera frame
        z = pc[..., 2]
        keep = np.all(z > 1e-3, axis=1)
        pc, z = pc[keep], z[keep]
        if not len(pc):
            continue
        uv = (pc @ np.asarray(K, float).T)[..., :2] / z[..., None]
        lo = np.floor(uv.min(axis=1) - 0.5).astype(int) + 1  # first pixel whose centre may be inside
        hi = np.floor(uv.max(axis=1) - 0.5).astype(int)
        lo = np.maximum(lo, 0)
        hi = np.minimum(hi, [w - 1, h - 1])
        for t in np.nonzero(np.all(hi >= lo, axis=1))[0]:
            xs = np.arange(lo[t, 0], hi[t, 0] + 1) + 0.5
            ys = np.arange(lo[t, 1], hi[t, 1] + 1) + 0.5
            X, Y = np.meshgrid(xs, ys)
            (x0, y0), (x1, y1), (x2, y2) = uv[t]
            area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
            if abs(area) < 1e-12:
                continue
            b0 = ((x1 - X) * (y2 - Y) - (x2 - X) * (y1 - Y)) / area
            b1 = ((x2 - X) * (y0 - Y) - (x0 - X) * (y2 - Y)) / area
            b2 = 1.0 - b0 - b1
            inside = (b0 >= 0) & (b1 >= 0) & (b2 >= 0)
            if not inside.any():
                continue
            iz = (b0 / z[t, 0] + b1 / z[t, 1] + b2 / z[t, 2])[inside]
            pix.append((Y[inside].astype(int)) * w + X[inside].astype(int))
            inv_z.append(iz)
            lab.append(np.full(iz.shape, label))
    out = np.full(w * h, -1, dtype=int)
    if pix:
        p, iz, lb = np.concatenate(pix), np.concatenate(inv_z), np.concatenate(lab)
        order = np.lexsort((-iz, p))  # by pixel, nearest (largest 1/z) first
        p, lb = p[order], lb[order]
        first = np.ones(len(p), bool)
        first[1:] = p[1:] != p[:-1]
        out[p[first]] = lb[first]
    return out.reshape(h, w)


def _erode(mask: np.ndarray, n: int) -> np.ndarray:
    """Shrink a boolean mask by ``n`` pixels (8-neighbourhood)."""
    m = mask.copy()
    for _ in range(n):
        p = np.pad(m, 1, constant_values=False)
        m = (m & p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:]
             & p[:-2, :-2] & p[2:, 2:] & p[:-2, 2:] & p[2:, :-2])
    return m


# -- measuring and judging --------------------------------------------------------------------------

def measure(sim: Simulator, scene: SceneSpec, camera: str = CAMERA) -> tuple[list[Region], np.ndarray]:
    """The regions of every object material in ``camera``'s picture of the world as it stands (the
    objects are moved away for a second picture and put back). Also the picture."""
    image = np.asarray(sim.render(camera))
    K = np.asarray(sim.camera_intrinsics(camera), float)
    cam = np.asarray(sim.camera_pose(camera), float)
    h, w = sim.camera_size(camera)
    shapes = object_triangles(sim, scene)
    keys: dict[tuple, int] = {}
    parts: list[np.ndarray] = []
    regions: list[Region] = []
    for obj, color, tris in shapes:
        k = (obj, tuple(round(c, 4) for c in color))
        if k not in keys:
            keys[k] = len(regions)
            regions.append(Region(obj, color))
            parts.append(tris)
        else:
            parts[keys[k]] = np.concatenate([parts[keys[k]], tris])
    labels = rasterize(K, cam, (w, h), parts)
    names = list(sim.object_names())
    poses = {n: np.asarray(sim.get_object_pose(n), float) for n in names}
    for i, n in enumerate(names):
        sim.set_object_pose(n, (float(cam[0]) + 10.0 * i, float(cam[1]), float(scene.ground_z) - _AWAY_DEPTH_M,
                                1.0, 0.0, 0.0, 0.0))
    try:
        background = np.asarray(sim.render(camera))
    finally:
        for n in names:
            sim.set_object_pose(n, poses[n])
    visible = _erode(np.abs(image.astype(int) - background.astype(int)).sum(axis=2) > DIFF_MIN, 1)
    linear = srgb_to_linear(image)
    for i, r in enumerate(regions):
        mask = _erode(labels == i, ERODE_PX) & visible
        r.pixels = int(mask.sum())
        if r.pixels >= MIN_PIXELS:
            r.measured = tuple(float(x) for x in linear[mask].mean(axis=0))
    return regions, image


def judge(regions: list[Region]) -> list[str]:
    """What disagrees with the declared colours (empty: all agree); see the module docstring."""
    seen = [r for r in regions if r.measured is not None]
    bad = []
    for r in seen:
        if r.hue_deg > MAX_HUE_DEG:
            bad.append(f"{r.label()} shows {_rgb_text(r.measured)}: its hue is {r.hue_deg:.0f} deg off "
                       f"(at most {MAX_HUE_DEG:g})")
    if len(seen) >= 2:
        ref = float(np.exp(np.median(np.log([r.gain for r in seen]))))
        for r in seen:
            ratio = r.gain / ref
            if not 1.0 / MAX_GAIN_RATIO <= ratio <= MAX_GAIN_RATIO:
                bad.append(f"{r.label()} shows {_rgb_text(r.measured)}: {ratio:.2f} x the picture's median "
                           f"brightness for its colour (allowed 1/{MAX_GAIN_RATIO:g} to {MAX_GAIN_RATIO:g})")
    return bad


def _embodiment():
    return create("embodiments", default_selection(("embodiment",))["embodiment"], {})


def task_regions(factory: SimFactory, task_name: str, emb=None) -> list[Region]:
    """Build ``task_name``'s scene at its catalog seed in a simulator from ``factory``, settle it
    as an attempt does, and measure its regions."""
    task = all_tasks()[task_name]
    emb = emb if emb is not None else _embodiment()
    inst = task.build(task.info.seed, emb)
    sim = factory()
    try:
        sim.build(inst.scene, emb)
        sim.step(task.settle_steps())
        regions, _ = measure(sim, inst.scene)
    finally:
        sim.close()
    return regions


def scene_features(scene: SceneSpec) -> tuple[set[str], int]:
    """What of a scene is likely to go wrong in a picture, and its number of object materials."""
    feats, materials = set(), set()
    for body in scene.bodies:
        vis = [s for s in body.shapes if s.visual and s.material.texture is None]
        colors = {tuple(round(float(c), 4) for c in s.material.color[:3]) for s in vis}
        materials |= {(body.name, c) for c in colors}
        if sum(s.collision for s in body.shapes) > LINK_SHAPES:
            feats.add("collision shapes past one link")
            if any(_lum(c) < 0.02 for c in colors):  # where shapes drawn in another colour show most
                feats.add("near-black body of collision shapes past one link")
        if len(vis) > LINK_SHAPES:
            feats.add("visual shapes past one link")
        if len(colors) >= 3:
            feats.add("three colours on one body")
        for c in colors:
            if _lum(c) < 0.02:
                feats.add("near-black")
            if max(c) - min(c) > 0.5:
                feats.add("saturated")
    for art in scene.articulations:
        feats.add("articulated")
        materials |= {(art.name, c) for *_, c in _urdf_visuals(art.urdf) if c is not None}
    return feats, len(materials)


@lru_cache(maxsize=1)
def representative_tasks() -> tuple[str, ...]:
    """The fewest installed tasks (greedily, in the suites' order on ties) whose catalog scenes
    between them show every feature of :func:`scene_features`, topped up to
    :data:`REPRESENTATIVE_COUNT` with the tasks of most object materials. Builds each scene
    description once (no simulator)."""
    emb = _embodiment()
    feats = {}
    for name, task in all_tasks().items():
        feats[name] = scene_features(task.build(task.info.seed, emb).scene)
    chosen: list[str] = []
    missing = set().union(*(f for f, _ in feats.values())) if feats else set()
    while missing:
        best = max(feats, key=lambda t: (len(feats[t][0] & missing), feats[t][1], -list(feats).index(t)))
        chosen.append(best)
        missing -= feats[best][0]
    rest = sorted((t for t in feats if t not in chosen), key=lambda t: (-feats[t][1], list(feats).index(t)))
    return tuple(chosen + rest[:max(0, REPRESENTATIVE_COUNT - len(chosen))])


def selected_tasks(value: str | None = None) -> list[str]:
    """The tasks to check: ``value`` (or ``$CAB_APPEARANCE_TASKS``): ``all``, a comma-separated
    list, or unset for :func:`representative_tasks`."""
    installed = list(all_tasks())
    value = os.environ.get(ENV_TASKS) if value is None else value
    if not value:
        return list(representative_tasks())
    if value.strip() == "all":
        return installed
    wanted = [t.strip() for t in value.split(",") if t.strip()]
    unknown = [t for t in wanted if t not in installed]
    if unknown:
        raise ConfigError(f"{ENV_TASKS}: unknown task(s) {', '.join(unknown)}; installed: {', '.join(installed)}")
    return wanted


def check_appearance(factory: SimFactory, tasks: list[str] | None = None) -> None:
    """Every object material of each task's initial scene (default: :func:`selected_tasks`) shows
    in the simulator's head-camera picture in its declared colour, within the module's tolerances;
    and every task shows at least one measurable region."""
    emb = _embodiment()
    failures = []
    for t in (selected_tasks() if tasks is None else tasks):
        regions = task_regions(factory, t, emb)
        if not any(r.measured is not None for r in regions):
            failures.append(f"{t}: no object material is visible in {CAMERA}")
        failures += [f"{t}: {b}" for b in judge(regions)]
    assert not failures, "objects in the wrong colours:\n  " + "\n  ".join(failures)


def main(argv: list[str] | None = None) -> int:
    """Print every region's figures per task and simulator; exit 1 where a check fails."""
    ap = argparse.ArgumentParser(prog="python -m cab_core.testing.appearance_conformance",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--sims", default=None, help="comma-separated simulators (default: every installed one)")
    ap.add_argument("--tasks", default=None, help="'all', or comma-separated tasks (default: the representative set)")
    a = ap.parse_args(argv)
    reg = registry("simulators")
    sims = a.sims.split(",") if a.sims else list(reg)
    emb = _embodiment()
    failed = 0
    for sim in sims:
        for t in selected_tasks(a.tasks or ""):
            t0 = time.perf_counter()

            def factory(sim: str = sim) -> Simulator:
                return reg[sim]({"name": sim, "render": True})

            regions = task_regions(factory, t, emb)
            bad = judge(regions)
            failed += bool(bad)
            print(f"{sim} {t}: {'FAIL' if bad else 'ok'} ({time.perf_counter() - t0:.1f} s)")
            for r in regions:
                if r.measured is None:
                    print(f"    {r.label():40s} {r.pixels:6d} px (too few)")
                else:
                    print(f"    {r.label():40s} {r.pixels:6d} px  shows {_rgb_text(r.measured)}  "
                          f"hue {r.hue_deg:5.1f} deg  gain {r.gain:5.2f}")
            for b in bad:
                print(f"  ! {b}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
