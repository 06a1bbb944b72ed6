"""The CodeActionBench suite: registration, the shared task helpers, and for beat_block_hammer,
stack_blocks_three and open_microwave seeded layouts within the FACTS ranges and verifiers that
accept hand-built success states.

Verifiers are exercised through :class:`FakeWorld`, a WorldView-compatible stand-in that serves
poses, joint positions, contacts and gripper commands from plain data (no simulator). The ``sim``
tests use the project's SAPIEN backend when it and an embodiment are installed.

The contract every task keeps (catalog entry, deterministic JSON builds, distinct seeded layouts, a
verifier that rejects every initial layout, catalog checkpoints) is checked in test_suite_tasks.py.
"""
from __future__ import annotations

from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
import suite_helpers as sh
from suite_helpers import FakeWorld, _cache, task_and_verifier  # noqa: F401 (_cache: autouse)

from cab_core.contracts.scene import ArticulatedObject, Box, Shape
from cab_core.contracts.task import Task
from cab_core.errors import PluginError
from cab_core.geometry import axis_angle_quat, quat_to_mat, transform_point
from cab_core.kits.assets import mesh_asset, write_asset
from cab_core.kits.scene import LayoutError, base_scene, lowest_point_z, rand_pose, sample_until, yaw_of
from cab_core.plugins import all_tasks, build_plugin_manager, registry
from cab_suite_codeaction import catalog, plugin
from cab_suite_codeaction.catalog import load_catalog
from cab_suite_codeaction.tasks import TASK_MODULES, load_tasks
from cab_suite_codeaction.tasks import beat_block_hammer as bbh

# the three tasks this file covers; every other task has its own test file (tests/test_suite_*.py)
TASKS = load_tasks(("beat_block_hammer", "stack_blocks_three", "open_microwave"))



# --- registration ---------------------------------------------------------------------------------
def test_suite_registers_through_the_plugin_manager():
    pm = build_plugin_manager(extra=[plugin], autoload=False)
    assert "codeaction" in registry("task_suites", pm)
    tasks = all_tasks(pm)
    from cab_suite_codeaction.tasks import TASK_MODULES

    assert set(TASKS) <= set(tasks)
    assert sorted(tasks) == sorted(TASK_MODULES)  # one task per registered module, named as its module
    catalog = [t["name"] for t in load_catalog()["tasks"]]
    assert set(tasks) <= set(catalog)
    assert all(isinstance(t, Task) for t in tasks.values())


def test_entry_point_declared():
    eps = {ep.name: ep.value for ep in metadata.entry_points(group="cab")}
    assert eps.get("suite_codeaction") == "cab_suite_codeaction.plugin"


def test_duplicate_task_ids_fail():
    with pytest.raises(PluginError, match="twice"):
        load_tasks(("stack_blocks_three", "stack_blocks_three"))


def test_one_module_per_task_named_after_it():
    every = load_tasks()
    assert set(TASK_MODULES) == set(every)
    for name, task in every.items():
        assert task.__class__.__module__.rsplit(".", 1)[1] == name
        assert task.info == catalog.task_info(name)


# --- layouts --------------------------------------------------------------------------------------
def _yaw(q):
    return yaw_of(q)


def test_beat_block_hammer_layouts(task_builds):
    task = TASKS["beat_block_hammer"]
    for inst in task_builds[task.name]:
        hammer, block = inst.scene.body("hammer"), inst.scene.body("block")
        assert hammer.kind == "dynamic" and 0.05 <= hammer.mass <= 0.2
        assert block.kind == "static"
        assert block.shapes[0].geometry == Box((0.025, 0.025, 0.025))
        assert np.allclose(hammer.pose[:2], (0.0, -0.06))
        # resting height from the geometry: the lowest point touches the table top (0.2 mm drop)
        low = hammer.pose[2] + lowest_point_z(hammer.shapes, hammer.pose[3:])
        assert 0.74 <= low <= 0.7405
        x, y, z = block.pose[:3]
        assert -0.25 <= x <= 0.25 and abs(x) >= 0.05 and -0.05 <= y <= 0.15
        assert z == pytest.approx(0.765)
        assert abs(_yaw(block.pose[3:])) <= 0.5 + 1e-9
        assert bbh._distance_to_footprint(np.asarray(block.pose[:2]) - hammer.pose[:2]) >= bbh.BLOCK_CLEARANCE
        assert inst.info["suggested_arm"] == ("right" if x > 0 else "left")


def test_hammer_geometry_is_graspable_and_privileged_points_consistent():
    info = TASKS["beat_block_hammer"].build(0, None).info["hammer"]
    assert 0.025 <= 2 * info["handle_radius"] <= 0.03 < 0.08  # fits the 8 cm gripper
    assert 0.20 <= info["handle_x_range"][1] - info["handle_x_range"][0] <= 0.25
    assert info["head_size"][1] == pytest.approx(0.105)
    lo, hi = info["handle_x_range"]
    assert lo < info["grasp_point"][0] < hi
    # the face point is on the head's end face, along the face normal from the head centre
    d = np.subtract(info["face_point"], info["head_center"])
    assert np.allclose(d / np.linalg.norm(d), info["face_normal"])
    assert np.linalg.norm(d) == pytest.approx(info["head_size"][1] / 2)


def test_stack_blocks_three_layouts(task_builds):
    task = TASKS["stack_blocks_three"]
    for inst in task_builds[task.name]:
        ps = [np.array(inst.scene.body(f"{c}_block").pose) for c in ("red", "green", "blue")]
        for p in ps:
            assert -0.28 <= p[0] <= 0.28 and abs(p[0]) >= 0.05
            assert -0.08 <= p[1] <= 0.05
            assert not (abs(p[0]) < 0.15 and p[1] > 0)  # ylim_prop
            assert p[2] == pytest.approx(0.766)
            assert abs(_yaw(p[3:])) <= 0.75 + 1e-9
            assert np.hypot(p[0], p[1] + 0.1) >= 0.15
        for i in range(3):
            for j in range(i + 1, 3):
                assert np.hypot(*(ps[i][:2] - ps[j][:2])) >= 0.10
        for c in ("red", "green", "blue"):
            b = inst.scene.body(f"{c}_block")
            assert b.kind == "dynamic" and b.shapes[0].geometry == Box((0.025,) * 3)
        assert inst.info["stack_order"] == ["red", "green", "blue"]


def test_open_microwave_layouts_and_urdf(task_builds):
    task = TASKS["open_microwave"]
    models = set()
    for inst in task_builds[task.name]:
        (mw,) = inst.scene.articulations
        assert isinstance(mw, ArticulatedObject) and mw.fix_root and mw.qpos == (0.0,)
        assert -0.12 <= mw.pose[0] <= -0.02 and 0.15 <= mw.pose[1] <= 0.20
        assert mw.pose[2] == pytest.approx(0.74)  # stands on the table (origin at its bottom)
        assert np.allclose(mw.pose[3:], (1, 0, 0, 0))
        m = inst.info["microwave"]
        models.add(m["model_id"])
        assert mw.pose[1] + m["size"][1] / 2 < 0.4  # clear of the wall
        sh.check_urdf_hinge(mw.urdf, (m["base_link"], m["door_link"]), m["door_joint"], m["door_limits"],
                         m["hinge_point_base"], m["hinge_axis_base"])
        assert 1.5 <= m["door_limits"][1] <= 2.2
        assert m["hinge_side"] == "left" and m["hinge_point_base"][0] < 0
        hx, hy, hz = m["handle_point_door"]
        assert m["door_width"] * 0.8 < hx < m["door_width"]  # on the free edge
        assert hy < -m["door_thickness"] - 0.02  # stands out in front of the door
        assert 0 < hz < m["door_height"]
        assert m["handle_clearance"] >= 0.02
    assert models == {0, 1}


def test_door_opens_toward_the_robot():
    m = TASKS["open_microwave"].build(0, None).info["microwave"]
    # rotating the handle about the hinge axis by +q moves it toward -y (the robot)
    q = 0.5
    rot = quat_to_mat(axis_angle_quat(m["hinge_axis_base"], q))
    moved = rot @ np.asarray(m["handle_point_door"])
    assert moved[1] < m["handle_point_door"][1] - 0.1
    assert moved[0] < m["handle_point_door"][0]  # swinging to the left


# --- verifiers ------------------------------------------------------------------------------------
def _strike(inst, offset=(0.0, 0.0)):
    """Hammer turned face-down (roll +90 deg about x) with its face on the block's top centre."""
    info = inst.info
    top = transform_point(info["block"]["pose"], info["block"]["top_point"])
    q = axis_angle_quat([1, 0, 0], np.pi / 2)
    pos = top - quat_to_mat(q) @ np.asarray(info["hammer"]["face_point"]) + [offset[0], offset[1], 0.0]
    return np.concatenate([pos, q])


def test_beat_block_hammer_verifier():
    task, inst, v = task_and_verifier("beat_block_hammer")
    assert v.scoring == "latch" and v.poll_every == 1 and v.guarded_objects == ("hammer",)
    w = FakeWorld(inst)
    w.poses["hammer"] = _strike(inst)
    face = transform_point(w.poses["hammer"], inst.info["hammer"]["face_point"])
    assert face[2] == pytest.approx(inst.info["block"]["pose"][2] + 0.025)  # face down on the top
    assert task.verifier(inst).evaluate(w).predicates == {"face_over_block": True, "hammer_touches_block": False}
    w.touching.add(frozenset(("hammer", "block")))
    assert v.evaluate(w).success
    w.poses["hammer"] = _strike(inst, (0.019, -0.019))
    assert v.evaluate(w).success
    w.poses["hammer"] = _strike(inst, (0.021, 0.0))
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["face_over_block"] is False
    assert ev.values["face_dx"] == pytest.approx(0.021, abs=1e-5)
    # guard: the hammer knocked off the table
    assert v.guard(w) == {"hammer_on_table": True}
    w.poses["hammer"][2] = 0.6
    assert v.guard(w) == {"hammer_on_table": False}


def _stacked(inst, w, base_xy=(0.0, -0.1), d_green=(0, 0, 0), d_blue=(0, 0, 0)):
    z0 = inst.info["resting_center_z"]
    red = np.array([base_xy[0], base_xy[1], z0])
    green = red + [0, 0, 0.05] + np.asarray(d_green)
    blue = green + [0, 0, 0.05] + np.asarray(d_blue)
    for n, p in (("red_block", red), ("green_block", green), ("blue_block", blue)):
        w.poses[n] = np.concatenate([p, [1, 0, 0, 0]])


def test_stack_blocks_three_verifier():
    task, inst, v = task_and_verifier("stack_blocks_three")
    assert v.scoring == "final" and set(v.guarded_objects) == {"red_block", "green_block", "blue_block"}
    w = FakeWorld(inst)
    _stacked(inst, w, d_green=(0.02, -0.02, 0.01), d_blue=(-0.024, 0.0, -0.011))
    ev = v.evaluate(w)
    assert ev.success and ev.predicates == {"green_on_red": True, "blue_on_green": True, "grippers_open": True}
    # not scored: where on the table the stack stands (FACTS B.6; paper appendix lists no change)
    _stacked(inst, w, base_xy=(0.25, 0.0))
    assert v.evaluate(w).success
    _stacked(inst, w, d_green=(0.026, 0, 0))
    assert v.evaluate(w).predicates["green_on_red"] is False
    _stacked(inst, w, d_blue=(0, 0, 0.013))
    assert v.evaluate(w).predicates == {"green_on_red": True, "blue_on_green": False, "grippers_open": True}
    _stacked(inst, w)
    w.grip["left"] = 0.8  # must be strictly above 0.8
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["grippers_open"] is False
    # the wrong order (red on top) fails
    w.grip["left"] = 1.0
    w.poses["red_block"], w.poses["blue_block"] = w.poses["blue_block"].copy(), w.poses["red_block"].copy()
    assert not v.evaluate(w).success


def test_open_microwave_verifier():
    task, inst, v = task_and_verifier("open_microwave")
    w = FakeWorld(inst)
    upper = inst.info["microwave"]["door_limits"][1]
    for frac, ok in ((0.0, False), (0.59, False), (0.6, True), (0.7, True), (1.0, True)):
        w.qpositions["microwave"] = np.array([frac * upper])
        ev = v.evaluate(w)
        assert ev.success is ok and ev.predicates == {"door_open": ok}
        assert ev.values["door_fraction"] == pytest.approx(frac)


# --- the task kit's helpers -----------------------------------------------------------------------
def test_rand_pose_limits_and_ylim_prop():
    rng = np.random.default_rng(0)
    for _ in range(500):
        p = rand_pose(rng, (-0.3, 0.3), (-0.1, 0.1), ylim_prop=True, rotate_rand=True,
                             rotate_lim=(0, 0, 0.5))
        assert -0.3 <= p[0] <= 0.3 and -0.1 <= p[1] <= 0.1 and p[2] == 0.741
        assert not (abs(p[0]) < 0.15 and p[1] > 0)
        assert abs(yaw_of(p[3:])) <= 0.5 + 1e-9
        assert np.allclose(quat_to_mat(p[3:])[:, 2], (0, 0, 1))  # yaw only
        assert p[3] >= 0


def test_sample_until_fails_loudly():
    with pytest.raises(LayoutError, match="widget"):
        sample_until(lambda: np.zeros(7), lambda p: False, what="the widget", max_tries=10)


def test_lowest_point_z():
    shapes = [Shape(Box((0.1, 0.2, 0.05)))]
    assert lowest_point_z(shapes) == pytest.approx(-0.05)
    q = axis_angle_quat([1, 0, 0], np.pi / 2)
    assert lowest_point_z(shapes, q) == pytest.approx(-0.2)


def test_write_asset_is_content_addressed_and_atomic(tmp_path, monkeypatch):
    monkeypatch.setenv("CAB_CACHE_DIR", str(tmp_path))
    a = write_asset("thing", b"hello", ".txt")
    b = write_asset("thing", b"hello", ".txt")
    c = write_asset("thing", b"world", ".txt")
    assert a == b != c and a.read_bytes() == b"hello" and a.parent == tmp_path / "assets"
    assert not [p for p in a.parent.iterdir() if p.suffix == ".tmp"]


def test_mesh_asset_deterministic(tmp_path, monkeypatch):
    trimesh = pytest.importorskip("trimesh")
    monkeypatch.setenv("CAB_CACHE_DIR", str(tmp_path))
    p1 = mesh_asset("box", trimesh.creation.box((0.1, 0.2, 0.3)))
    p2 = mesh_asset("box", trimesh.creation.box((0.1, 0.2, 0.3)))
    assert p1 == p2 and Path(p1).suffix == ".obj"
    assert np.allclose(trimesh.load(p1).extents, (0.1, 0.2, 0.3))


def test_base_scene_facts():
    sc = base_scene()
    table, wall = sc.body("table"), sc.body("wall")
    assert table.kind == wall.kind == "static"
    assert table.shapes[0].geometry == Box((0.6, 0.35, 0.025))
    assert table.pose[2] + 0.025 == pytest.approx(0.74)
    assert wall.pose[1] - wall.shapes[0].geometry.half_size[1] == pytest.approx(0.4)
    assert sc.timestep == pytest.approx(1 / 250)
    assert base_scene(table_x=0.3, table_z_bias=-0.1).body("table").pose[:3] == pytest.approx((0.3, 0, 0.615))


# --- with the SAPIEN backend --------------------------------------------------------------------
@pytest.mark.sim
@pytest.mark.parametrize("name", sorted(TASKS))
def test_sim_initial_scene_settles_and_fails(name):
    with sh.sapien_world(TASKS[name], sim_config={}) as (sim, emb, inst):
        sh.check_settled_scene_fails(TASKS[name], sim, emb, inst, 250)


def _pose_success_state(name, inst, sim):
    if name == "beat_block_hammer":
        sim.set_object_pose("hammer", _strike(inst) + np.r_[0, 0, 0.0005, 0, 0, 0, 0])
    elif name == "stack_blocks_three":
        z0 = inst.info["resting_center_z"]
        for i, c in enumerate(("red", "green", "blue")):
            sim.set_object_pose(f"{c}_block", [0.002 * i, -0.1, z0 + 0.05 * i + 0.0005, 1, 0, 0, 0])
    elif name == "open_microwave":
        # the open door sweeps through where the left gripper waits at home: park that arm up and
        # away first (shoulder lifted), as the reference solution does before the door swings wide
        q = sim.get_qpos()
        q[sim.joint_names.index("fl_joint2")] -= 0.6
        sim.set_qpos(q)
        sim.set_object_qpos("microwave", [0.7 * inst.info["microwave"]["door_limits"][1]])


@pytest.mark.sim
@pytest.mark.parametrize("name", sorted(TASKS))
def test_sim_success_state_passes(name):
    task = TASKS[name]
    with sh.sapien_world(task, sim_config={}) as (sim, emb, inst):
        sim.step(task.settle_steps())
        w = sh.world_view(sim, emb, inst)
        v = task.verifier(inst)
        _pose_success_state(name, inst, sim)
        sh.check_success_holds(task, sim, w, v, 2)
        if name != "beat_block_hammer":  # the stack and the open door stay put
            sim.step(250)
            assert v.evaluate(w).success
