"""Issue 26, item 13: objects in their declared colours on every simulator.

PyBullet drew a link given no visual shape as its collision shapes, in white: a body with more
collision shapes than a Bullet link takes (lift_pot's pot: 25) had its second link's collision
boxes drawn over its own visual shapes (white handles, a white band on the wall, flickering with
the depth order). The conformance check :mod:`cab_core.testing.appearance_conformance` measures
every object material's colour in each task's initial picture and catches that."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from cab_core.contracts.scene import Body, Box, CameraSpec, Material, SceneSpec, Shape
from cab_core.errors import ConfigError
from cab_core.geometry import extrinsic_from_pose, intrinsics, look_at_cv, project_points
from cab_core.kits.assets import hinged_urdf, urdf_part
from cab_core.plugins import all_tasks, registry
from cab_core.testing import appearance_conformance as ac
from cab_core.testing import sim_conformance as sc

SIMS = [s for s in ("mujoco", "pybullet", "sapien") if importlib.util.find_spec(f"cab_sim_{s}") is not None]
BLACK = Material(color=(0.01, 0.01, 0.01, 1.0))


def _sim(name: str):
    return registry("simulators")[name]({"name": name, "render": True})


def _rack_scene() -> SceneSpec:
    """A black box on the left and, in the same body, 17 collision-only boxes in a row on the right
    (PyBullet: 18 collision shapes make two links; the second one, boxes 15 and 16 of the row,
    carries no visual shape)."""
    shapes = [Shape(Box((0.05, 0.05, 0.05)), pose=(-0.2, 0, 0.05, 1, 0, 0, 0), material=BLACK)]
    shapes += [Shape(Box((0.012, 0.05, 0.05)), pose=(-0.05 + 0.03 * i, 0, 0.05, 1, 0, 0, 0), material=BLACK,
                     visual=False) for i in range(17)]
    cam = CameraSpec("cam", 160, 120, 60.0, pose=tuple(look_at_cv((0.1, 1.2, 0.5), (0.1, 0.4, 0.05))))  # robot behind
    return SceneSpec(bodies=[Body("rack", shapes, pose=(0, 0.4, 0, 1, 0, 0, 0), kind="static")], cameras=[cam])


@pytest.mark.skipif("pybullet" not in SIMS, reason="PyBullet is not installed")
def test_pybullet_collision_only_shapes_are_never_drawn():
    """Removing the body changes no pixel where only its collision-only boxes are (those of its
    second link used to be drawn white), and does change the pixels of its visual box."""
    sim = _sim("pybullet")
    try:
        sim.build(_rack_scene(), sc.make_embodiment())
        with_body = sim.render("cam").astype(int)
        K, E = sim.camera_intrinsics("cam"), extrinsic_from_pose(sim.camera_pose("cam"))
        sim.set_object_pose("rack", (0, 0, -100, 1, 0, 0, 0))
        without = sim.render("cam").astype(int)
    finally:
        sim.close()
    uv, _ = project_points(K, E, [[-0.05 + 0.03 * i, 0.45, 0.05] for i in range(17)] + [[-0.2, 0.45, 0.05]])
    px = np.floor(uv).astype(int)
    for u, v in px[:-1]:
        assert np.array_equal(with_body[v - 2:v + 3, u - 2:u + 3], without[v - 2:v + 3, u - 2:u + 3]), (u, v)
    u, v = px[-1]
    assert np.abs(with_body[v, u] - without[v, u]).sum() > 60


@pytest.mark.skipif("pybullet" not in SIMS, reason="PyBullet is not installed")
def test_the_check_catches_pybullet_drawing_collision_shapes(monkeypatch):
    """With PyBullet's old behaviour restored (a link without visual shapes gets none: -1), the
    check reports lift_pot's black handle material as far too bright and its red body's hue off
    (the white band). As it is now, it passes (test_lift_pot_shows_its_declared_colours)."""
    from cab_sim_pybullet.simulator import PybulletSimulator  # here: the test is skipped without PyBullet

    factory = lambda: _sim("pybullet")  # noqa: E731
    monkeypatch.setattr(PybulletSimulator, "_no_visual", lambda self: -1)
    bad = ac.judge(ac.task_regions(factory, "lift_pot"))
    # the white collision boxes: handles far too bright, a white band that turns the red wall's hue
    assert len(bad) == 2, bad
    assert bad[0].startswith("pot (0.57, 0.01, 0.01) shows ") and "its hue is" in bad[0], bad
    assert bad[1].startswith("pot (0.01, 0.01, 0.01) shows ") and "x the picture's median brightness" in bad[1], bad
    with pytest.raises(AssertionError, match=r"lift_pot: pot \(0\.01, 0\.01, 0\.01\)"):
        ac.check_appearance(factory, ["lift_pot"])


@pytest.mark.parametrize("sim", SIMS)
def test_lift_pot_shows_its_declared_colours(sim):
    """On every simulator: the pot's red body, light lining and black handles are measured (enough
    pixels) and agree with their declared colours."""
    regions = ac.task_regions(lambda: _sim(sim), "lift_pot")
    pot = {r.declared: r for r in regions if r.obj == "pot"}
    assert len(pot) == 3 and all(r.measured is not None for r in pot.values()), [(r.label(), r.pixels) for r in regions]
    assert ac.judge(regions) == []
    handle = min(pot.values(), key=lambda r: ac._lum(r.declared))
    body = max(pot.values(), key=lambda r: r.declared[0] - r.declared[1])
    assert ac._lum(handle.measured) < 0.05 < ac._lum(body.measured)  # black handles, not white
    assert body.hue_deg < 5 and body.measured[0] > 5 * body.measured[1]  # a red body, no white band


def test_rasterize_keeps_the_nearest_shape():
    """Two boxes in line with the camera: the near one covers the far one where they overlap; the
    far one shows beside it; nothing else is labelled."""
    cam = look_at_cv((0.0, -1.0, 0.0), (0.0, 0.0, 0.0))
    K = intrinsics(100, 100, 60.0)
    near = ac._transform(ac._primitive_triangles(Box((0.05, 0.05, 0.05))), (0, -0.5, 0, 1, 0, 0, 0))
    far = ac._transform(ac._primitive_triangles(Box((0.2, 0.05, 0.05))), (0.1, 0, 0, 1, 0, 0, 0))
    lab = ac.rasterize(K, cam, (100, 100), [far, near])
    assert lab[50, 50] == 1 and lab[50, 70] == 0 and lab[5, 5] == -1 and lab[50, 2] == -1 and lab[50, 90] == -1
    # the near box's front face: 0.1 m wide at 0.45 m, f = 50 / tan(30 deg) px: 19.2 px across
    cols = np.nonzero((lab == 1).any(axis=0))[0]
    assert abs(len(cols) - 0.1 / 0.45 * K[0, 0]) <= 1


def test_judge_states_what_is_wrong():
    red = ac.Region("cup", (0.6, 0.05, 0.05), 500, (0.3, 0.025, 0.025))
    black = ac.Region("cup", (0.01, 0.01, 0.01), 500, (0.005, 0.005, 0.005))
    grey = ac.Region("cup", (0.3, 0.3, 0.3), 500, (0.15, 0.15, 0.15))
    assert ac.judge([red, black, grey]) == []
    white_handles = ac.Region("pot", (0.01, 0.01, 0.01), 500, (0.6, 0.6, 0.6))
    [msg] = ac.judge([red, grey, white_handles])
    assert msg.startswith("pot (0.01, 0.01, 0.01) shows (0.60, 0.60, 0.60): ") and "allowed 1/4 to 4" in msg
    washed = ac.Region("cup", (0.6, 0.05, 0.05), 500, (0.5, 0.5, 0.5))
    [msg] = ac.judge([washed, grey])
    assert "hue is 48 deg off (at most 15)" in msg  # acos((0.6 + 0.05 + 0.05) / (0.6036 * 1.732))


def test_task_selection(monkeypatch):
    installed = list(all_tasks())
    monkeypatch.delenv(ac.ENV_TASKS, raising=False)
    chosen = ac.selected_tasks()
    assert chosen == list(ac.representative_tasks()) and len(chosen) == ac.REPRESENTATIVE_COUNT
    assert set(chosen) <= set(installed)
    # among them a scene where white collision shapes would show: a dark body split over links
    emb = ac._embodiment()
    tasks = all_tasks()
    feats = set().union(*(ac.scene_features(tasks[t].build(tasks[t].info.seed, emb).scene)[0] for t in chosen))
    assert {"near-black body of collision shapes past one link", "articulated", "visual shapes past one link",
            "three colours on one body", "saturated"} <= feats
    monkeypatch.setenv(ac.ENV_TASKS, "all")
    assert ac.selected_tasks() == installed
    monkeypatch.setenv(ac.ENV_TASKS, "lift_pot, open_microwave")
    assert ac.selected_tasks() == ["lift_pot", "open_microwave"]
    monkeypatch.setenv(ac.ENV_TASKS, "lift_pot,no_such_task")
    with pytest.raises(ConfigError, match="CAB_APPEARANCE_TASKS: unknown task.s. no_such_task; installed: "):
        ac.selected_tasks()


def test_the_check_runs_with_the_simulator_conformance_suite():
    assert ac.check_appearance in sc.CHECKS and ac.check_appearance in sc.NEEDS_RENDERER
    assert sc.check_id(ac.check_appearance) == "appearance"


def test_a_urdf_material_name_carries_one_colour():
    """Simulators keep either the first or the last colour given under one URDF material name (the
    microwave's buttons and knob once differed per simulator): the suite refuses two colours per name."""
    def build(knob_material):
        parts = [urdf_part("box", (0.1, 0.1, 0.1), (0, 0, 0), rgba=(0.8, 0.8, 0.82, 1), material="button"),
                 urdf_part("box", (0.1, 0.1, 0.1), (0, 0, 0.2), rgba=(0.55, 0.55, 0.58, 1), material=knob_material)]
        return hinged_urdf("thing", base_inertial="", base_parts=parts, child="door", child_inertial="",
                           child_parts=[], joint="hinge", origin=(0, 0, 0), axis="0 0 1", upper=1.0,
                           velocity=1.0, damping=0.1, friction=0.0)

    assert 'material name="knob"' in build("knob")
    with pytest.raises(ValueError, match=r"thing: material 'button' is given two colours"):
        build("button")
