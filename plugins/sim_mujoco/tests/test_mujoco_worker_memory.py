"""What a waiting MuJoCo worker holds: a scene sized from its model (no geom ever dropped, the same
pictures as the fixed 20000 geoms before), and the fork server's preparation (``cab_preload``) that
loads the GL libraries and bindings the worker's renderer uses without starting anything."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mujoco")

import mujoco  # noqa: E402
import sim_backend_checks as checks  # noqa: E402

from cab_sim_mujoco import gl  # noqa: E402
from cab_sim_mujoco.mjcf import VISUAL_GROUP  # noqa: E402
from cab_sim_mujoco.simulator import _Renderer, scene_capacity  # noqa: E402

pytestmark = pytest.mark.sim

W, H = 96, 72
N = 3000  # more geoms than a capacity of "a few hundred" would hold


def _crowd() -> mujoco.MjModel:
    """``N`` small visible boxes on a grid in front of one camera, and one hidden (collision) box."""
    boxes = "".join(f"<geom type='box' size='.004 .004 .004' pos='{(i % 60) * .01 - .3:.3f} 0 "
                    f"{(i // 60) * .01:.3f}' rgba='{i % 7 / 7:.3f} .5 {i % 11 / 11:.3f} 1' group='{VISUAL_GROUP}'/>"
                    for i in range(N))
    xml = (f"<mujoco><visual><global offwidth='{W}' offheight='{H}'/></visual><worldbody>"
           "<light pos='0 -1 2'/><camera name='c' pos='0 -0.8 0.25' xyaxes='1 0 0 0 0 1'/>"
           f"{boxes}<geom type='box' size='.1 .1 .1' pos='0 0 -1' group='3'/></worldbody></mujoco>")
    return mujoco.MjModel.from_xml_string(xml)


def test_the_scene_holds_every_geom_of_a_crowded_model_and_pictures_do_not_change(tmp_path, monkeypatch):
    checks.require_renderer("mujoco")
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the full scene's warning to MUJOCO_LOG.TXT here
    model = _crowd()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    r = _Renderer(model, W, H)
    try:
        assert N < r.scene.maxgeom == scene_capacity(model) < 20000
        image = r.render(model, data, 0, W, H)
        assert r.scene.ngeom == N  # every visible box, the hidden one not
        assert image.std() > 5
        # the same picture as the former fixed capacity draws
        r.scene = mujoco.MjvScene(model, maxgeom=20000)
        assert np.array_equal(r.render(model, data, 0, W, H), image)
        # a full scene grows and draws everything rather than leaving geoms out
        r.scene = mujoco.MjvScene(model, maxgeom=100)
        again = r.render(model, data, 0, W, H)
        assert r.scene.ngeom == N and r.scene.maxgeom > N
        assert "geom buffer is full" in (tmp_path / "MUJOCO_LOG.TXT").read_text()  # the overflow was real
        assert np.array_equal(again, image)
    finally:
        r.free()


def test_the_capacity_holds_a_scene_drawn_with_every_decoration_on():
    """Sites, joints, tendons, actuators, sensors, cameras, lights, inertia, centres of mass, body
    frames and contacts all drawn (every flag on): the scene is still not full."""
    chain = "".join(f"<body pos='0 0 .05'><joint name='j{i}' axis='0 1 0'/><geom type='capsule' size='.01 .02'/>"
                    f"<site name='s{i}'/><camera name='c{i}'/><light pos='0 0 1'/>" for i in range(40))
    xml = (f"<mujoco><worldbody><geom type='plane' size='1 1 .1'/><body pos='0 0 .01'>{chain}{'</body>' * 40}"
           "<site name='end'/></body><body pos='.1 0 .02'><freejoint/><geom type='box' size='.02 .02 .02'/></body>"
           "</worldbody><tendon><spatial name='t'><site site='s0'/><site site='s20'/><site site='s39'/></spatial>"
           "</tendon><actuator>" + "".join(f"<motor joint='j{i}'/>" for i in range(40)) + "</actuator>"
           "<sensor><rangefinder site='s5'/><rangefinder site='s6'/></sensor></mujoco>")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data)
    option = mujoco.MjvOption()
    option.flags[:] = 1
    option.geomgroup[:] = 1
    option.sitegroup[:] = 1
    option.jointgroup[:] = 1
    option.tendongroup[:] = 1
    option.actuatorgroup[:] = 1
    option.frame = mujoco.mjtFrame.mjFRAME_BODY
    scene = mujoco.MjvScene(model, maxgeom=scene_capacity(model))
    mujoco.mjv_updateScene(model, data, option, mujoco.MjvPerturb(), mujoco.MjvCamera(),
                           mujoco.mjtCatBit.mjCAT_ALL, scene)
    assert data.ncon > 0 and 200 < scene.ngeom < scene.maxgeom


_PRELOAD = """
import json, os, sys
import cab_sim_mujoco
cab_sim_mujoco.cab_preload()
from OpenGL import platform
maps = open("/proc/self/maps").read()
out = {"threads": len(os.listdir("/proc/self/task")), "platform": type(platform.PLATFORM).__name__,
       "gl": "OpenGL.GL" in sys.modules, "egl_mesa": "libEGL_mesa" in maps, "osmesa": "libOSMesa" in maps}
from cab_core.testing import sim_conformance as sc
from cab_sim_mujoco.simulator import MujocoSimulator
sim = MujocoSimulator({"render": True})
sim.build(sc.make_scene(), sc.make_embodiment())
out["backend"] = sim.versions()["gl_backend"]
out["rendered"] = bool(sim.render(sc.HEAD_CAMERA).std() > 2)
print(json.dumps(out))
"""


@pytest.mark.parametrize("backend", ["egl", "osmesa"])
def test_the_fork_servers_hook_loads_the_chosen_backend_and_starts_nothing(backend):
    """In a fresh process as the fork server: ``MUJOCO_GL``'s backend is loaded and PyOpenGL bound
    to it, no thread is started by the hook, and a context of that backend then renders."""
    if not gl._loads(backend):
        pytest.skip(f"{backend} is not installed here")
    env = dict(os.environ, MUJOCO_GL=backend)
    env.pop("PYOPENGL_PLATFORM", None)
    run = subprocess.run([sys.executable, "-c", _PRELOAD], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.splitlines()[-1])
    assert out["threads"] == 1 and out["gl"]
    assert out["platform"] == ("EGLPlatform" if backend == "egl" else "OSMesaPlatform")
    assert out["egl_mesa"] == (backend == "egl") and out["osmesa"] == (backend == "osmesa")
    assert out["backend"] == backend and out["rendered"]


def test_the_hook_loads_nothing_when_no_backend_can_start(monkeypatch):
    monkeypatch.setattr(gl, "_loads", lambda backend: False)
    assert gl.preload() == []
