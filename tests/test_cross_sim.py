"""The installed simulators agree with each other on what the robot API and the verifiers read:
camera poses, intrinsics and where a world point lands in the image; contact reports; joint and
gripper drives tracking the same targets; articulated objects. Every check builds the conformance
world (cab_core.testing.sim_conformance) on each installed simulator and compares them pairwise;
a simulator whose engine is missing is left out, and a check needs two of them.

Tolerances, and why:
- a world point's pixel: 1 px between any two simulators, and 1 px from the pinhole projection with
  K and the camera pose (pixel centres at integer + 0.5);
- camera pose and K: 1e-5 (the same kinematics, float32 in SAPIEN);
- a resting body's contact impulse: 25% of its weight x timestep apart (the engines' contact
  models differ; each is within 30% of m g dt by the conformance suite);
- drives: after 1 s on a step target, 0.01 rad / 2 mm apart (each is within that of the target);
  along a smooth streamed trajectory, 0.03 rad apart at any step (transients differ);
- articulations: link poses at a set joint angle 1e-5 apart; a damped lid released at 1 rad has
  closed (below 0.05 rad) everywhere after 3 s.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from cab_core.contracts.scene import Body, CameraSpec, Material, SceneSpec, Shape, Sphere
from cab_core.errors import MissingDependency, RendererUnavailable
from cab_core.geometry import look_at_cv, pose_inv, pose_mul, transform_point
from cab_core.plugins import build_plugin_manager, registry
from cab_core.testing import sim_conformance as sc

pytestmark = pytest.mark.sim

CANDIDATES = ("sapien", "pybullet", "mujoco")


def _installed() -> dict:
    factories = registry("simulators", build_plugin_manager(autoload=True))
    out = {}
    for name in CANDIDATES:
        if name not in factories:
            continue
        try:
            factories[name]({"name": name, "render": False}).close()
        except MissingDependency:
            continue
        out[name] = factories[name]
    return out


INSTALLED = _installed()
PAIRS = list(itertools.combinations(sorted(INSTALLED), 2))


def _needs_two():
    if len(INSTALLED) < 2:
        pytest.skip(f"needs two installed simulators, found {sorted(INSTALLED)}")


def _make(name: str, render: bool = False):
    return INSTALLED[name]({"name": name, "render": render})


def _per_sim(fn, render: bool = False, scene: SceneSpec | None = None) -> dict:
    """{sim: fn(sim)} over the installed simulators, each built from the conformance world (or
    ``scene`` with the conformance robot); a simulator that cannot render is skipped."""
    out = {}
    for name in sorted(INSTALLED):
        sim = _make(name, render)
        try:
            sim.build(scene if scene is not None else sc.make_scene(), sc.make_embodiment())
        except RendererUnavailable as e:
            pytest.skip(f"{name} cannot render here: {e}")
        try:
            out[name] = fn(sim)
        finally:
            sim.close()
    return out


# -- cameras ---------------------------------------------------------------------------------------

PROBE = CameraSpec("probe", 320, 240, 45.0, pose=tuple(look_at_cv((0.1, -0.9, 1.5), (0.0, 0.1, 0.75))))
POINTS = ((0.0, 0.1, 0.75), (-0.25, 0.3, 0.8), (0.3, -0.1, 0.9), (0.2, 0.45, 0.76))
RED = Material(color=(1.0, 0.0, 0.0, 1.0))


def _dots(points) -> list[Body]:
    return [Body(f"dot{i}", [Shape(Sphere(0.008), material=RED, collision=False)], pose=tuple(p) + (1, 0, 0, 0),
                 kind="static") for i, p in enumerate(points)]


def _projection(sim, camera: str, p) -> np.ndarray:
    pc = transform_point(pose_inv(sim.camera_pose(camera)), p)
    assert pc[2] > 0
    return (sim.camera_intrinsics(camera) @ pc)[:2] / pc[2]


def _centroids(img: np.ndarray, near: list[np.ndarray], radius: float = 8.0) -> list[np.ndarray]:
    """Centroid (u, v, pixel centres at +0.5) of the red pixels within ``radius`` px of each
    expected point (the dots are a few pixels wide and far apart)."""
    img = img.astype(int)
    red = (img[..., 0] - np.maximum(img[..., 1], img[..., 2])) > 60
    v, u = np.nonzero(red)
    pixels = np.stack([u, v], axis=1) + 0.5
    out = []
    for p in near:
        mine = pixels[np.linalg.norm(pixels - p, axis=1) < radius]
        assert len(mine) >= 3, f"no red dot near {p}"
        out.append(mine.mean(axis=0))
    return out


def _camera_readings(camera: str, points) -> dict:
    scene = SceneSpec(bodies=_dots(points), cameras=[PROBE], ground_color=(0.05, 0.05, 0.05, 1.0))

    def read(sim):
        proj = [_projection(sim, camera, p) for p in points]
        return {"pose": sim.camera_pose(camera), "K": sim.camera_intrinsics(camera), "proj": proj,
                "pixels": _centroids(sim.render(camera), proj)}

    return _per_sim(read, render=True, scene=scene)


def _assert_cameras_agree(r: dict) -> None:
    for name, x in r.items():
        for c, p in zip(x["pixels"], x["proj"]):
            assert np.linalg.norm(c - p) <= 1.0, f"{name}: a dot at pixel {c}, projected at {p}"
    for a, b in PAIRS:
        np.testing.assert_allclose(r[a]["K"], r[b]["K"], rtol=1e-6)
        np.testing.assert_allclose(r[a]["pose"][:3], r[b]["pose"][:3], atol=1e-5)
        assert abs(abs(float(np.dot(r[a]["pose"][3:], r[b]["pose"][3:]))) - 1.0) < 1e-5, (a, b)
        for ca, cb in zip(r[a]["pixels"], r[b]["pixels"]):
            assert np.linalg.norm(ca - cb) <= 1.0, f"{a} sees a dot at {ca}, {b} at {cb}"


def test_a_world_point_lands_on_the_same_pixel_in_a_fixed_camera():
    _needs_two()
    _assert_cameras_agree(_camera_readings("probe", POINTS))


def test_a_world_point_lands_on_the_same_pixel_in_a_wrist_camera():
    """The mounted camera: dots placed in front of it (in its own frame) at the robot's home."""
    _needs_two()
    name = sorted(INSTALLED)[0]
    sim = _make(name)
    sim.build(SceneSpec(), sc.make_embodiment())
    try:
        pose = sim.camera_pose(sc.WRIST_CAMERA)
    finally:
        sim.close()
    local = ((0.0, 0.0, 0.35), (0.05, -0.03, 0.3), (-0.06, 0.04, 0.4))
    _assert_cameras_agree(_camera_readings(sc.WRIST_CAMERA, [transform_point(pose, p) for p in local]))


# -- contacts ----------------------------------------------------------------------------------------

RESTING = (("cube", "table"), ("can", "table"), ("block", "table"), ("ball", "table"), ("lidbox/base", "table"),
           ("dropper", "ground"))


def test_contact_reports_agree():
    """After the world settles: the same resting pairs, with the same names, and the cube's
    support impulse alike; the arm swung into the post is reported by every simulator."""
    _needs_two()

    def read(sim):
        sim.step(150)
        resting = {tuple(sorted((c.a, c.b))): c.impulse for c in sim.get_contacts()}
        tgt = sim.get_drive_targets()
        tgt[0] = 1.6
        sim.set_drive_targets(tgt)
        sim.step(250)
        post = {c.b if c.a == "post" else c.a for c in sim.get_contacts() if "post" in (c.a, c.b)}
        return resting, post, sim.get_qpos()[0]

    r = _per_sim(read)
    weight = sc.CUBE_MASS * 9.81 * sc.TIMESTEP
    for name, (resting, post, q0) in r.items():
        for pair in RESTING:
            assert tuple(sorted(pair)) in resting, f"{name}: no {pair} contact among {sorted(resting)}"
        assert post and all(n.startswith("robot/") for n in post), (name, post)
        assert q0 < 1.5, f"{name}: the post did not stop the arm"
    for a, b in PAIRS:
        ia, ib = r[a][0][("cube", "table")], r[b][0][("cube", "table")]
        assert abs(ia - ib) < 0.25 * weight, f"cube on table: {a} {ia:.3g} N*s, {b} {ib:.3g} N*s"


# -- drives ------------------------------------------------------------------------------------------


def test_joint_and_gripper_drives_track_alike():
    _needs_two()
    target = np.array([-0.5, 0.3, 0.01, 0.03])

    def read(sim):
        trajectory = []
        sc._motion_script(sim, 150)
        for _ in range(150):
            trajectory.append(sim.get_qpos())
            sim.step(1)
        sim.set_drive_targets(target)
        sim.step(int(round(1.0 / sim.timestep)))
        return np.asarray(trajectory), sim.get_qpos()

    r = _per_sim(read)
    for a, b in PAIRS:
        settled = np.abs(r[a][1] - r[b][1])
        assert np.all(settled[:2] < 0.01) and np.all(settled[2:] < 0.002), (a, b, r[a][1], r[b][1])
        streamed = np.abs(r[a][0] - r[b][0]).max(axis=0)
        assert np.all(streamed[:2] < 0.03) and np.all(streamed[2:] < 0.003), (a, b, streamed)


# -- articulations -----------------------------------------------------------------------------------


def test_articulated_objects_agree():
    _needs_two()

    def read(sim):
        sim.set_object_qpos("lidbox", [0.8])
        root = sim.get_object_pose("lidbox")
        lid = pose_mul(pose_inv(root), sim.get_object_link_pose("lidbox", "lid"))
        names = sorted(sim.get_object_link_names("lidbox"))
        sim.set_object_qpos("lidbox", [1.0])
        sim.step(int(round(3.0 / sim.timestep)))
        return lid, names, float(sim.get_object_qpos("lidbox")[0])

    r = _per_sim(read)
    for name, (_, names, closed) in r.items():
        assert names == ["base", "lid"], (name, names)
        assert 0.0 - 1e-3 <= closed < 0.05, f"{name}: the lid released at 1 rad is at {closed:.3f} rad after 3 s"
    for a, b in PAIRS:
        np.testing.assert_allclose(r[a][0][:3], r[b][0][:3], atol=1e-5)
        assert abs(abs(float(np.dot(r[a][0][3:], r[b][0][3:]))) - 1.0) < 1e-5, (a, b)
        assert math.isfinite(r[a][2]) and math.isfinite(r[b][2])
