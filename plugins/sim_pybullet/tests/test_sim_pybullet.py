"""The PyBullet backend: PyBullet-specific checks
(camera projection against PyBullet's own renderer, renderer choice, options, mass properties,
agreement with SAPIEN, bodies beyond a Bullet link's shape limit, the robot's self-collision).
What every backend guarantees beyond the suite is checked in tests/test_sim_backends.py; the shared
conformance suite (cab_core.testing.sim_conformance) runs on this backend through
`pytest --cab-conformance` (scripts/test.sh turns it on)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")

import sim_backend_checks as checks  # noqa: E402

from cab_core.contracts.scene import Body, Box, CameraSpec, Capsule, Cylinder, Material, Mesh, SceneSpec, Shape, Sphere  # noqa: E402
from cab_core.errors import BadCommand, ConfigError, RendererUnavailable  # noqa: E402
from cab_core.geometry import pose_inv, transform_point  # noqa: E402
from cab_core.plugins import create  # noqa: E402
from cab_core.testing import sim_conformance as sc  # noqa: E402
from cab_sim_pybullet import massprops, renderer  # noqa: E402
from cab_sim_pybullet.simulator import PybulletSimulator  # noqa: E402

pytestmark = pytest.mark.sim


PYBULLET = checks.backend("pybullet")  # it renders with TinyRenderer, on any machine
rendering, physics_only = PYBULLET.rendering, PYBULLET.physics_only


def test_bad_options_are_config_errors():
    for cfg in ({"renderer": "vulkan"}, {"physics": {"no_such_parameter": 1.0}}, {"physics": {"gripper_force_n": 0}}):
        with pytest.raises(ConfigError):
            PybulletSimulator(cfg)


def test_projected_point_lands_on_its_pixel():
    """A small red sphere at a known world point renders centred on the pixel K predicts."""
    target = np.array([0.05, 0.10, sc.TABLE_TOP + 0.15])
    red = Material(color=(1.0, 0.0, 0.0, 1.0))
    scene = SceneSpec(bodies=[Body("dot", [Shape(Sphere(0.006), material=red)], pose=tuple(target) + (1, 0, 0, 0),
                                   kind="static")],
                      cameras=[CameraSpec("cam", 320, 240, 45.0, pose=tuple(sc.make_scene().cameras[0].pose))])
    sim = PybulletSimulator({"render": True, "renderer": "tiny"})
    sim.build(scene, sc.make_embodiment())
    try:
        img = sim.render("cam").astype(int)
        red = (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80)
        assert red.sum() > 4, "the marker is not visible"
        v, u = np.nonzero(red)
        p = transform_point(pose_inv(sim.camera_pose("cam")), target)
        uv = (sim.camera_intrinsics("cam") @ p)[:2] / p[2]
        centroid = np.array([u.mean() + 0.5, v.mean() + 0.5])  # pixel i covers [i, i + 1)
        assert np.all(np.abs(centroid - uv) < 1.0), (centroid, uv)
    finally:
        sim.close()


def test_renderer_choice(monkeypatch):
    monkeypatch.setattr(renderer, "gpu_device_nodes", lambda: [])
    assert renderer.choose("auto").kind == "tiny"
    monkeypatch.setattr(renderer, "gpu_device_nodes", lambda: ["/dev/nvidia0"])
    assert renderer.choose("auto").kind == "egl"
    assert renderer.choose("tiny").kind == "tiny"
    with pytest.raises(ConfigError):
        renderer.choose("opengl")


def test_egl_that_cannot_start_fails_fast(monkeypatch):
    """A requested EGL renderer that does not load is a RendererUnavailable with a diagnosis."""
    monkeypatch.setattr(renderer.importlib.util, "find_spec", lambda name: None)
    sim = PybulletSimulator({"render": True, "renderer": "egl"})
    with pytest.raises(RendererUnavailable, match="renderer: tiny"):
        sim.build(sc.make_scene(), sc.make_embodiment())


def test_versions_name_the_renderer():
    sim = sc.build(rendering)
    try:
        v = sim.versions()
        assert v["pybullet"] == "3.2.7" and v["render"] == "on"
        assert v["renderer"] == "TinyRenderer (CPU)" and v["renderer_choice"] == "requested"
    finally:
        sim.close()


def test_dynamic_nonconvex_mesh_is_rejected():
    obj = sc.assets_dir() / "cube.obj"
    scene = SceneSpec(bodies=[Body("m", [Shape(Mesh(str(obj), convex=False))], pose=(0, 0, 1, 1, 0, 0, 0))])
    with pytest.raises(BadCommand, match="non-convex"):
        PybulletSimulator({"render": False}).build(scene, sc.make_embodiment())
    scene.bodies[0].kind = "static"
    sim = PybulletSimulator({"render": False})
    sim.build(scene, sc.make_embodiment())
    sim.close()


@pytest.mark.parametrize("geometry, mass, inertia", [
    (Box((0.1, 0.2, 0.3)), 1000 * 0.048, [0.048 * 1000 * (0.04 + 0.09) / 3, 0.048 * 1000 * (0.01 + 0.09) / 3,
                                          0.048 * 1000 * (0.01 + 0.04) / 3]),
    (Sphere(0.1), 1000 * 4 / 3 * np.pi * 1e-3, [0.4 * 1000 * 4 / 3 * np.pi * 1e-3 * 0.01] * 3),
    (Cylinder(0.1, 0.2), 1000 * np.pi * 0.01 * 0.4,
     [0.5 * 4 * np.pi * 0.01, 4 * np.pi * (0.03 + 0.16) / 12, 4 * np.pi * (0.03 + 0.16) / 12]),
])
def test_primitive_mass_properties(geometry, mass, inertia):
    p = massprops.shape_props(geometry, 1000.0)
    assert p.mass == pytest.approx(mass, rel=1e-9)
    np.testing.assert_allclose(np.diag(p.inertia), inertia, rtol=1e-9)


def test_convex_mesh_mass_properties_match_the_box():
    """The hull integration of the conformance cube (scaled) gives the box's exact values."""
    mesh = massprops.shape_props(Mesh(str(sc.assets_dir() / "cube.obj"), scale=(1.0, 2.0, 1.5)), 500.0)
    box = massprops.shape_props(Box((0.02, 0.04, 0.03)), 500.0)
    assert mesh.mass == pytest.approx(box.mass, rel=1e-9)
    np.testing.assert_allclose(mesh.com, 0.0, atol=1e-12)
    np.testing.assert_allclose(mesh.inertia, box.inertia, rtol=1e-9, atol=1e-15)


def test_capsule_tends_to_a_sphere_and_a_cylinder():
    r = 0.05
    sphere = massprops.shape_props(Sphere(r), 1.0)
    np.testing.assert_allclose(massprops.shape_props(Capsule(r, 1e-9), 1.0).inertia, sphere.inertia, rtol=1e-6)
    long = massprops.shape_props(Capsule(0.001, 1.0), 1.0)
    cyl = massprops.shape_props(Cylinder(0.001, 1.0), 1.0)
    assert long.inertia[1, 1] == pytest.approx(cyl.inertia[1, 1], rel=1e-2)


def test_body_mass_and_centre_of_mass_reach_bullet():
    """An L-shaped body: the dynamics see the declared mass and the off-centre centre of mass,
    and the reported pose stays the body frame."""
    shapes = [Shape(Box((0.05, 0.01, 0.01))), Shape(Box((0.01, 0.05, 0.01)), pose=(0.04, 0.04, 0, 1, 0, 0, 0))]
    scene = SceneSpec(bodies=[Body("ell", shapes, pose=(0.3, 0.2, 1.0, 1, 0, 0, 0), mass=0.25)])
    sim = PybulletSimulator({"render": False})
    sim.build(scene, sc.make_embodiment())
    try:
        np.testing.assert_allclose(sim.get_object_pose("ell"), (0.3, 0.2, 1.0, 1, 0, 0, 0), atol=1e-12)
        mb = sim._bodies["ell"]
        assert sim._c.getDynamicsInfo(mb.uid, -1)[0] == pytest.approx(0.25)
        assert mb.com_local[0] > 0.005 and mb.com_local[1] > 0.005
    finally:
        sim.close()


def test_two_simulators_in_one_process_are_independent():
    a = sc.build(physics_only)
    b = sc.build(physics_only)
    try:
        a.set_object_pose("cube", (0.1, 0.0, 1.2, 1, 0, 0, 0))
        a.step(10)
        b.step(10)
        assert b.get_object_pose("cube")[2] < 0.8 < a.get_object_pose("cube")[2]
    finally:
        a.close()
        b.close()


def test_agrees_with_sapien_on_the_conformance_world():
    """Same description, same calls: robot link and camera poses, intrinsics, resting contacts and
    drive tracking agree with the SAPIEN backend (the reference for conventions)."""
    sapien_sim = pytest.importorskip("cab_sim_sapien.simulator")
    a = sc.build(physics_only)
    b = sc.build(lambda: sapien_sim.SapienSimulator({"render": False}))
    try:
        for sim in (a, b):
            sim.set_qpos([0.4, 0.3, 0.02, 0.03])
        for link in sc.ROBOT_LINKS:
            np.testing.assert_allclose(a.get_link_pose(link)[:3], b.get_link_pose(link)[:3], atol=1e-5)
            assert abs(abs(np.dot(a.get_link_pose(link)[3:], b.get_link_pose(link)[3:])) - 1) < 1e-6, link
        for cam in a.camera_names():
            np.testing.assert_allclose(a.camera_intrinsics(cam), b.camera_intrinsics(cam))
            pa, pb = a.camera_pose(cam), b.camera_pose(cam)
            point = transform_point(pb, (0.05, -0.02, 0.6))  # a point in front of the camera
            uv = []
            for pose in (pa, pb):
                p = transform_point(pose_inv(pose), point)
                uv.append((a.camera_intrinsics(cam) @ p)[:2] / p[2])
            assert np.all(np.abs(uv[0] - uv[1]) < 1.0), (cam, uv)
        target = np.array([-0.5, 0.3, 0.01, 0.03])
        for sim in (a, b):
            sim.set_drive_targets(target)
            sim.step(250)
        np.testing.assert_allclose(a.get_qpos(), b.get_qpos(), atol=0.01)
        pairs = [{frozenset((c.a, c.b)) for c in sim.get_contacts()} for sim in (a, b)]
        for pair in (("cube", "table"), ("lidbox/base", "table"), ("dropper", "ground")):
            assert frozenset(pair) in pairs[0] and frozenset(pair) in pairs[1], pair
        for name in ("cube", "ball", "can", "block"):
            np.testing.assert_allclose(a.get_object_pose(name)[:3], b.get_object_pose(name)[:3], atol=0.005)
        # articulations: the same joint value puts the same link at the same pose
        for sim in (a, b):
            sim.set_object_pose("lidbox", (-0.15, 0.02, 1.2, 1, 0, 0, 0))
            sim.set_object_qpos("lidbox", [0.8])
        assert a.get_object_link_names("lidbox") == b.get_object_link_names("lidbox") == ["base", "lid"]
        lid_a, lid_b = a.get_object_link_pose("lidbox", "lid"), b.get_object_link_pose("lidbox", "lid")
        np.testing.assert_allclose(lid_a[:3], lid_b[:3], atol=1e-5)
        assert abs(abs(np.dot(lid_a[3:], lid_b[3:])) - 1) < 1e-6
    finally:
        a.close()
        b.close()


def test_body_with_more_shapes_than_a_bullet_link_takes():
    """40 cubes in a row (PyBullet takes 16 shapes per link): one rigid body with the right mass,
    resting level on the ground, named as one object in contacts."""
    shapes = [Shape(Box((0.01, 0.01, 0.01)), pose=(0.02 * i - 0.39, 0, 0, 1, 0, 0, 0)) for i in range(40)]
    scene = SceneSpec(bodies=[Body("row", shapes, pose=(0.3, 0.3, 0.05, 1, 0, 0, 0), density=1000.0)],
                      cameras=sc.make_scene().cameras)
    sim = PybulletSimulator({"render": True, "renderer": "tiny"})
    sim.build(scene, sc.make_embodiment())
    try:
        mb = sim._bodies["row"]
        c = sim._c
        masses = [c.getDynamicsInfo(mb.uid, link)[0] for link in range(-1, c.getNumJoints(mb.uid))]
        assert len(masses) == 3 and sum(masses) == pytest.approx(40 * 8e-6 * 1000)
        # each link keeps the inertia of its own 16 (or 8) cubes: a row 0.32 m long about z
        izz = [c.getDynamicsInfo(mb.uid, link)[2][2] for link in (-1, 0, 1)]
        assert izz[0] == pytest.approx(16 * 8e-3 * 0.32 ** 2 / 12, rel=0.02), izz
        sim.step(250)
        pose = sim.get_object_pose("row")
        assert abs(pose[2] - 0.01) < 1e-3 and abs(abs(pose[3]) - 1.0) < 1e-4, pose
        assert {(x.a, x.b) for x in sim.get_contacts()} == {("ground", "row")}
        assert sim.render(sc.HEAD_CAMERA).std() > 2.0
    finally:
        sim.close()


def test_the_two_arms_collide_but_one_arm_never_with_itself():
    """The aloha robot: its left arm swung across into the right one reports left-right link
    pairs only (an arm's own links and the body never pair up)."""
    emb = create("embodiments", "aloha_agilex", {})
    sim = PybulletSimulator({"render": False})
    sim.build(SceneSpec(), emb)
    try:
        sim.step(10)
        assert not sim.get_contacts(), "the robot at home touches itself"
        q = sim.get_qpos()
        q[sim.joint_names.index("fl_joint1")], q[sim.joint_names.index("fl_joint2")] = -1.5, 1.5
        sim.set_qpos(q)
        sim.step(1)
        pairs = {(c.a, c.b) for c in sim.get_contacts()}
        assert pairs and all(a.startswith("robot/fl_") and b.startswith("robot/fr_") for a, b in pairs), pairs
    finally:
        sim.close()
