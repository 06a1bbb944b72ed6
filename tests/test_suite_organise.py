"""The "organise" tasks of the CodeActionBench suite (blocks_ranking_size, stack_bowls_three,
hanging_mug): seeded layouts within the FACTS B.6 ranges, verifiers that accept hand-built success
states and reject near misses, and what the spatial checkpoints accept.

Verifiers are exercised through :class:`FakeWorld` (poses and gripper commands from plain data);
the ``sim`` tests build the catalog instance with the project's SAPIEN backend.

The contract every task keeps (catalog entry, deterministic JSON builds, distinct seeded layouts, a
verifier that rejects every initial layout, catalog checkpoints) is checked in test_suite_tasks.py.
"""
from __future__ import annotations

import numpy as np
import pytest
import suite_helpers as sh
from suite_helpers import SEEDS, TASKS, FakeWorld, _cache, task_and_verifier, tcp_in_rule  # noqa: F401 (_cache: autouse)

from cab_core.geometry import quat_to_mat, transform_point
from cab_core.kits.scene import yaw_of

NAMES = ("blocks_ranking_size", "stack_bowls_three", "hanging_mug")


def _task(name):
    return sh.task_module(name), TASKS[name]



def _yaw(q):
    return yaw_of(q)


# --- blocks_ranking_size ---------------------------------------------------------------------------
def test_blocks_ranking_size_layouts(task_builds):
    mod, task = _task("blocks_ranking_size")
    colours = set()
    for inst in task_builds[task.name]:
        blocks = inst.info["blocks"]
        assert [b["name"] for b in blocks] == ["block1", "block2", "block3"]
        ps = []
        for b, (lo, hi) in zip(blocks, mod.HALF_RANGES):
            body = inst.scene.body(b["name"])
            h = body.shapes[0].geometry.half_size
            assert h[0] == h[1] == h[2] == b["half_size"] and lo <= h[0] <= hi
            assert body.kind == "dynamic"
            p = np.asarray(body.pose)
            assert -0.28 <= p[0] <= 0.28 and abs(p[0]) >= 0.05
            assert -0.08 <= p[1] <= 0.05 and not (abs(p[0]) < 0.15 and p[1] > 0)
            assert p[2] == pytest.approx(0.741 + h[0])
            assert abs(_yaw(p[3:])) <= 0.75 + 1e-9
            assert np.hypot(p[0], p[1] + 0.1) >= 0.10
            ps.append(p)
            colours.add(tuple(b["colour_srgb"]))
        for i in range(3):
            for j in range(i + 1, 3):
                assert np.hypot(*(ps[i][:2] - ps[j][:2])) >= 0.10
        assert not all(mod.ranked(*ps, tol=mod.PRESOLVED_TOLERANCE).values())
    assert len(colours) == 3 * len(SEEDS)  # random colours


def _row(inst, w, xs=(-0.07, 0.0, 0.06), dys=(0.0, 0.0, 0.0), y=-0.1):
    for b, x, dy in zip(inst.info["blocks"], xs, dys):
        w.poses[b["name"]] = np.array([x, y + dy, 0.74 + b["half_size"], 1, 0, 0, 0])


def test_blocks_ranking_size_verifier():
    task, inst, v = task_and_verifier("blocks_ranking_size")
    assert set(v.guarded_objects) == {"block1", "block2", "block3"}
    w = FakeWorld(inst)
    _row(inst, w)
    ev = v.evaluate(w)
    assert ev.success and task.subgoals(w) == [True, True, True]
    # compactness: neighbours closer than 0.13 in x and 0.03 in y
    _row(inst, w, xs=(-0.129, 0.0, 0.129), dys=(0.029, 0.0, -0.029))
    assert v.evaluate(w).success
    _row(inst, w, xs=(-0.131, 0.0, 0.06))
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["large_middle_aligned"] is False
    assert task.subgoals(w) == [False, True, False]
    _row(inst, w, dys=(0.0, 0.0, 0.031))
    assert v.evaluate(w).predicates["middle_small_aligned"] is False
    # the wrong order: small on the left
    _row(inst, w, xs=(0.06, 0.0, -0.06))
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["size_order"] is False
    assert task.subgoals(w) == [True, True, False]
    # both grippers must be open (> 0.8 commanded)
    _row(inst, w)
    w.grip["right"] = 0.8
    assert v.evaluate(w).predicates["grippers_open"] is False
    assert task.subgoals(w) == [True, True, True]  # the subgoals are geometric
    # not scored: where on the table the row lies
    w.grip["right"] = 1.0
    _row(inst, w, y=0.1)
    assert v.evaluate(w).success
    assert v.guard(w) == {f"block{i}_on_table": True for i in (1, 2, 3)}
    w.poses["block2"][2] = 0.6
    assert v.guard(w)["block2_on_table"] is False


def test_blocks_ranking_size_spatial_rules():
    task, inst, _ = task_and_verifier("blocks_ranking_size")
    rules = task.spatial_checkpoints(inst.info)
    w = FakeWorld(inst)
    b1 = inst.info["blocks"][0]
    grasp = np.asarray(b1["pose"][:3]) + b1["grasp_tcp_offset"]
    w.tcp["left"][:3] = grasp + [0.015, 0.0, 0.035]
    assert tcp_in_rule(rules[0], w, "left") and not tcp_in_rule(rules[1], w, "left")
    # the middle block set down 7 cm right of the large one
    assert rules[3].prerequisites == (1,) and rules[4].prerequisites == (2,)
    w.tcp["right"][:3] = grasp + [0.07, 0.01, -0.006]
    assert tcp_in_rule(rules[3], w, "right")
    w.tcp["right"][:3] = grasp + [-0.01, 0.01, -0.006]  # on the wrong side
    assert not tcp_in_rule(rules[3], w, "right")


# --- stack_bowls_three -----------------------------------------------------------------------------
def test_stack_bowls_three_layouts_and_bowl(task_builds):
    mod, task = _task("stack_bowls_three")
    for inst in task_builds[task.name]:
        names = [b["name"] for b in inst.info["bowls"]]
        assert names == ["bowl1", "bowl2", "bowl3"]
        ps = [np.asarray(inst.scene.body(n).pose) for n in names]
        assert [p[1] for p in ps] == sorted(p[1] for p in ps)  # numbered by y
        for p in ps:
            assert -0.3 <= p[0] <= 0.3 and abs(p[0]) >= 0.09
            assert -0.15 <= p[1] <= 0.15 and not (abs(p[0]) < 0.15 and p[1] > 0)
            assert p[2] == pytest.approx(0.74, abs=1e-3) and np.allclose(p[3:], (1, 0, 0, 0))
            assert np.hypot(p[0], p[1] + 0.1) >= 0.13
        for i in range(3):
            for j in range(i + 1, 3):
                assert np.hypot(*(ps[i][:2] - ps[j][:2])) >= 0.13
    b = inst.info["bowl"]
    # a bowl fits between its neighbours, and the gripper (pads up to 9.2 cm apart) pinches its wall
    assert 2 * b["rim_outer_radius"] < 0.13 and b["wall_thickness"] < 0.02
    assert 0.05 <= b["mass_kg"] <= 0.4
    # nested bowls sit low enough for the verifier's one-sided height limits
    rise = b["nest_rise"]
    assert 0.005 < rise and 0.74 + rise < 0.79 and 0.74 + 2 * rise < 0.83
    assert rise == pytest.approx(mod.BOWL.nest_rise, abs=1e-6)
    # the inside is open: the collision wall is thin wedges, the floor a disc
    body = inst.scene.body("bowl1")
    assert body.kind == "dynamic" and sum(s.collision for s in body.shapes) == 1 + 2 * mod.BOWL.segments
    assert any(s.visual and not s.collision for s in body.shapes)


def _nest(w, xy=(0.0, -0.1), rise=0.021, d2=(0, 0), d3=(0, 0), order=("bowl1", "bowl2", "bowl3")):
    for k, (n, d) in enumerate(zip(order, ((0, 0), d2, d3))):
        w.poses[n] = np.array([xy[0] + d[0], xy[1] + d[1], 0.74 + k * rise, 1, 0, 0, 0])


def test_stack_bowls_three_verifier():
    task, inst, v = task_and_verifier("stack_bowls_three")
    assert set(v.guarded_objects) == {"bowl1", "bowl2", "bowl3"}
    w = FakeWorld(inst)
    _nest(w)
    ev = v.evaluate(w)
    assert ev.success and task.subgoals(w) == [True, True]
    # any order of the three, anywhere on the table
    _nest(w, xy=(0.2, 0.1), order=("bowl3", "bowl1", "bowl2"))
    assert v.evaluate(w).success
    # xy tolerance 0.04 per axis between consecutive (by height) bowls
    _nest(w, d2=(0.039, -0.039), d3=(0.0, -0.039 + 0.039))
    assert v.evaluate(w).success
    _nest(w, d3=(0.041, 0.0))
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["pair_aligned_12"] is False and ev.predicates["pair_aligned_01"]
    assert task.subgoals(w) == [True, False]
    # one-sided heights: z - [0.74, 0.77, 0.81] < 0.02
    _nest(w, rise=0.0249)
    assert v.evaluate(w).predicates["heights_ok"] is True
    _nest(w, rise=0.0501)  # bowl2 at 0.7901
    ev = v.evaluate(w)
    assert ev.predicates["heights_ok"] is False and not ev.success
    # two bowls side by side, the third in one of them: one pair aligned, not a stack
    _nest(w)
    w.poses["bowl1"][:2] = (0.15, -0.1)
    w.poses["bowl2"][2] = 0.74
    w.poses["bowl3"][2] = 0.761
    ev = v.evaluate(w)
    assert not ev.success and task.subgoals(w) == [True, False]
    _nest(w)
    w.grip["left"] = 0.5
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["grippers_open"] is False
    w.poses["bowl2"][2] = 0.6
    assert v.guard(w)["bowl2_on_table"] is False


def test_stack_bowls_three_spatial_rules():
    task, inst, _ = task_and_verifier("stack_bowls_three")
    rules = task.spatial_checkpoints(inst.info)
    b = inst.info["bowl"]
    w = FakeWorld(inst)
    c = np.asarray(inst.info["bowls"][2]["pose"][:3])
    for phi in (0.0, 2.0, -2.5):  # anywhere on the ring around the bowl's axis
        w.tcp["left"][:3] = c + [b["grasp_radius"] * np.cos(phi), b["grasp_radius"] * np.sin(phi), b["grasp_tcp_dz"]]
        assert tcp_in_rule(rules[2], w, "left")
        assert not tcp_in_rule(rules[0], w, "left")
    w.tcp["left"][:3] = c + [0.0, 0.0, b["grasp_tcp_dz"]]  # over the centre: not on the ring
    assert not tcp_in_rule(rules[2], w, "left")
    assert rules[3].prerequisites == (1,) and rules[4].prerequisites == (2,)
    # placing bowl2 into bowl1: the pinch ring one nesting step above bowl1's
    s = np.asarray(inst.info["bowls"][0]["pose"][:3])
    w.tcp["right"][:3] = s + [0.0, -b["grasp_radius"], b["grasp_tcp_dz"] + b["nest_rise"]]
    assert tcp_in_rule(rules[3], w, "right")


# --- hanging_mug -----------------------------------------------------------------------------------
def test_hanging_mug_layouts_and_assets(task_builds):
    mod, task = _task("hanging_mug")
    for inst in task_builds[task.name]:
        mug, rack = inst.scene.body("mug"), inst.scene.body("rack")
        assert mug.kind == "dynamic" and 0.1 <= mug.mass <= 0.4 and rack.kind == "static"
        x, y, z = mug.pose[:3]
        assert -0.25 <= x <= -0.1 and -0.05 <= y <= 0.05 and not (abs(x) < 0.15 and y > 0)
        assert z == pytest.approx(0.74, abs=1e-3)
        assert np.allclose(quat_to_mat(mug.pose[3:])[:, 2], (0, 0, 1))  # upright
        # the handle (local +x) points into the half turn x -> +y -> -x (+y turned by +-1.57)
        handle = quat_to_mat(mug.pose[3:])[:, 0]
        assert handle[1] >= -1e-3 and abs(_yaw(mug.pose[3:]) - np.pi / 2) <= 1.57 + 1e-9
        rx, ry, rz = rack.pose[:3]
        assert 0.1 <= rx <= 0.3 and 0.13 <= ry <= 0.17 and rz == pytest.approx(0.74)
        assert abs(_yaw(rack.pose[3:])) <= 0.2 + 1e-9
        info = inst.info
        assert np.allclose(info["rack"]["midpoint_world"], mod.rack_midpoint(rack.pose), atol=1e-6)
    m, r = info["mug"], info["rack"]
    # a peg passes through the handle's opening with room; the hang point lies inside the opening
    w, h = m["handle_opening_size_xz"]
    assert w >= 2 * r["peg_radius"] + 0.01 and h >= 2 * r["knob_radius"] + 0.015
    top = m["handle_opening_top"]
    assert abs(m["hang_point"][0] - top[0]) < w / 2 and top[2] - h < m["hang_point"][2] < top[2]
    # the rim pinch: the wall fits between the pads opened to the pinch command (0.11 p - 0.018 m)
    assert m["wall_thickness"] + 0.01 < 0.11 * m["pinch_gripper_command"] - 0.018
    # a hung mug's point is above 0.86 m when it hangs from the middle of the peg
    mid_peg_z = 0.74 + r["peg_root"][2] + r["peg_length"] / 2 * r["peg_direction"][2]
    assert mid_peg_z > 0.86 + 0.01
    # the peg's tip is the rack's functional point, the post's foot its origin
    assert np.allclose(r["peg_tip"], np.add(r["peg_root"], np.multiply(r["peg_length"], r["peg_direction"])))


def _hung_pose(inst, shift=(0.0, 0.0), z=0.89):
    """The mug with its handle at right angles to the peg (toward the rack's +y), its hang point
    over the rack's midpoint (shifted by ``shift``) at height ``z``."""
    info = inst.info
    yaw = _yaw(info["rack"]["pose"][3:]) + np.pi / 2
    q = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    mid = np.asarray(info["rack"]["midpoint_world"])
    target = np.array([mid[0] + shift[0], mid[1] + shift[1], z])
    return np.concatenate([target - quat_to_mat(q) @ np.asarray(info["mug"]["hang_point"]), q])


def test_hanging_mug_verifier():
    task, inst, v = task_and_verifier("hanging_mug")
    assert v.guarded_objects == ("mug",)
    w = FakeWorld(inst)
    w.poses["mug"] = _hung_pose(inst)
    ev = v.evaluate(w)
    assert ev.success and task.subgoals(w) == [True]
    assert transform_point(w.poses["mug"], inst.info["mug"]["hang_point"])[2] == pytest.approx(0.89)
    w.grip["left"] = 0.0  # only the right gripper must be open
    assert v.evaluate(w).success
    w.poses["mug"] = _hung_pose(inst, shift=(0.019, -0.019))
    assert v.evaluate(w).success
    w.poses["mug"] = _hung_pose(inst, shift=(0.021, 0.0))
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["mug_at_peg"] is False and task.subgoals(w) == [False]
    w.poses["mug"] = _hung_pose(inst, z=0.859)
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates == {"mug_at_peg": True, "mug_high": False, "right_gripper_open": True}
    w.poses["mug"] = _hung_pose(inst)
    w.grip["right"] = 0.8
    ev = v.evaluate(w)
    assert not ev.success and ev.predicates["right_gripper_open"] is False and task.subgoals(w) == [True]
    # the midpoint follows the rack
    w.grip["right"] = 1.0
    w.poses["rack"][0] += 0.05
    assert not v.evaluate(w).success
    w.poses["mug"][2] = 0.6
    assert v.guard(w) == {"mug_on_table": False}


def test_hanging_mug_spatial_rules():
    task, inst, _ = task_and_verifier("hanging_mug")
    rules = task.spatial_checkpoints(inst.info)
    assert rules[1].prerequisites == (0,)
    w = FakeWorld(inst)
    m = inst.info["mug"]
    c = np.asarray(m["pose"][:3])
    w.tcp["left"][:3] = c + [m["rim_mid_radius"], 0.0, m["grasp_tcp_dz"] + 0.03]
    assert tcp_in_rule(rules[0], w, "left")
    w.tcp["left"][:3] = c + [0.06, 0.0, m["grasp_tcp_dz"]]
    assert not tcp_in_rule(rules[0], w, "left")
    # the hanging reference: over the rim opposite the handle, the handle on the peg's middle
    ref = np.asarray(rules[1].reference(w))
    rack = inst.info["rack"]
    assert ref[2] > rack["midpoint_world"][2] + 0.1
    assert 0.06 < np.linalg.norm(ref[:2] - np.asarray(rack["midpoint_world"][:2])) < 0.12


# --- with the SAPIEN backend ----------------------------------------------------------------------
def _pose_success_state(name, inst, sim):
    if name == "blocks_ranking_size":
        x = -0.07
        for b, dx in zip(inst.info["blocks"], (0.0, 0.065, 0.055)):
            x += dx
            sim.set_object_pose(b["name"], [x, -0.1, 0.74 + b["half_size"] + 0.0005, 1, 0, 0, 0])
    elif name == "stack_bowls_three":
        rise = inst.info["bowl"]["nest_rise"]
        for k, b in enumerate(inst.info["bowls"]):
            sim.set_object_pose(b["name"], [0.0, -0.1, 0.74 + k * rise + 0.001, 1, 0, 0, 0])
    elif name == "hanging_mug":
        # let go upright with the top of the handle's opening on the middle of the peg: the mug
        # tips about the peg and hangs there
        info = inst.info
        m, r = info["mug"], info["rack"]
        rack = np.asarray(r["pose"])
        yaw = _yaw(rack[3:]) + np.pi / 2
        q = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        on_peg = transform_point(rack, np.add(r["peg_root"], np.multiply(r["hang_along"], r["peg_direction"])))
        on_peg[2] += r["peg_radius"] + 0.001
        sim.set_object_pose("mug", np.concatenate([on_peg - quat_to_mat(q) @ np.asarray(m["handle_opening_top"]), q]))


@pytest.mark.sim
@pytest.mark.parametrize("name", NAMES)
def test_sim_initial_scene_fails_and_success_state_passes(name):
    task = TASKS[name]
    with sh.sapien_world(task) as (sim, emb, inst):
        w, v, _ = sh.check_settled_scene_fails(task, sim, emb, inst, 100)
        _pose_success_state(name, inst, sim)
        sh.check_success_holds(task, sim, w, v, 500)
