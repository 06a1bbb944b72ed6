"""Appearance randomisation of a scene instance: does an agent solve the task when the scene looks
different (light, colours, camera, clutter) while the task, its objects' placement and its hidden
verifier are the same?

The config group ``randomize`` (``none``, ``lighting``, ``textures``, ``camera``, ``distractors``,
``all``) selects which of the four parts are drawn; each part's parameters are in its option's
file (``cab_core/conf/randomize/``). Every draw comes from one random stream seeded by the scene
seed and the task (so an attempt at a seed always looks the same, and a sweep over seeds sees a
different look per seed) and is recorded (``result.json`` ``randomization``):

- **lighting**: each directional light's direction turned by at most ``direction_deg`` about a
  random axis, its colour scaled by an intensity drawn in ``intensity`` and tinted per channel by at
  most ``tint``; the ambient light scaled within ``ambient``; point lights scaled like the
  directional ones.
- **textures**: the fixtures (every static body: the table, the wall, a task's fixed parts) and
  the ground get a colour drawn in HSV (``fixture_value``, ``fixture_saturation``), a surface
  roughness in ``roughness`` and, where ``patterns`` is on, a procedural texture image (stripes,
  checks or noise, generated and cached as PNG) on their visual shapes; the task's movable objects
  are recoloured by a hue turn of at most ``object_hue_deg`` and a value scale in
  ``object_value``, unless the task's instruction names a colour (then they keep theirs: an agent
  told "the red block" must still see a red block).
- **camera**: every fixed camera of the robot (the head camera) moved by at most ``position_m`` and
  turned by at most ``angle_deg`` about a random axis. The calibration the tools return is the
  simulator's camera pose, so it follows the jittered camera exactly; the recording camera copies
  the jittered head camera.
- **distractors**: ``count`` small objects (boxes, cylinders, spheres of drawn sizes and colours)
  placed at the free places the task offers (:meth:`cab_core.contracts.task.Task.distractor_slots`:
  where no verifier, checkpoint or reference solution looks); a task that offers none gets none,
  which the record says.

Nothing here changes a verifier, a checkpoint, the objects' placement or their physical
parameters (a distractor is a new body the task never reads), nor anything an agent receives
besides the pictures."""
from __future__ import annotations

import colorsys
import hashlib
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from cab_core.contracts.scene import (
    Body,
    Box,
    CameraSpec,
    Cylinder,
    Lighting,
    Material,
    SceneSpec,
    Shape,
    Sphere,
    cache_dir,
)
from cab_core.errors import ConfigError
from cab_core.geometry import quat_mul, quat_to_mat

PARTS = ("lighting", "textures", "camera", "distractors")
#: words of an instruction that name a colour: the objects then keep theirs
COLOUR_WORDS = ("red", "green", "blue", "yellow", "orange", "purple", "pink", "black", "white", "grey", "gray",
                "brown", "cyan", "magenta", "violet", "golden", "silver")
DEFAULTS: dict[str, dict[str, Any]] = {
    "lighting": {"direction_deg": 30.0, "intensity": [0.6, 1.4], "tint": 0.15, "ambient": [0.5, 1.5]},
    "textures": {"fixture_value": [0.25, 0.9], "fixture_saturation": [0.0, 0.6], "roughness": [0.3, 0.9],
                 "patterns": True, "object_hue_deg": 180.0, "object_value": [0.6, 1.2]},
    "camera": {"position_m": 0.01, "angle_deg": 1.5},
    "distractors": {"count": [1, 3], "size_m": [0.02, 0.04]},
}


@dataclass(frozen=True)
class Randomization:
    """The randomisation an attempt asks for: the option's name and, per part drawn, its
    parameters (a part absent is not drawn)."""
    name: str = "none"
    parts: dict[str, dict[str, Any]] = field(default_factory=dict)

    @classmethod
    def from_cfg(cls, cfg: dict | None) -> Randomization | None:
        """The ``randomize`` config group's option; None for ``none`` (nothing drawn)."""
        c = dict(cfg or {})
        name = str(c.pop("name", "none"))
        unknown = sorted(set(c) - set(PARTS))
        if unknown:
            raise ConfigError(f"unknown randomize key(s) {', '.join(unknown)}; valid: name, {', '.join(PARTS)}")
        parts = {}
        for part, params in c.items():
            if params in (None, False):
                continue
            given = dict(params) if isinstance(params, dict) else {}
            bad = sorted(set(given) - set(DEFAULTS[part]))
            if bad:
                raise ConfigError(f"unknown randomize.{part} key(s) {', '.join(bad)}; valid: {', '.join(DEFAULTS[part])}")
            merged = {**DEFAULTS[part], **given}
            for k, v in merged.items():
                _check(f"randomize.{part}.{k}", v, DEFAULTS[part][k])
            parts[part] = merged
        return cls(name, parts) if parts else None

    def as_record(self) -> dict:
        return {"name": self.name, "parts": self.parts}


def _check(key: str, v: Any, like: Any) -> None:
    if isinstance(like, bool):
        if not isinstance(v, bool):
            raise ConfigError(f"{key} must be true or false, got {v!r}")
    elif isinstance(like, list):
        if (not isinstance(v, (list, tuple)) or len(v) != 2 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                     and math.isfinite(x) and x >= 0 for x in v)
                or v[0] > v[1]):
            raise ConfigError(f"{key} must be a range [low, high] of non-negative numbers, got {v!r}")
    elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise ConfigError(f"{key} must be a non-negative number, got {v!r}")


def rng_for(seed: int, task: str) -> np.random.Generator:
    h = int.from_bytes(hashlib.sha256(f"randomize:{task}:{seed}".encode()).digest()[:8], "little")
    return np.random.default_rng(h)


def _uni(rng: np.random.Generator, lim) -> float:
    return float(rng.uniform(float(lim[0]), float(lim[1])))


def _turn(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    """A rotation (wxyz) by at most ``max_deg`` about a uniformly drawn axis."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = math.radians(rng.uniform(-max_deg, max_deg))
    return np.array([math.cos(a / 2), *(math.sin(a / 2) * axis)])


def _rotate(v, q: np.ndarray) -> np.ndarray:
    return quat_to_mat(q) @ np.asarray(v, float)


def _triple(values) -> tuple[float, float, float]:
    """Three numbers (a direction, a colour) as the tuple of floats the lighting holds."""
    x, y, z = values
    return float(x), float(y), float(z)


def _r(v) -> list[float]:
    return [round(float(x), 6) for x in v]


# -- lighting -----------------------------------------------------------------------------------
def randomize_lighting(lighting: Lighting, rng: np.random.Generator, p: dict) -> tuple[Lighting, dict]:
    def colour(c) -> tuple[float, float, float]:
        k = _uni(rng, p["intensity"])
        return _triple(max(0.0, x * k * (1 + rng.uniform(-p["tint"], p["tint"]))) for x in c)

    directional = []
    for d, c in lighting.directional:
        nd = _rotate(d, _turn(rng, p["direction_deg"]))
        directional.append((_triple(nd), colour(c)))
    points = tuple((pos, colour(c)) for pos, c in lighting.points)
    amb = _uni(rng, p["ambient"])
    out = Lighting(ambient=_triple(x * amb for x in lighting.ambient), directional=tuple(directional),
                   points=points)
    return out, {"ambient": _r(out.ambient), "directional": [[_r(d), _r(c)] for d, c in out.directional],
                 "points": [_r(c) for _, c in out.points]}


# -- colours and textures -----------------------------------------------------------------------
PATTERNS = ("stripes", "checks", "noise")


def pattern_texture(kind: str, rgb, seed: int, size: int = 128) -> str:
    """A procedural texture image (PNG in the cache folder, made once): ``kind`` over the colour
    ``rgb`` (linear, 0..1, like every cab colour), its contrast and scale drawn from ``seed``. The
    pixels are written sRGB-encoded, as an image file's are read (a simulator shows a texture's
    bytes as it shows a plain colour's sRGB value), so the light stripes show ``rgb`` itself.
    Returns the file's path."""
    folder = Path(cache_dir()) / "textures"
    folder.mkdir(parents=True, exist_ok=True)
    key = hashlib.sha256(f"{kind}:{_r(rgb)}:{seed}:{size}:srgb".encode()).hexdigest()[:16]
    path = folder / f"{kind}-{key}.png"
    if path.exists():
        return str(path)
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    period = rng.uniform(0.08, 0.25)
    if kind == "stripes":
        angle = rng.uniform(0, math.pi)
        t = (np.cos(angle) * x + np.sin(angle) * y) / period
        m = (np.floor(t) % 2).astype(float)
    elif kind == "checks":
        m = ((np.floor(x / period) + np.floor(y / period)) % 2).astype(float)
    else:
        coarse = rng.uniform(0, 1, (8, 8))
        m = np.kron(coarse, np.ones((size // 8, size // 8)))
    contrast = rng.uniform(0.15, 0.4)
    img = np.clip(np.asarray(rgb, float)[None, None, :3] * (1 - contrast * m[..., None]), 0, 1)
    img = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(img, 1 / 2.4) - 0.055)
    from PIL import Image

    tmp = path.with_suffix(f".{rng.integers(1 << 30)}.tmp.png")
    Image.fromarray((img * 255 + 0.5).astype(np.uint8)).save(tmp)
    tmp.replace(path)
    return str(path)


def _hsv(rng: np.random.Generator, p: dict) -> tuple[float, float, float]:
    h = rng.uniform(0, 1)
    return colorsys.hsv_to_rgb(h, _uni(rng, p["fixture_saturation"]), _uni(rng, p["fixture_value"]))


def _recolour_object(c, rng: np.random.Generator, p: dict) -> tuple[float, float, float, float]:
    h, s, v = colorsys.rgb_to_hsv(*[float(x) for x in c[:3]])
    h = (h + rng.uniform(-p["object_hue_deg"], p["object_hue_deg"]) / 360.0) % 1.0
    v = min(1.0, v * _uni(rng, p["object_value"]))
    return (*colorsys.hsv_to_rgb(h, s, v), float(c[3]))


def names_a_colour(instruction: str) -> list[str]:
    words = {w.strip(".,;:!?'\"()").lower() for w in instruction.split()}
    return [c for c in COLOUR_WORDS if c in words]


def randomize_textures(scene: SceneSpec, rng: np.random.Generator, p: dict, instruction: str) -> dict:
    """Recolour (and texture) the fixtures and the ground; recolour the movable objects unless the
    instruction names a colour. Changes ``scene`` in place; returns what was drawn."""
    rec: dict[str, Any] = {"fixtures": {}, "objects": {}}
    for b in scene.bodies:
        if b.kind != "static":
            continue
        rgb = _hsv(rng, p)
        rough = _uni(rng, p["roughness"])
        tex = None
        if p["patterns"]:
            kind = PATTERNS[int(rng.integers(len(PATTERNS)))]
            tex = pattern_texture(kind, rgb, int(rng.integers(1 << 31)))
        b.shapes = [replace(s, material=replace(s.material, color=(*rgb, 1.0), roughness=rough, texture=tex))
                    if s.visual else s for s in b.shapes]
        rec["fixtures"][b.name] = {"color": _r(rgb), "roughness": round(rough, 4),
                                   "texture": None if tex is None else Path(tex).name.split("-")[0]}
    g = _hsv(rng, p)
    scene.ground_color = (*g, 1.0)
    rec["ground"] = _r(g)
    named = names_a_colour(instruction)
    if named:
        rec["objects_kept"] = f"the instruction names a colour ({', '.join(named)})"
        return rec
    for b in scene.bodies:
        if b.kind == "static":
            continue
        shifted = {}
        shapes = []
        for s in b.shapes:
            key = tuple(s.material.color)
            if key not in shifted:  # one object's shapes of one colour stay one colour
                shifted[key] = _recolour_object(s.material.color, rng, p)
            shapes.append(replace(s, material=replace(s.material, color=shifted[key])) if s.visual else s)
        b.shapes = shapes
        rec["objects"][b.name] = [_r(c) for c in shifted.values()]
    return rec


# -- camera -------------------------------------------------------------------------------------
def randomize_cameras(cameras: tuple[CameraSpec, ...], rng: np.random.Generator, p: dict) -> tuple[tuple, dict]:
    """Each fixed camera (no mount link) moved and turned; mounted cameras are the robot's."""
    out, rec = [], {}
    for c in cameras:
        if c.mount_link:
            out.append(c)
            continue
        d = rng.normal(size=3)
        d = d / np.linalg.norm(d) * p["position_m"] * rng.uniform(0, 1) ** (1 / 3)
        q = quat_mul(_turn(rng, p["angle_deg"]), np.asarray(c.pose[3:7], float))
        q = q / np.linalg.norm(q)
        pose = (*(float(a + b) for a, b in zip(c.pose[:3], d)), *(float(x) for x in q))
        out.append(replace(c, pose=pose))
        angle = 2 * math.degrees(math.acos(min(1.0, abs(float(np.dot(q, np.asarray(c.pose[3:7], float)))))))
        rec[c.name] = {"moved_m": round(float(np.linalg.norm(d)), 6), "turned_deg": round(angle, 4),
                       "pose": _r(pose)}
    return tuple(out), rec


# -- distractors --------------------------------------------------------------------------------
def distractor_bodies(slots: list, rng: np.random.Generator, p: dict) -> tuple[list[Body], dict]:
    """Up to ``count`` small objects on the free places ``slots`` (``(x, y, z_surface)``), each a
    box, a cylinder or a sphere of a drawn size and colour, resting on its surface."""
    lo, hi = (int(v) for v in p["count"])
    n = min(int(rng.integers(lo, hi + 1)), len(slots))
    order = rng.permutation(len(slots))[:n]
    bodies, rec = [], []
    for i, k in enumerate(sorted(int(j) for j in order)):
        x, y, z = (float(v) for v in slots[k])
        size = _uni(rng, p["size_m"])
        kind = ("box", "cylinder", "sphere")[int(rng.integers(3))]
        rgb = colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0.3, 0.9), rng.uniform(0.3, 0.95))
        mat = Material(color=(*rgb, 1.0), static_friction=0.8, dynamic_friction=0.8)
        shapes: dict[str, Box | Cylinder | Sphere] = {"box": Box((size, size, size)),
                                                      "cylinder": Cylinder(size, size), "sphere": Sphere(size)}
        geom = shapes[kind]
        yaw = rng.uniform(-math.pi, math.pi)
        pose = (x, y, z + size + 0.0005, math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        name = f"distractor_{i}"
        bodies.append(Body(name, [Shape(geom, material=mat)], pose=pose, kind="dynamic", density=300.0,
                           angular_damping=0.5 if kind == "sphere" else 0.05))
        rec.append({"name": name, "shape": kind, "size_m": round(size, 4), "xy": _r((x, y)), "color": _r(rgb)})
    return bodies, {"offered_slots": len(slots), "placed": rec}


# -- all of it ----------------------------------------------------------------------------------
def randomize_instance(scene: SceneSpec, embodiment, r: Randomization, seed: int, task: str, instruction: str,
                       slots: list) -> tuple[Any, dict]:
    """Apply ``r`` to ``scene`` (in place) and return the embodiment the simulator is to build (its
    fixed cameras jittered when asked) and the record of every draw. Parts are drawn in a fixed
    order from one stream, each part from its own sub-stream so that adding one part does not
    change another's draws."""
    root = rng_for(seed, task)
    streams = {part: np.random.default_rng(root.integers(1 << 63)) for part in PARTS}
    rec: dict[str, Any] = {**r.as_record()}
    if "lighting" in r.parts:
        scene.lighting, rec["lighting"] = randomize_lighting(scene.lighting, streams["lighting"], r.parts["lighting"])
    if "textures" in r.parts:
        rec["textures"] = randomize_textures(scene, streams["textures"], r.parts["textures"], instruction)
    if "camera" in r.parts:
        cams, rec["camera"] = randomize_cameras(tuple(embodiment.cameras), streams["camera"], r.parts["camera"])
        embodiment = replace(embodiment, cameras=cams)
    if "distractors" in r.parts:
        bodies, rec["distractors"] = distractor_bodies(slots, streams["distractors"], r.parts["distractors"])
        scene.bodies.extend(bodies)
    return embodiment, rec
