"""Small perturbations of a scene instance: is a verdict robust to what differs between two runs of
"the same" instance (a millimetre of placement, a couple of percent of friction)?

``perturb.seed`` (null: off) draws, from its own random stream, for each object of the scene (every
body, static fixtures such as the table or a bell included, and every articulated object; not the
ground, not the robot):

- a shift in the table plane of at most ``position_m`` (default 1 mm) and a turn about the vertical
  of at most ``angle_deg`` (default 0.5 degrees). Not vertical, not a tilt: an object resting on the
  table would start inside it, and the simulator's push out of the overlap is a far larger
  disturbance than the one asked for;
- each declared physical parameter of the object scaled by ``1 + u``, ``|u| <= physics_fraction``
  (default 2 %): the static and dynamic friction and restitution of each of its shapes' materials, its
  mass (or density), linear and angular damping; for an articulated object its joint friction and
  damping. The default material (the ground's) is not changed.

The attempt records what was drawn (``result.json`` ``perturbation``), so a perturbed run can be
repeated exactly. The scene seed still decides the instance; the noise is drawn from ``perturb.seed``
and the scene seed together.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from cab_core.contracts.scene import ArticulatedObject, Body, SceneSpec
from cab_core.errors import ConfigError
from cab_core.geometry import quat_mul

KEYS = ("seed", "position_m", "angle_deg", "physics_fraction")


@dataclass(frozen=True)
class Perturbation:
    seed: int
    position_m: float = 0.001
    angle_deg: float = 0.5
    physics_fraction: float = 0.02

    @classmethod
    def from_cfg(cls, cfg: dict | None) -> Perturbation | None:
        """The ``perturb`` config section; None when ``seed`` is null (no perturbation)."""
        c = dict(cfg or {})
        unknown = sorted(set(c) - set(KEYS))
        if unknown:
            raise ConfigError(f"unknown perturb key(s) {', '.join(unknown)}; valid: {', '.join(KEYS)}")
        seed = c.get("seed")
        if seed is None:
            return None
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ConfigError(f"perturb.seed must be a non-negative integer or null, got {seed!r}")
        out: dict[str, float] = {}
        limits = {"position_m": 0.05, "angle_deg": 10.0, "physics_fraction": 0.5}
        for k, hi in limits.items():
            v = c.get(k, getattr(cls, k))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= hi or not math.isfinite(v):
                raise ConfigError(f"perturb.{k} must be a number in [0, {hi:g}], got {v!r}")
            out[k] = float(v)
        return cls(seed=seed, **out)

    def as_record(self) -> dict:
        return {k: getattr(self, k) for k in KEYS}


def _scale(rng: np.random.Generator, frac: float) -> float:
    return float(1.0 + rng.uniform(-frac, frac))


def _moved(pose, rng: np.random.Generator, p: Perturbation) -> tuple[tuple[float, ...], dict]:
    r = p.position_m * math.sqrt(rng.uniform(0.0, 1.0))  # uniform over the disc
    phi = rng.uniform(0.0, 2 * math.pi)
    yaw = math.radians(rng.uniform(-p.angle_deg, p.angle_deg))
    dx, dy = r * math.cos(phi), r * math.sin(phi)
    q = quat_mul(np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]), np.asarray(pose[3:7], float))
    q = q / np.linalg.norm(q)
    new = (float(pose[0] + dx), float(pose[1] + dy), float(pose[2]), *(float(v) for v in q))
    return new, {"dx_m": dx, "dy_m": dy, "yaw_deg": math.degrees(yaw)}


def _perturb_body(b: Body, rng: np.random.Generator, p: Perturbation) -> dict:
    b.pose, moved = _moved(b.pose, rng, p)
    f = {k: _scale(rng, p.physics_fraction) for k in ("friction", "restitution", "mass", "damping")}
    b.shapes = [replace(s, material=replace(s.material,
                                            static_friction=s.material.static_friction * f["friction"],
                                            dynamic_friction=s.material.dynamic_friction * f["friction"],
                                            restitution=s.material.restitution * f["restitution"]))
                for s in b.shapes]
    if b.mass is not None:
        b.mass = b.mass * f["mass"]
    else:
        b.density = b.density * f["mass"]
    b.linear_damping *= f["damping"]
    b.angular_damping *= f["damping"]
    return {**moved, **{f"{k}_scale": v for k, v in f.items()}}


def _perturb_articulation(a: ArticulatedObject, rng: np.random.Generator, p: Perturbation) -> dict:
    a.pose, moved = _moved(a.pose, rng, p)
    f = {k: _scale(rng, p.physics_fraction) for k in ("joint_friction", "joint_damping")}
    a.joint_friction *= f["joint_friction"]
    a.joint_damping *= f["joint_damping"]
    return {**moved, **{f"{k}_scale": v for k, v in f.items()}}


def perturb_scene(scene: SceneSpec, p: Perturbation, scene_seed: int) -> dict:
    """Perturb ``scene`` (the instance of ``scene_seed``) in place; returns what was drawn, per
    object, in the scene's order. The noise is drawn from (``p.seed``, ``scene_seed``): the same
    pair perturbs the same instance the same way, and one noise seed differs between instances."""
    rng = np.random.default_rng([p.seed, scene_seed, 0x7E57])
    drawn: dict[str, dict] = {}
    for b in scene.bodies:
        drawn[b.name] = _perturb_body(b, rng, p)
    for a in scene.articulations:
        drawn[a.name] = _perturb_articulation(a, rng, p)
    return drawn
