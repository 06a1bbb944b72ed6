"""The MuJoCo backend: MuJoCo-specific checks (GL
backend choice and diagnosis, options, mass and damping, rendering from threads, an attempt
through the CLI). What every backend guarantees beyond the suite is checked in
tests/test_sim_backends.py; the shared conformance suite (cab_core.testing.sim_conformance) runs
on this backend through `pytest --cab-conformance` (scripts/test.sh turns it on)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")

import sim_backend_checks as checks  # noqa: E402

import cab_sim_mujoco  # noqa: E402
from cab_core.contracts.scene import ArticulatedObject, Body, Box, Mesh, SceneSpec, Shape, Sphere  # noqa: E402
from cab_core.errors import BadCommand, ConfigError, RendererUnavailable  # noqa: E402
from cab_core.geometry import transform_point  # noqa: E402
from cab_core.testing import sim_conformance as sc  # noqa: E402
from cab_sim_mujoco import gl  # noqa: E402
from cab_sim_mujoco.simulator import MujocoSimulator  # noqa: E402

pytestmark = pytest.mark.sim


MUJOCO = checks.backend("mujoco")
rendering, physics_only = MUJOCO.rendering, MUJOCO.physics_only


def test_hydra_config_builds_the_backend():
    """conf/sim/mujoco.yaml is a valid option set of this backend."""
    from pathlib import Path

    import yaml

    cfg = yaml.safe_load((Path(cab_sim_mujoco.__file__).parent / "conf" / "sim" / "mujoco.yaml").read_text())
    assert cfg["name"] == "mujoco"
    sim = MujocoSimulator(dict(cfg, render=False))
    sim.build(sc.make_scene(), sc.make_embodiment())
    sim.close()


def test_bad_options_are_config_errors():
    with pytest.raises(ConfigError, match="impratoi"):
        MujocoSimulator({"physics": {"impratoi": 3}})
    with pytest.raises(ConfigError, match="cone"):
        MujocoSimulator({"physics": {"cone": "round"}})
    with pytest.raises(ConfigError, match="contact_solref"):
        MujocoSimulator({"physics": {"contact_solref": [0.01]}})


def test_options_reach_the_model():
    sim = MujocoSimulator({"render": False, "timestep": 0.002, "physics": {"impratio": 3, "condim": 6}})
    sim.build(sc.make_scene(), sc.make_embodiment())
    try:
        assert sim.timestep == 0.002 and sim.versions()["timestep"] == "0.002"
        assert sim._model.opt.impratio == 3
        assert set(sim._model.geom_condim[sim._model.geom_contype > 0]) == {6}
        assert '"impratio": 3.0' in sim.versions()["physics"]
    finally:
        sim.close()


def test_mass_is_imposed():
    """A body's declared mass replaces the density-derived one (inertia scaled alike)."""
    import mujoco

    sim = sc.build(physics_only)
    try:
        m = sim._model
        cube = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "cube")
        assert m.body_mass[cube] == pytest.approx(sc.CUBE_MASS)
        i = 0.1 * (0.05 ** 2 + 0.05 ** 2) / 12
        np.testing.assert_allclose(m.body_inertia[cube], [i, i, i], rtol=1e-6)
    finally:
        sim.close()


def test_gl_backend_respects_mujoco_gl():
    assert gl.choose_backend({"MUJOCO_GL": "egl"}) == ("egl", "MUJOCO_GL")
    with pytest.raises(RendererUnavailable, match="not a backend"):
        gl.choose_backend({"MUJOCO_GL": "vulkan"})
    backend, how = gl.choose_backend({})
    assert how == "auto" and backend in ("egl", "osmesa")


def test_missing_gl_library_is_diagnosed(monkeypatch):
    monkeypatch.setattr(gl, "_loads", lambda backend: False)
    with pytest.raises(RendererUnavailable, match="libosmesa6"):
        gl.choose_backend({})
    with pytest.raises(RendererUnavailable, match="MUJOCO_GL=osmesa was set"):
        gl.choose_backend({"MUJOCO_GL": "osmesa"})


def test_software_renderer_is_recorded():
    info = gl.GLInfo("egl", "auto", "llvmpipe (LLVM 15.0.6, 256 bits)", "4.5 Mesa 25.0.7", "Mesa")
    d = gl.describe(info)
    assert d["llvmpipe"] == "yes" and d["render_driver"].startswith("llvmpipe") and d["gl_backend"] == "egl"
    gpu = gl.describe(gl.GLInfo("egl", "MUJOCO_GL", "NVIDIA H100/PCIe/SSE2", "4.6", "NVIDIA"))
    assert gpu["llvmpipe"] == "no" and gpu["render_driver"] == "gpu"


def test_versions_name_the_gl_renderer():
    v = checks.rendering_versions("mujoco")
    assert v["render"] == "on" and v["render_device"] and v["gl_backend"] in ("egl", "osmesa", "glfw")
    assert v["llvmpipe"] == ("yes" if "llvmpipe" in v["render_device"] else "no")


def test_nonconvex_collision_mesh_is_rejected():
    obj = sc.assets_dir() / "cube.obj"
    for kind in ("dynamic", "static"):
        scene = SceneSpec(bodies=[Body("m", [Shape(Mesh(str(obj), convex=False))], pose=(0, 0, 1, 1, 0, 0, 0),
                                       kind=kind)])
        with pytest.raises(BadCommand, match="convex hull"):
            MujocoSimulator({"render": False}).build(scene, sc.make_embodiment())
    # as a visual only, it is fine
    scene = SceneSpec(bodies=[Body("m", [Shape(Mesh(str(obj), convex=False), collision=False),
                                         Shape(Mesh(str(obj)), visual=False)], pose=(0, 0, 1, 1, 0, 0, 0))])
    sim = MujocoSimulator({"render": False})
    sim.build(scene, sc.make_embodiment())
    sim.close()


def test_body_damping_decays_velocity_as_physx_does():
    """PhysX scales a body's velocity by 1 / (1 + dt c) each step; so does this backend."""
    ball = Body("ball", [Shape(Sphere(0.05))], pose=(0, 0, 1, 1, 0, 0, 0), linear_damping=0.2, angular_damping=0.5)
    sim = MujocoSimulator({"render": False})
    sim.build(SceneSpec(bodies=[ball], gravity=(0.0, 0.0, 0.0)), sc.make_embodiment())
    try:
        dof = sim._things["ball"].dadr
        sim._data.qvel[dof:dof + 6] = [1.0, 0.0, 0.0, 0.0, 0.0, 2.0]
        sim.step(100)
        dt = sim.timestep
        v = sim.get_object_velocity("ball")
        np.testing.assert_allclose(v[[0, 5]], [1.0 / (1 + dt * 0.2) ** 100, 2.0 / (1 + dt * 0.5) ** 100], rtol=1e-9)
    finally:
        sim.close()


_BUILD_AND_REPORT = """
from cab_core.errors import RendererUnavailable
from cab_core.testing import sim_conformance as sc
try:
    from cab_sim_mujoco.simulator import MujocoSimulator
    sim = MujocoSimulator({"render": True})
    sim.build(sc.make_scene(), sc.make_embodiment())
    v = sim.versions()
    print("RENDERED", v["gl_backend"], v["gl_backend_chosen_by"], sim.render(sc.HEAD_CAMERA).std() > 2)
except RendererUnavailable as e:
    print("UNAVAILABLE", e)
"""


@pytest.mark.parametrize("backend", ["egl", "osmesa"])
def test_an_operator_set_mujoco_gl_is_used_or_diagnosed(backend):
    """MUJOCO_GL is honoured in a fresh process: that backend renders, or its absence is a
    RendererUnavailable naming the package (never MuJoCo's bare import failure, never another
    backend)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, MUJOCO_GL=backend)
    env.pop("PYOPENGL_PLATFORM", None)
    out = subprocess.run([sys.executable, "-c", _BUILD_AND_REPORT], env=env, capture_output=True, text=True,
                         timeout=120).stdout
    if gl._loads(backend):
        assert f"RENDERED {backend} MUJOCO_GL True" in out, out
    else:
        assert "UNAVAILABLE" in out and f"MUJOCO_GL={backend} was set" in out, out


def test_malformed_urdf_is_a_bad_command(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text('<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="revolute">'
                   '<parent link="a"/><child link="b"/><limit lower="zero" upper="1"/></joint></robot>')
    for text in (bad.read_text(), "<robot", '<robot name="x"><link name="a"/><link name="b"/></robot>'):
        bad.write_text(text)
        scene = SceneSpec(articulations=[ArticulatedObject("thing", str(bad))])
        with pytest.raises(BadCommand, match="URDF"):
            MujocoSimulator({"render": False}).build(scene, sc.make_embodiment())


def test_object_velocity_is_the_centre_of_mass_velocity():
    """A body whose centre of mass is off its origin, spinning freely: the reported linear
    velocity is the (constant) velocity of its centre of mass, which a finite difference of
    the centre's position confirms."""
    body = Body("bar", [Shape(Box((0.1, 0.02, 0.02)), pose=(0.2, 0, 0, 1, 0, 0, 0))], pose=(0, 0, 1, 1, 0, 0, 0),
                angular_damping=0.0)
    sim = MujocoSimulator({"render": False})
    sim.build(SceneSpec(bodies=[body], gravity=(0.0, 0.0, 0.0)), sc.make_embodiment())
    try:
        t = sim._things["bar"]
        sim._data.qvel[t.dadr:t.dadr + 6] = [0.0, 0.0, 0.0, 0.0, 0.0, 3.0]  # origin at rest, spinning
        com = lambda: transform_point(sim.get_object_pose("bar"), (0.2, 0, 0))  # noqa: E731
        c0 = com()
        v0 = sim.get_object_velocity("bar")
        sim.step(1)
        # one step's chord of the centre's path (it turns by w^2 r dt / 2 = 0.004 m/s within it)
        np.testing.assert_allclose(v0[:3], (com() - c0) / sim.timestep, atol=0.005)
        np.testing.assert_allclose(v0, [0.0, 0.6, 0.0, 0.0, 0.0, 3.0], atol=1e-9)  # w x r, r = 0.2 m
    finally:
        sim.close()


def test_any_thread_may_render():
    """The GL context is released after each picture: threads take turns (a host may serve tool
    calls from worker threads), and every picture of one state is the same."""
    import threading

    checks.require_renderer("mujoco")
    sim = sc.build(rendering)
    try:
        images, errors = [], []

        def take():
            try:
                images.append(sim.render(sc.HEAD_CAMERA))
            except Exception as e:  # noqa: BLE001 (reported below)
                errors.append(e)

        for _ in range(3):
            t = threading.Thread(target=take)
            t.start()
            t.join()
        take()
        assert errors == [] and len(images) == 4
        assert all(np.array_equal(images[0], im) for im in images[1:])
    finally:
        sim.close()


def test_two_simulators_render_concurrently():
    """Two simulators in one process, each driven by its own thread at the same time, share the
    process's GL context without corrupting each other's pictures."""
    import threading

    checks.require_renderer("mujoco")
    sims = [sc.build(rendering) for _ in range(2)]
    try:
        reference = sims[0].render(sc.HEAD_CAMERA)
        results: list = []

        def loop(sim):
            try:
                results.extend(np.array_equal(sim.render(sc.HEAD_CAMERA), reference) for _ in range(10))
            except Exception as e:  # noqa: BLE001 (reported below)
                results.append(e)

        threads = [threading.Thread(target=loop, args=(s,)) for s in sims]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert results == [True] * 20, results
    finally:
        for s in sims:
            s.close()


def test_an_attempt_through_the_cli_records_mujoco(tmp_path):
    """``cab +sim=mujoco`` composes conf/sim/mujoco.yaml, a physics override reaches the model,
    and the record names the simulator, its parameters and the GL renderer."""
    import json
    import os
    import subprocess
    import sys

    checks.require_renderer("mujoco")
    cab = os.path.join(os.path.dirname(sys.executable), "cab")
    r = subprocess.run([cab, "+sim=mujoco", "+model=oracle", "task=click_bell", "+sim.physics.impratio=12",
                        f"hydra.run.dir={tmp_path}/d"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads((tmp_path / "d" / "result.json").read_text())
    assert res["sim"] == "mujoco" and res["verdict"]["success"] is True
    v = res["versions"]["simulator"]
    assert v["simulator"] == "mujoco" and json.loads(v["physics"])["impratio"] == 12.0
    assert v["render"] == "on" and v["gl_backend"] in ("egl", "osmesa", "glfw") and v["llvmpipe"] in ("yes", "no")
