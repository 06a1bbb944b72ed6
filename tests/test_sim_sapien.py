"""The SAPIEN backend: the shared simulator conformance suite, plus SAPIEN-specific checks
(camera conventions against SAPIEN's own matrices, renderer diagnosis, physics-only mode, the
snapshot guarantees this backend gives beyond the suite)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("sapien")

from cab_core.errors import BadCommand, ConfigError, RendererUnavailable  # noqa: E402
from cab_core.geometry import intrinsics, pose_inv, pose_to_mat  # noqa: E402
from cab_core.scene import Body, CameraSpec, Mesh, SceneSpec, Shape  # noqa: E402
from cab_core.testing import sim_conformance as sc  # noqa: E402
from cab_sim_sapien import renderer as sapien_renderer  # noqa: E402
from cab_sim_sapien.simulator import SapienSimulator  # noqa: E402

pytestmark = pytest.mark.sim



@pytest.fixture(scope="module")
def render_available() -> str | None:
    """None if this machine can render with SAPIEN, else the diagnosis."""
    sim = SapienSimulator({"render": True})
    try:
        sim.build(SceneSpec(), sc.make_embodiment())
    except RendererUnavailable as e:
        return str(e)
    finally:
        sim.close()
    return None


@pytest.mark.parametrize("check", sc.CHECKS, ids=sc.check_id)
def test_conformance(check, render_available):
    if render_available is not None:
        if check in sc.NEEDS_RENDERER:
            pytest.skip(f"needs a renderer: {render_available}")
        check(lambda: SapienSimulator({"render": False}))
    else:
        check(lambda: SapienSimulator({"render": True}))


def test_conformance_physics_only():
    """Everything but images also holds without a render system."""
    for check in sc.CHECKS:
        if check not in sc.NEEDS_RENDERER:
            check(lambda: SapienSimulator({"render": False}))


def test_registered_through_entry_point():
    from cab_core.plugins import build_plugin_manager, registry

    factory = registry("simulators", build_plugin_manager(autoload=True))["sapien"]
    sim = factory({"render": False, "name": "sapien"})
    assert isinstance(sim, SapienSimulator)


def test_unknown_option_is_a_config_error():
    with pytest.raises(ConfigError):
        SapienSimulator({"rendr": True})
    with pytest.raises(ConfigError):
        SapienSimulator({"timestep": -1})
    with pytest.raises(ConfigError, match="shader"):
        SapienSimulator({"shader": "no_such_shader"})
    with pytest.raises(ConfigError):
        SapienSimulator({"shadow_map_size": 0})


def test_timestep_option_overrides_the_scene():
    sim = SapienSimulator({"render": False, "timestep": 0.002})
    sim.build(sc.make_scene(), sc.make_embodiment())
    try:
        assert sim.timestep == 0.002
        assert sim.versions()["timestep"] == "0.002"
    finally:
        sim.close()


def test_camera_conventions_match_sapien(render_available):
    """Our OpenCV pose and K agree with SAPIEN's own extrinsic and intrinsic matrices."""
    if render_available is not None:
        pytest.skip(render_available)
    sim = sc.build(lambda: SapienSimulator({"render": True}))
    try:
        sim.set_qpos([0.4, 0.3, 0.02, 0.03])
        sim.step(1)
        sim.render(sc.HEAD_CAMERA)  # syncs render poses
        for name in sim.camera_names():
            comp = sim._cameras[name].component
            np.testing.assert_allclose(comp.get_intrinsic_matrix(), sim.camera_intrinsics(name), rtol=1e-5)
            E = pose_to_mat(pose_inv(sim.camera_pose(name)))[:3]
            np.testing.assert_allclose(comp.get_extrinsic_matrix(), E, atol=2e-5)
    finally:
        sim.close()


def test_head_camera_reproduces_codeactionbench_record(render_available):
    """FACTS B.3: the recorded head camera E and K (640x480, fovy 37 deg)."""
    if render_available is not None:
        pytest.skip(render_available)
    E_rec = np.array([[1, 0, 0, 0.032], [0, -0.8, -0.6, 0.45], [0, 0.6, -0.8, 1.35]])
    cam_pose_world = np.linalg.inv(np.vstack([E_rec, [0, 0, 0, 1]]))
    from cab_core.geometry import mat_to_pose

    head = CameraSpec("head_camera", 640, 480, 37.0, pose=tuple(mat_to_pose(cam_pose_world)))
    sim = SapienSimulator({"render": True})
    sim.build(SceneSpec(cameras=[head]), sc.make_embodiment())
    try:
        K = sim.camera_intrinsics("head_camera")
        np.testing.assert_allclose(K, [[717.284, 0, 320], [0, 717.284, 240], [0, 0, 1]], atol=1e-3)
        sim.render("head_camera")
        comp = sim._cameras["head_camera"].component
        np.testing.assert_allclose(comp.get_extrinsic_matrix(), E_rec, atol=1e-5)
        np.testing.assert_allclose(intrinsics(640, 480, 37.0), comp.get_intrinsic_matrix(), rtol=1e-5)
    finally:
        sim.close()


def test_physics_only_build_keeps_camera_geometry():
    sim = sc.build(lambda: SapienSimulator({"render": False}))
    try:
        assert sorted(sim.camera_names()) == sorted([sc.HEAD_CAMERA, sc.WRIST_CAMERA])
        assert sim.camera_size(sc.WRIST_CAMERA) == (120, 160)
        assert sim.camera_pose(sc.WRIST_CAMERA).shape == (7,)
        with pytest.raises(RendererUnavailable, match="render: false"):
            sim.render(sc.HEAD_CAMERA)
        assert sim.versions()["render"] == "off"
    finally:
        sim.close()


def test_missing_render_device_is_diagnosed(monkeypatch):
    import sapien

    def no_device(*_a, **_k):
        raise RuntimeError("failed to find a rendering device")

    monkeypatch.setattr(sapien.render, "RenderSystem", no_device)
    sim = SapienSimulator({"render": True})
    with pytest.raises(RendererUnavailable) as e:
        sim.build(sc.make_scene(), sc.make_embodiment())
    msg = str(e.value)
    assert "failed to find a rendering device" in msg
    assert "mesa-vulkan-drivers >= 24.3 from bookworm-backports" in msg
    assert "render: false" in msg


def test_diagnosis_names_an_old_mesa(monkeypatch):
    monkeypatch.setattr(sapien_renderer, "icd_files", lambda: ["/usr/share/vulkan/icd.d/lvp_icd.x86_64.json"])
    monkeypatch.setattr(sapien_renderer, "lavapipe",
                        lambda: {"manifest": "lvp_icd.x86_64.json", "library": "x", "mesa": "22.3.6"})
    msg = sapien_renderer.diagnose("failed to find a rendering device")
    assert "Mesa 22.3.6, too old" in msg and "bookworm-backports" in msg


def test_versions_name_the_render_device(render_available):
    if render_available is not None:
        pytest.skip(render_available)
    sim = SapienSimulator({"render": True})
    sim.build(SceneSpec(), sc.make_embodiment())
    try:
        v = sim.versions()
        assert v["sapien"].startswith("3.") and v["render"] == "on" and v["render_device"]
        if "llvmpipe" in v["render_device"]:
            assert v["render_driver"].startswith("lavapipe") and v.get("mesa")
    finally:
        sim.close()


def test_dynamic_nonconvex_mesh_is_rejected(tmp_path):
    obj = sc.assets_dir() / "cube.obj"
    scene = SceneSpec(bodies=[Body("m", [Shape(Mesh(str(obj), convex=False))], pose=(0, 0, 1, 1, 0, 0, 0))])
    sim = SapienSimulator({"render": False})
    with pytest.raises(BadCommand, match="non-convex"):
        sim.build(scene, sc.make_embodiment())
    # static non-convex meshes are fine
    scene.bodies[0].kind = "static"
    sim = SapienSimulator({"render": False})
    sim.build(scene, sc.make_embodiment())
    sim.close()


def test_snapshot_then_restore_replays_the_original_run():
    """Stronger than the suite: save, run, restore, run again == the run right after the save,
    bit for bit, in this instance and in a second build."""
    def run(sim):
        sc._motion_script(sim, 200, phase=60)
        return sc.world_state(sim)

    sim = sc.build(lambda: SapienSimulator({"render": False}))
    other = sc.build(lambda: SapienSimulator({"render": False}))
    try:
        sc._motion_script(sim, 60)
        snap = sim.save_state()
        original = run(sim)
        sim.restore_state(snap)
        sc._assert_bit_equal(original, run(sim), "replay in the same instance")
        other.restore_state(snap)
        sc._assert_bit_equal(original, run(other), "replay in another build")
        assert other.steps == sim.steps == 60 + 200
    finally:
        sim.close()
        other.close()


def test_closed_simulator_refuses_calls():
    from cab_core.errors import SimulatorError

    sim = sc.build(lambda: SapienSimulator({"render": False}))
    sim.close()
    with pytest.raises(SimulatorError):
        sim.step(1)
    with pytest.raises(SimulatorError):
        sim.get_qpos()


def test_shadows_option_changes_the_image(render_available):
    if render_available is not None:
        pytest.skip(render_available)
    images = []
    for shadows in (False, True):
        sim = sc.build(lambda: SapienSimulator({"render": True, "shadows": shadows, "shadow_map_size": 512}))
        try:
            assert sim.versions()["shadows"] == ("on (512)" if shadows else "off")
            images.append(sim.render(sc.HEAD_CAMERA).astype(int))
        finally:
            sim.close()
    assert np.abs(images[0] - images[1]).max() > 10, "shadows made no visible difference"


def test_contacts_survive_a_restore():
    """get_contacts() after a restore gives the snapshot's last-step contacts, not stale ones."""
    sim = sc.build(lambda: SapienSimulator({"render": False}))
    try:
        sim.step(100)
        snap = sim.save_state()
        before = sim.get_contacts()
        sim.set_object_pose("cube", (0.1, 0.0, 1.2, 1, 0, 0, 0))
        sim.step(5)  # the cube is in the air now
        assert not any("cube" in (c.a, c.b) for c in sim.get_contacts())
        sim.restore_state(snap)
        assert sim.get_contacts() == before
    finally:
        sim.close()


def test_physics_only_steps_like_a_rendering_build(render_available):
    """Visual shapes and cameras do not touch the physics: both builds step bit-identically."""
    if render_available is not None:
        pytest.skip(render_available)
    a = sc.build(lambda: SapienSimulator({"render": True}))
    b = sc.build(lambda: SapienSimulator({"render": False}))
    try:
        sc._motion_script(a, 200)
        sc._motion_script(b, 200)
        sc._assert_bit_equal(sc.world_state(a), sc.world_state(b), "render on vs off")
    finally:
        a.close()
        b.close()
