"""The bins group of the CodeActionBench suite (pick_diverse_bottles, put_bottles_dustbin,
dump_bin_bigbin): deterministic seeded layouts within the FACTS ranges, generated assets of plausible
size, verifiers that accept hand-built success states and reject near misses, and checkpoints that
follow the bottles.

Verifiers run on :class:`FakeWorld` (plain data, no simulator); the ``sim`` tests build the real
scene with the SAPIEN backend and check that it settles, fails the verifier, and (where the success
state is a resting one) that a success state built in the simulator passes.

The contract every task keeps (catalog entry, deterministic JSON builds, distinct seeded layouts, a
verifier that rejects every initial layout, catalog checkpoints) is checked in test_suite_tasks.py.
"""
from __future__ import annotations

import numpy as np
import pytest
import suite_helpers as sh
from suite_helpers import SEEDS, TASKS, FakeWorld, _cache, task_and_verifier  # noqa: F401 (_cache: autouse)

from cab_core.attempt.engine.episode import VerdictTracker
from cab_core.geometry import axis_angle_quat, quat_to_mat, transform_point
from cab_core.kits.scene import yaw_of
from cab_suite_codeaction import assets_bins

NAMES = ("pick_diverse_bottles", "put_bottles_dustbin", "dump_bin_bigbin")


# --- assets ---------------------------------------------------------------------------------------------
def test_bottles_are_plausible_and_graspable():
    trimesh = pytest.importorskip("trimesh")
    styles = list(assets_bins.DIVERSE_BOTTLES) + list(assets_bins.DRINK_BOTTLES.values())
    assert len(assets_bins.DIVERSE_BOTTLES) == 20 and len({s.kind for s in assets_bins.DIVERSE_BOTTLES}) >= 8
    for s in styles:
        assert 0.10 <= s.height <= 0.26 and 0.04 <= 2 * s.radius <= 0.075
        assert 0.04 <= s.grasp_width <= 0.075  # fits the 8 cm gripper
        assert 0.03 <= s.mass <= 0.4
        prof = assets_bins.bottle_profile(s)
        assert prof[0][0] == 0 and prof[-1][0] == 0 and np.all(prof[:, 0] >= 0)
    shapes = assets_bins.bottle_shapes(assets_bins.DIVERSE_BOTTLES[0], "t-bottle")
    hull = [s for s in shapes if s.collision]
    assert len(hull) == 1 and hull[0].geometry.convex
    m = trimesh.load(hull[0].geometry.path)
    s = assets_bins.DIVERSE_BOTTLES[0]
    assert m.bounds[0][2] == pytest.approx(-s.height / 2, abs=1e-3)
    assert m.bounds[1][2] == pytest.approx(s.height / 2, abs=1e-3)
    assert m.extents[0] == pytest.approx(2 * s.radius, rel=0.02)


# --- pick_diverse_bottles ---------------------------------------------------------------------------
def test_pick_diverse_bottles_layouts():
    task = TASKS["pick_diverse_bottles"]
    models = set()
    for seed in SEEDS:
        inst = task.build(seed, None)
        for key, (lo, hi) in (("bottle1", (-0.25, -0.05)), ("bottle2", (0.05, 0.25))):
            b = inst.scene.body(key)
            info = inst.info[key]
            x, y, z = b.pose[:3]
            assert lo <= x <= hi and 0.03 <= y <= 0.23
            assert z - info["height"] / 2 == pytest.approx(0.741)  # standing on the table
            assert abs(yaw_of(b.pose[3:])) <= 1.0 + 1e-9
            assert np.allclose(transform_point(b.pose, [0, 0, 1]) - b.pose[:3], [0, 0, 1])  # upright
            assert b.kind == "dynamic" and 0.05 <= b.mass <= 0.4
            assert 0 <= info["model_id"] < 20
            models.add(info["model_id"])
        assert inst.info["arm_of"] == {"bottle1": "left", "bottle2": "right"}
    assert len(models) >= 8


def _hold(inst, w, key, xyz):
    w.poses[key] = np.array([*xyz, 1.0, 0.0, 0.0, 0.0])


def test_pick_diverse_bottles_verifier():
    task, inst, v = task_and_verifier("pick_diverse_bottles")
    assert v.scoring == "final" and set(v.guarded_objects) == {"bottle1", "bottle2"}
    w = FakeWorld(inst)
    _hold(inst, w, "bottle1", (-0.12, -0.1, 0.95))
    _hold(inst, w, "bottle2", (0.12, -0.1, 0.95))
    ev = v.evaluate(w)
    assert ev.success and all(ev.predicates.values())
    assert task.subgoals(w) == [True, True, True]
    # tolerances: 0.1 m per axis around the targets, centre above 0.89 m
    _hold(inst, w, "bottle1", (-0.06 - 0.099, -0.105 + 0.099, 0.891))
    assert v.evaluate(w).success
    _hold(inst, w, "bottle1", (-0.06 - 0.101, -0.105, 0.95))
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["bottle1_xy"] is False
    assert task.subgoals(w) == [False, True, False]
    _hold(inst, w, "bottle1", (-0.12, -0.1, 0.889))
    assert v.evaluate(w).predicates["bottle1_raised"] is False
    # the bottles swapped between the targets do not count
    _hold(inst, w, "bottle1", (0.12, -0.1, 0.95))
    _hold(inst, w, "bottle2", (-0.12, -0.1, 0.95))
    assert not v.evaluate(w).success
    # guard: a bottle knocked off the table
    assert all(v.guard(w).values())
    w.poses["bottle2"][2] = 0.6
    assert v.guard(w)["bottle2_on_table"] is False


def test_pick_diverse_bottles_checkpoints_follow_the_bottles():
    task = TASKS["pick_diverse_bottles"]
    inst = task.build(0, None)
    w = FakeWorld(inst)
    rules = task.spatial_checkpoints(inst.info)
    g = np.asarray(rules[0].reference(w))
    b = inst.info["bottle1"]
    assert g[2] == pytest.approx(w.poses["bottle1"][2] + b["grasp_point"][2])
    w.poses["bottle1"][:3] += [0.05, 0.0, 0.0]
    assert np.asarray(rules[0].reference(w))[0] == pytest.approx(g[0] + 0.05)
    assert rules[2].prerequisites == (0,) and rules[3].prerequisites == (1,)
    hold = np.asarray(rules[2].reference(w))
    assert rules[2].test((hold + [0.09, -0.09, -0.09] - hold) * 100)
    assert not rules[2].test(np.array([0.0, 0.0, -11.0]))


# --- put_bottles_dustbin ------------------------------------------------------------------------------
def test_put_bottles_dustbin_layouts():
    task = TASKS["put_bottles_dustbin"]
    for seed in SEEDS:
        inst = task.build(seed, None)
        table, dustbin = inst.scene.body("table"), inst.scene.body("dustbin")
        assert table.pose[0] == pytest.approx(0.3)
        assert dustbin.kind == "static" and np.allclose(dustbin.pose, (-0.45, 0, 0, 1, 0, 0, 0))
        ps = []
        for key, model_id in zip(("bottle1", "bottle2", "bottle3"), (1, 2, 3)):
            b, info = inst.scene.body(key), inst.info[key]
            x, y, z = b.pose[:3]
            assert -0.25 <= x <= 0.3 and abs(x) >= 0.05 and 0.03 <= y <= 0.23
            assert z - info["height"] / 2 == pytest.approx(0.741)
            assert np.allclose(b.pose[3:], (1, 0, 0, 0))  # upright, no rotation
            assert info["model"] == "114_bottle" and info["model_id"] == model_id
            ps.append(np.array([x, y]))
        for i in range(3):
            for j in range(i + 1, 3):
                assert np.linalg.norm(ps[i] - ps[j]) >= 0.13
        # the dustbin stands left of the table, its rim below the table top and clear of its legs
        d = inst.info["dustbin"]
        assert d["rim_z"] < 0.69 and d["pose"][0] + d["outer_half_size"][0] < 0.3 - 0.6 + 0.06 - 0.025
        assert 0.13 < d["floor_z"] < 0.25 - 0.008  # balls on its floor are inside dump_bin_bigbin's band


def _in_bin(w, key, xyz):
    w.poses[key] = np.array([*xyz, 1.0, 0.0, 0.0, 0.0])


def test_put_bottles_dustbin_verifier():
    task, inst, v = task_and_verifier("put_bottles_dustbin")
    assert v.scoring == "final" and set(v.guarded_objects) == {"bottle1", "bottle2", "bottle3"}
    w = FakeWorld(inst)
    for i, key in enumerate(("bottle1", "bottle2", "bottle3")):
        _in_bin(w, key, (-0.45, -0.12 + 0.12 * i, 0.23))
    ev = v.evaluate(w)
    assert ev.success and all(ev.predicates.values())
    assert task.subgoals(w) == [True, True, True, True]
    for xyz, ok in (((-0.45 + 0.22, 0.0, 0.3), True), ((-0.45 - 0.222, 0.0, 0.3), False), ((-0.45, 0.324, 0.3), True),
                    ((-0.45, -0.326, 0.3), False), ((-0.45, 0.0, 0.19), False), ((-0.45, 0.0, 0.71), False),
                    ((0.1, 0.1, 0.82), False)):
        _in_bin(w, "bottle2", xyz)
        assert v.evaluate(w).predicates["bottle2_in_bin"] is ok, xyz
    assert task.subgoals(w) == [True, False, True, False]
    # guard: above z 0.1 and inside x [-0.85, 0.55], y [-0.55, 0.55]
    assert all(v.guard(w).values())
    _in_bin(w, "bottle3", (0.56, 0.0, 0.82))
    assert v.guard(w)["bottle3_on_table"] is False
    _in_bin(w, "bottle3", (-0.7, 0.0, 0.05))
    assert v.guard(w)["bottle3_on_table"] is False
    _in_bin(w, "bottle3", (-0.45, 0.0, 0.23))
    assert all(v.guard(w).values())


# --- dump_bin_bigbin ----------------------------------------------------------------------------------
def test_dump_bin_bigbin_layouts():
    task = TASKS["dump_bin_bigbin"]
    models = set()
    for seed in SEEDS:
        inst = task.build(seed, None)
        assert inst.scene.body("table").pose[0] == pytest.approx(0.3)
        assert np.allclose(inst.scene.body("dustbin").pose, (-0.45, 0, 0, 1, 0, 0, 0))
        sb, info = inst.scene.body("small_bin"), inst.info["small_bin"]
        x, y, z = sb.pose[:3]
        assert -0.2 <= x <= 0.2 and abs(x) >= 0.05 and -0.2 <= y <= -0.05
        assert z - info["height"] / 2 == pytest.approx(0.741)
        assert abs(yaw_of(sb.pose[3:])) <= np.pi / 8.5 + 1e-9
        assert np.allclose(quat_to_mat(sb.pose[3:])[:, 2], (0, 0, 1))
        assert info["model_id"] in (0, 3, 7, 8, 9, 10) and sb.kind == "dynamic"
        assert 0.05 <= 2 * info["radius_top"] <= 0.08 and 0.05 <= info["grasp_width"] <= 0.075
        models.add(info["model_id"])
        names = inst.info["balls"]["names"]
        assert len(names) == 5
        ps = []
        for n in names:
            ball = inst.scene.body(n)
            assert ball.shapes[0].geometry == assets_bins.Sphere(0.008) and ball.mass <= 0.002
            bx, by, bz = ball.pose[:3]
            # on the bin's floor, inside it
            assert np.hypot(bx - x, by - y) + 0.008 < info["inner_radius_floor"]
            assert bz - 0.008 == pytest.approx(z - info["height"] / 2 + assets_bins.BIN_FLOOR, abs=1e-3)
            ps.append(np.array([bx, by]))
        assert min(np.linalg.norm(p - q) for i, p in enumerate(ps) for q in ps[i + 1:]) >= 0.016  # no overlap
        assert inst.info["latch_subgoals"] == [2]
    assert len(models) >= 4


def _poured(inst, w, bin_xyz=(-0.1, -0.1, 1.05), ball_z=0.208):
    w.poses["small_bin"] = np.array([*bin_xyz, 1.0, 0.0, 0.0, 0.0])
    for i, n in enumerate(inst.info["balls"]["names"]):
        w.poses[n] = np.array([-0.45 + 0.02 * i, 0.0, ball_z, 1.0, 0.0, 0.0, 0.0])


def test_dump_bin_bigbin_verifier_and_latch():
    task, inst, v = task_and_verifier("dump_bin_bigbin", 3)
    assert v.scoring == "latch" and v.poll_every == 1
    assert set(v.guarded_objects) == {"small_bin", *inst.info["balls"]["names"]} and v.guard_min_z == 0.05
    w = FakeWorld(inst)
    tracker = VerdictTracker(v, w)
    assert tracker.armed  # false at the start: the event can latch
    _poured(inst, w, bin_xyz=(-0.42, 0.0, 1.0))
    ev = v.evaluate(w)
    assert ev.success and ev.predicates == {"small_bin_raised": True, "balls_in_band": True}
    assert task.subgoals(w) == [True, True, True]
    tracker.poll(1)
    assert tracker.latched
    # band edges and the 1.0 m mark
    _poured(inst, w, bin_xyz=(-0.42, 0.0, 0.999))
    assert v.evaluate(w).predicates["small_bin_raised"] is False
    for z, ok in ((0.13, True), (0.25, True), (0.129, False), (0.251, False)):
        _poured(inst, w, ball_z=z)
        assert v.evaluate(w).predicates["balls_in_band"] is ok
    _poured(inst, w)
    w.poses["ball3"][2] = 0.79  # one ball still in the small bin
    assert task.subgoals(w) == [True, False, False]
    # final requirements: held above the table top
    _poured(inst, w, bin_xyz=(-0.12, -0.08, 0.95))
    req = v.final_requirements(w)
    assert req == {"small_bin_over_table": True, "small_bin_above_tabletop": True, "small_bin_held": False}
    w.finger_touch.add(("left", "small_bin"))
    assert all(v.final_requirements(w).values())
    h = inst.info["small_bin"]["height"]
    _poured(inst, w, bin_xyz=(-0.12, -0.08, 0.74 + h / 2 + 0.001))  # resting on the table
    assert v.final_requirements(w)["small_bin_above_tabletop"] is False
    _poured(inst, w, bin_xyz=(-0.12, -0.08, 0.74 + h / 2 + 0.035))
    assert v.final_requirements(w)["small_bin_above_tabletop"] is True
    w.poses["small_bin"][3:] = axis_angle_quat([1, 0, 0], np.pi / 4)  # tilted: the rim's edge is lower
    assert v.final_requirements(w)["small_bin_above_tabletop"] is False
    _poured(inst, w, bin_xyz=(-0.42, 0.0, 1.05))  # still over the dustbin
    assert v.final_requirements(w)["small_bin_over_table"] is False
    # guard: a ball on the floor
    _poured(inst, w)
    assert all(v.guard(w).values())
    w.poses["ball5"][2] = 0.008
    assert v.guard(w)["ball5_on_table"] is False


def test_dump_bin_bigbin_latch_is_not_true_at_the_start():
    task = TASKS["dump_bin_bigbin"]
    for seed in SEEDS:
        inst = task.build(seed, None)
        assert task.verifier(inst).evaluate(FakeWorld(inst)).predicates == {"small_bin_raised": False,
                                                                             "balls_in_band": False}


# --- with the SAPIEN backend --------------------------------------------------------------------------
@pytest.mark.sim
@pytest.mark.parametrize("name", NAMES)
def test_sim_initial_scene_settles_and_fails(name):
    with sh.sapien_world(TASKS[name]) as (sim, emb, inst):
        sh.check_settled_scene_fails(TASKS[name], sim, emb, inst, 100, tol=2e-3)


@pytest.mark.sim
def test_sim_bottles_resting_in_the_dustbin_pass():
    """Bottles dropped into the dustbin come to rest inside the verifier's region."""
    task = TASKS["put_bottles_dustbin"]
    with sh.sapien_world(task, seed=0) as (sim, emb, inst):
        sim.step(10)
        for i, key in enumerate(("bottle1", "bottle2", "bottle3")):
            q = (1.0, 0.0, 0.0, 0.0) if i == 0 else tuple(axis_angle_quat([1, 0, 0], np.pi / 2))  # standing / lying
            sim.set_object_pose(key, (-0.45 + 0.08 * (i - 1), -0.13 + 0.13 * i, 0.45, *q))
        sim.step(500)
        w = sh.world_view(sim, emb, inst)
        v = task.verifier(inst)
        ev = v.evaluate(w)
        assert ev.success, ev
        assert all(v.guard(w).values())


@pytest.mark.sim
def test_sim_balls_resting_in_the_dustbin_are_in_the_band():
    task = TASKS["dump_bin_bigbin"]
    with sh.sapien_world(task, seed=3) as (sim, emb, inst):
        sim.step(10)
        for i, n in enumerate(inst.info["balls"]["names"]):
            sim.set_object_pose(n, (-0.5 + 0.025 * i, 0.02 * i, 0.5, 1.0, 0.0, 0.0, 0.0))
        sim.step(300)
        sim.set_object_pose("small_bin", (-0.1, -0.1, 1.02, 1.0, 0.0, 0.0, 0.0))  # held up (about to fall)
        sim.step(1)
        w = sh.world_view(sim, emb, inst)
        ev = task.verifier(inst).evaluate(w)
        assert ev.success, ev
        assert task.subgoals(w) == [True, True, True]
