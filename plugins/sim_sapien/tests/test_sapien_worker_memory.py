"""What a waiting SAPIEN worker holds: the default shader pack's unread pictures in 8 bits (the colour
pictures unchanged, bit for bit), and the fork server's preparation (``cab_preload``) that loads the
Vulkan loader and Mesa's drivers without creating an instance or a device."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("sapien")

import sim_backend_checks as checks  # noqa: E402

from cab_core.testing import sim_conformance as sc  # noqa: E402
from cab_sim_sapien import simulator as sapien_sim  # noqa: E402

pytestmark = pytest.mark.sim

rendering = checks.backend("sapien").rendering


def _pictures(sim) -> dict[str, np.ndarray]:
    return {name: sim.render(name) for name in sim.camera_names()}


def test_unread_pictures_are_8_bit_and_the_colour_pictures_do_not_change(monkeypatch):
    checks.require_renderer("sapien")
    slim = sc.build(rendering)
    try:
        small = _pictures(slim)
        cam = slim._cameras[sc.HEAD_CAMERA].component
        assert np.asarray(cam.get_picture("Position")).dtype == np.uint8
        assert np.asarray(cam.get_picture("Color")).dtype == np.float32
    finally:
        slim.close()
    monkeypatch.setattr(sapien_sim, "_UNREAD_PICTURES", ())  # SAPIEN's own formats, as before
    full = sc.build(rendering)
    try:
        as_before = _pictures(full)
        assert np.asarray(full._cameras[sc.HEAD_CAMERA].component.get_picture("Position")).dtype == np.float32
    finally:
        full.close()
    assert small.keys() == as_before.keys() and len(small) == 2
    for name in small:
        assert small[name].std() > 2 and np.array_equal(small[name], as_before[name]), name


_PRELOAD = """
import json, os
import cab_sim_sapien
cab_sim_sapien.cab_preload()
maps = open("/proc/self/maps").read()
out = {"threads": len(os.listdir("/proc/self/task")), "loader": "libvulkan.so" in maps,
       "lavapipe": "libvulkan_lvp" in maps}
from cab_core.testing import sim_conformance as sc
from cab_sim_sapien.simulator import SapienSimulator
sim = SapienSimulator({"render": True})
sim.build(sc.make_scene(), sc.make_embodiment())
out["rendered"] = bool(sim.render(sc.HEAD_CAMERA).std() > 2)
print(json.dumps(out))
"""


def test_the_fork_servers_hook_loads_the_vulkan_libraries_and_starts_nothing():
    checks.require_renderer("sapien")
    from cab_sim_sapien import renderer

    if not renderer.lavapipe()["library"]:
        pytest.skip("no lavapipe here")
    run = subprocess.run([sys.executable, "-c", _PRELOAD], env=dict(os.environ), capture_output=True, text=True,
                         timeout=180)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.splitlines()[-1])
    assert out == {"threads": 1, "loader": True, "lavapipe": True, "rendered": True}


def test_the_warm_up_picture_leaves_the_worlds_cameras_unpictured(monkeypatch):
    """The process's first picture (pipelines compiled while building) is taken by a throwaway camera:
    no camera of the world holds pictures until it is pictured, and none is left behind."""
    checks.require_renderer("sapien")
    monkeypatch.setattr(sapien_sim, "_WARMED_SHADERS", set())
    sim = sc.build(rendering)
    try:
        assert sapien_sim._WARMED_SHADERS == {"default"}
        assert sorted(sim.camera_names()) == sorted([sc.HEAD_CAMERA, sc.WRIST_CAMERA])
        assert "cab_warm_up" not in [e.name for e in sim._scene.entities]
        for name in sim.camera_names():
            with pytest.raises(IndexError):  # SAPIEN: no picture taken, nothing allocated
                sim._cameras[name].component.get_picture("Color")
        assert sim.render(sc.HEAD_CAMERA).std() > 2
    finally:
        sim.close()
