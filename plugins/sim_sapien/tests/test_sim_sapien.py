"""The SAPIEN backend: SAPIEN-specific checks
(camera conventions against SAPIEN's own matrices, renderer diagnosis, options, shadows).
What every backend guarantees beyond the suite is checked in tests/test_sim_backends.py; the shared
conformance suite (cab_core.testing.sim_conformance) runs on this backend through
`pytest --cab-conformance` (scripts/test.sh turns it on)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("sapien")

import sim_backend_checks as checks  # noqa: E402

from cab_core.contracts.scene import Body, CameraSpec, Mesh, SceneSpec, Shape  # noqa: E402
from cab_core.errors import BadCommand, ConfigError, RendererUnavailable  # noqa: E402
from cab_core.geometry import intrinsics, mat_to_pose, pose_inv, pose_to_mat  # noqa: E402
from cab_core.testing import sim_conformance as sc  # noqa: E402
from cab_sim_sapien import renderer as sapien_renderer  # noqa: E402
from cab_sim_sapien.simulator import SapienSimulator  # noqa: E402

pytestmark = pytest.mark.sim


rendering = checks.backend("sapien").rendering


def test_bad_options_are_config_errors():
    with pytest.raises(ConfigError, match="shader"):
        SapienSimulator({"shader": "no_such_shader"})
    with pytest.raises(ConfigError):
        SapienSimulator({"shadow_map_size": 0})


def test_camera_conventions_match_sapien():
    """Our OpenCV pose and K agree with SAPIEN's own extrinsic and intrinsic matrices."""
    checks.require_renderer("sapien")
    sim = sc.build(rendering)
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


def test_head_camera_reproduces_codeactionbench_record():
    """FACTS B.3: the recorded head camera E and K (640x480, fovy 37 deg)."""
    checks.require_renderer("sapien")
    E_rec = np.array([[1, 0, 0, 0.032], [0, -0.8, -0.6, 0.45], [0, 0.6, -0.8, 1.35]])
    cam_pose_world = np.linalg.inv(np.vstack([E_rec, [0, 0, 0, 1]]))
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


def test_versions_name_the_render_device():
    v = checks.rendering_versions("sapien")
    assert v["sapien"].startswith("3.") and v["render"] == "on" and v["render_device"]
    if "llvmpipe" in v["render_device"]:
        assert v["render_driver"].startswith("lavapipe") and v.get("mesa")


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


def test_shadows_option_changes_the_image():
    checks.require_renderer("sapien")
    images = []
    for shadows in (False, True):
        sim = sc.build(lambda shadows=shadows: SapienSimulator({"render": True, "shadows": shadows, "shadow_map_size": 512}))
        try:
            assert sim.versions()["shadows"] == ("on (512)" if shadows else "off")
            images.append(sim.render(sc.HEAD_CAMERA).astype(int))
        finally:
            sim.close()
    assert np.abs(images[0] - images[1]).max() > 10, "shadows made no visible difference"
