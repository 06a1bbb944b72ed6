"""The pin planner (Pinocchio + OMPL + TOPP-RA) on the aloha_agilex embodiment: FK, collision world,
IK, joint and straight-line plans, timing on the dt grid, refusals; and agreement with mplib where
both are installed."""
from __future__ import annotations

import sys

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("ompl")

from cab_core.errors import ConfigError, MissingDependency, PlannerError  # noqa: E402
from cab_core.geometry import axis_angle_quat, quat_angle, quat_mul  # noqa: E402
from cab_embodiment_aloha import kinematics  # noqa: E402
from cab_embodiment_aloha.params import DEFAULT_PARAMS  # noqa: E402
from cab_embodiment_aloha.reach import tcp_quat  # noqa: E402
from cab_planner_pin import plugin  # noqa: E402
from cab_planner_pin.planner import PinConfig, PinPlanner  # noqa: E402

DT = 1.0 / 250.0
TOP_DOWN = tcp_quat((0, 0, -1), (1, 0, 0))
TOP_DOWN_ROLLED = tcp_quat((0, 0, -1), (0, 1, 0))
FORWARD = tcp_quat((0, 1, 0), (1, 0, 0))


@pytest.fixture(scope="module")
def spec(aloha_spec):
    return aloha_spec


@pytest.fixture(scope="module")
def planner(spec):
    p = plugin.cab_planners()["pin"]({})
    p.setup(spec, DT)
    return p


def home(spec, arm):
    return np.array(spec.arms[arm].home_qpos, dtype=float)


def pose(xyz, quat):
    return np.concatenate([np.asarray(xyz, float), quat])


def assert_pose_close(got, want, pos_m=0.002, rot_rad=0.01):
    assert np.linalg.norm(got[:3] - want[:3]) < pos_m, (got, want)
    assert quat_angle(got[3:], want[3:]) < rot_rad, (got, want)


def assert_timed(planner, positions, arm="left"):
    """Rows one dt apart: no joint faster than its velocity limit; at rest at both ends."""
    steps = np.abs(np.diff(positions, axis=0))
    vmax = planner._arms[arm].vel
    assert np.all(steps <= vmax * DT * 1.02 + 1e-9), steps.max(axis=0) / DT
    assert np.all(steps[0] <= vmax * DT * 0.2) and np.all(steps[-1] <= vmax * DT * 0.2)


# --- plugin, config, versions, FK ------------------------------------------------------------


def test_plugin_hook_and_factory():
    reg = plugin.cab_planners()
    assert set(reg) == {"pin"}
    assert isinstance(reg["pin"]({}), PinPlanner)


def test_missing_library_raises_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "ompl", None)
    with pytest.raises(MissingDependency, match="pip install pin ompl toppra"):
        plugin.cab_planners()["pin"]({})


def test_config_validation():
    assert PinConfig.from_dict({"planning_time": 0.5, "unrelated_key": 1}).planning_time == 0.5
    with pytest.raises(ConfigError, match="fingers"):
        PinConfig.from_dict({"fingers": "half"})
    with pytest.raises(ConfigError, match="positive"):
        PinConfig.from_dict({"ik_seeds": 0})


def test_setup_rejects_a_bad_dt(spec):
    with pytest.raises(ConfigError, match="dt"):
        PinPlanner({}).setup(spec, 0.0)


def test_use_before_setup_and_unknown_arm_are_errors(planner):
    with pytest.raises(PlannerError, match="before setup"):
        PinPlanner({}).fk("left", np.zeros(6))
    with pytest.raises(PlannerError, match="unknown arm"):
        planner.fk("middle", np.zeros(6))
    with pytest.raises(PlannerError, match="expected 6"):
        planner.fk("left", np.zeros(5))


def test_versions(planner):
    v = planner.versions()
    assert v["pin"] != "missing" and v["ompl"].startswith("2.") and v["toppra"] != "missing"


@pytest.mark.parametrize("arm", ["left", "right"])
def test_fk_matches_the_generated_kinematics(planner, spec, arm):
    rng = np.random.default_rng(7)
    for q in [home(spec, arm)] + [rng.uniform(-1.2, 1.2, 6) for _ in range(5)]:
        want = kinematics.tcp_pose_world(DEFAULT_PARAMS, arm, q)
        got = planner.fk(arm, q)
        assert np.allclose(got[:3], want[:3], atol=1e-6)
        assert quat_angle(got[3:], want[3:]) < 1e-6


# --- the collision world ----------------------------------------------------------------------


@pytest.mark.parametrize("arm", ["left", "right"])
def test_home_is_a_valid_collision_free_start(planner, spec, arm):
    ap = planner._arms[arm]
    assert not ap.collides(home(spec, arm))
    assert planner._start_problem(ap, home(spec, arm)) is None


def test_other_arm_is_not_in_the_collision_world(planner, spec):
    ap = planner._arms["left"]
    assert not any("fr_" in a or "fr_" in b for a, b in
                   ((ap.link_of[p.first], ap.link_of[p.second]) for p in ap.geom.collisionPairs))
    q = ap.full(home(spec, "left"))
    q[ap.model.joints[ap.model.getJointId("fr_joint2")].idx_q] = 2.4  # right upper arm in its pedestal
    assert not ap.pin.computeCollisions(ap.model, ap.data, ap.geom, ap.gdata, q, True)
    bad = home(spec, "left")
    bad[1] = 2.4  # the same for the left arm is a collision
    assert ap.collides(bad)
    assert any("fl_" in a or "fl_" in b for a, b in ap.colliding_pairs(bad))


def test_srdf_disabled_pairs_are_not_checked(planner):
    ap = planner._arms["left"]
    pairs = {tuple(sorted((ap.link_of[p.first], ap.link_of[p.second]))) for p in ap.geom.collisionPairs}
    assert ("fl_link1", "fl_link2") not in pairs and ("fl_link2", "fl_link3") not in pairs
    assert pairs, "no collision pair left"


# --- IK ------------------------------------------------------------------------------------

IK_CASES = [
    ("left", (-0.20, 0.00, 0.85), TOP_DOWN),
    ("left", (-0.30, 0.15, 0.80), TOP_DOWN_ROLLED),
    ("left", (-0.10, 0.10, 0.90), FORWARD),
    ("right", (0.20, -0.10, 0.80), TOP_DOWN),
    ("right", (0.30, 0.20, 0.85), FORWARD),
]


@pytest.mark.parametrize("arm,xyz,quat", IK_CASES)
def test_ik_round_trip(planner, spec, arm, xyz, quat):
    target = pose(xyz, quat)
    r = planner.ik(arm, target, home(spec, arm))
    assert r.ok, r.message
    assert r.qpos.shape == (6,)
    assert_pose_close(planner.fk(arm, r.qpos), target, pos_m=1e-5, rot_rad=1e-5)
    assert r.position_error_m < 1e-5 and r.rotation_error_rad < 1e-5
    ap = planner._arms[arm]
    assert np.all(r.qpos >= ap.limits[:, 0]) and np.all(r.qpos <= ap.limits[:, 1])
    assert not ap.collides(r.qpos)


@pytest.mark.parametrize("arm,xyz,quat", IK_CASES)
def test_ik_agrees_with_mplib(planner, spec, arm, xyz, quat):
    """The same arm configuration as the mplib planner (same CLIK from the same seed, nearest first)."""
    pytest.importorskip("mplib")
    from cab_planner_mplib.planner import MplibPlanner

    m = MplibPlanner({})
    m.setup(spec, DT)
    target = pose(xyz, quat)
    a, b = planner.ik(arm, target, home(spec, arm)), m.ik(arm, target, home(spec, arm))
    assert a.ok and b.ok
    # equal up to a turn of 2 pi (a solution on the +-pi limit of the wrist roll is the same either way)
    diff = np.angle(np.exp(1j * (a.qpos - b.qpos)))
    assert np.all(np.abs(diff) < 2e-3), (a.qpos, b.qpos)


def test_ik_prefers_the_solution_near_the_seed(planner, spec):
    """A 2 cm leg from home: the solution continued from the seed, a small joint change."""
    q = home(spec, "left")
    target = planner.fk("left", q)
    target[0] += 0.02
    r = planner.ik("left", target, q)
    assert r.ok and np.linalg.norm(r.qpos - q) < 0.1


def test_ik_refuses_an_unreachable_pose(planner, spec):
    r = planner.ik("left", pose((2.0, 0.0, 0.9), TOP_DOWN), home(spec, "left"))
    assert not r.ok and r.qpos is None and "IK failed" in r.message


def test_ik_refuses_a_malformed_pose(planner, spec):
    r = planner.ik("left", [0.0, 0.0, np.nan, 1, 0, 0, 0], home(spec, "left"))
    assert not r.ok and "invalid target" in r.message


# --- planning ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def top_down_plan(planner, spec):
    target = pose((-0.20, 0.0, 0.85), TOP_DOWN)
    return target, planner.plan_to_pose("left", home(spec, "left"), target)


def test_plan_from_home_to_top_down_pose(planner, spec, top_down_plan):
    target, r = top_down_plan
    assert r.status == "success", r.message
    pos = r.positions
    assert pos.ndim == 2 and pos.shape[1] == 6 and len(pos) > 10
    assert np.array_equal(pos[0], home(spec, "left"))
    assert_pose_close(planner.fk("left", pos[-1]), target, pos_m=1e-5, rot_rad=1e-5)
    lim = planner._arms["left"].limits
    assert np.all(pos >= lim[:, 0] - 1e-6) and np.all(pos <= lim[:, 1] + 1e-6)


def test_trajectory_is_sampled_at_dt(planner, top_down_plan):
    _, r = top_down_plan
    assert r.dt == pytest.approx(DT)
    assert_timed(planner, r.positions)
    assert r.raw["duration_s"] == pytest.approx((len(r.positions) - 1) * DT)
    assert 0.5 < r.raw["duration_s"] < 6.0


def test_acceleration_limits_hold(planner, top_down_plan):
    _, r = top_down_plan
    acc = np.abs(np.diff(r.positions, n=2, axis=0)) / DT ** 2
    # the grid's first and last rows are pinned to the ends; inside, TOPP-RA's limits hold
    assert np.all(acc[1:-1] <= planner._arms["left"].acc * 1.05 + 1e-6), acc.max(axis=0)


def test_every_row_is_collision_free(planner, top_down_plan):
    ap = planner._arms["left"]
    _, r = top_down_plan
    assert not any(ap.collides(q) for q in r.positions[:: max(1, len(r.positions) // 50)])


def test_planning_is_deterministic(planner, spec, top_down_plan):
    target, r = top_down_plan
    again = planner.plan_to_pose("left", home(spec, "left"), target)
    assert np.array_equal(again.positions, r.positions)


def test_rrt_goes_around_a_blocked_line(planner, spec):
    """When the straight joint line collides, OMPL's RRTConnect finds a collision-free path, the same
    one every time (seeded)."""
    ap = planner._arms["left"]
    rng = np.random.default_rng(5)
    lo, hi = ap.limits[:, 0], ap.limits[:, 1]
    for _ in range(500):
        a, b = rng.uniform(lo, hi), rng.uniform(lo, hi)
        if not ap.collides(a) and not ap.collides(b) and planner._line(ap, a, b) is None:
            break
    else:
        pytest.fail("no free pair of configurations with a blocked line between them")
    path = planner._rrt(ap, a, [b])
    assert path is not None
    assert np.allclose(path[0], a) and np.allclose(path[-1], b)
    dense = np.concatenate([np.linspace(p, q, 10) for p, q in zip(path[:-1], path[1:])])
    assert not any(ap.collides(q) for q in dense)
    assert np.array_equal(planner._rrt(ap, a, [b]), path)


@pytest.mark.parametrize("arm,start_xyz,delta", [
    ("left", (-0.20, 0.0, 0.90), (0.0, 0.0, -0.10)),
    ("right", (0.20, 0.0, 0.90), (-0.10, 0.10, 0.0)),
])
def test_straight_line_plan_follows_a_line(planner, spec, arm, start_xyz, delta):
    start_pose = pose(start_xyz, TOP_DOWN)
    q0 = planner.ik(arm, start_pose, home(spec, arm)).qpos
    goal = pose(np.add(start_xyz, delta), TOP_DOWN)
    r = planner.plan_to_pose(arm, q0, goal, straight_line=True)
    assert r.status == "success" and r.message == "screw path", r.message
    assert_pose_close(planner.fk(arm, r.positions[-1]), goal, pos_m=1e-4)
    assert_timed(planner, r.positions, arm)
    a, b = np.asarray(start_xyz, float), goal[:3]
    u = (b - a) / np.linalg.norm(b - a)
    for q in r.positions[:: max(1, len(r.positions) // 40)]:
        p = planner.fk(arm, q)
        off = (p[:3] - a) - ((p[:3] - a) @ u) * u
        assert np.linalg.norm(off) < 0.002
        assert quat_angle(p[3:], TOP_DOWN) < 0.01


def test_screw_path_turns_about_a_fixed_point(planner, spec):
    """A pure rotation about the approach axis: the TCP stays where it is while it turns."""
    q0 = planner.ik("left", pose((-0.2, 0.0, 0.88), TOP_DOWN), home(spec, "left")).qpos
    start = planner.fk("left", q0)
    goal = start.copy()
    goal[3:] = quat_mul(start[3:], axis_angle_quat([1, 0, 0], 0.3))
    r = planner.plan_to_pose("left", q0, goal, straight_line=True)
    assert r.status == "success", r.message
    for q in r.positions[:: max(1, len(r.positions) // 30)]:
        assert np.linalg.norm(planner.fk("left", q)[:3] - start[:3]) < 0.002
    assert_pose_close(planner.fk("left", r.positions[-1]), goal)


def test_typical_move_duration(planner, spec):
    """A 0.3 m TCP move takes about 1-2.5 s of simulated time."""
    q0 = planner.ik("left", pose((-0.2, 0.0, 0.9), TOP_DOWN), home(spec, "left")).qpos
    r = planner.plan_to_pose("left", q0, pose((0.1, 0.0, 0.9), TOP_DOWN))
    assert r.ok, r.message
    assert 1.0 <= (len(r.positions) - 1) * r.dt <= 2.5


def test_dt_grid_follows_setup(spec):
    p = PinPlanner({})
    p.setup(spec, 0.01)
    q = home(spec, "left")
    target = p.fk("left", q)
    target[2] -= 0.05
    r = p.plan_to_pose("left", q, target)
    assert r.ok and r.dt == 0.01
    steps = np.abs(np.diff(r.positions, axis=0))
    assert np.all(steps <= p._arms["left"].vel * 0.01 * 1.02 + 1e-9)


# --- refusals ------------------------------------------------------------------------------


def test_unreachable_pose_is_no_ik(planner, spec):
    r = planner.plan_to_pose("left", home(spec, "left"), pose((2.0, 0.0, 0.9), TOP_DOWN))
    assert r.status == "no_ik"
    assert r.positions is None and not r.ok


def test_out_of_limits_start_is_invalid_start(planner, spec):
    q = home(spec, "left")
    q[1] = 3.0
    r = planner.plan_to_pose("left", q, pose((-0.2, 0.0, 0.85), TOP_DOWN))
    assert r.status == "invalid_start"
    assert "fl_joint2" in r.message


def test_colliding_start_is_invalid_start(planner, spec):
    q = np.array([0.0, 2.4, 0.0, 0.0, 0.0, 0.0])  # upper arm in its own pedestal
    r = planner.plan_to_pose("left", q, pose((-0.2, 0.0, 0.85), TOP_DOWN))
    assert r.status == "invalid_start"
    assert "self-collision" in r.message


def test_wrong_start_length_is_invalid_start(planner):
    r = planner.plan_to_pose("left", np.zeros(5), pose((-0.2, 0.0, 0.85), TOP_DOWN))
    assert r.status == "invalid_start"


def test_malformed_goal_is_invalid_goal(planner, spec):
    r = planner.plan_to_pose("left", home(spec, "left"), [0, 0, 0.9, 0, 0, 0, 0])
    assert r.status == "invalid_goal"


@pytest.mark.parametrize("straight", [False, True])
def test_zero_length_move_succeeds_in_place(planner, spec, straight):
    q = home(spec, "left")
    r = planner.plan_to_pose("left", q, planner.fk("left", q), straight_line=straight)
    assert r.status == "success"
    assert r.positions.shape == (2, 6)
    assert np.array_equal(r.positions[0], q) and np.array_equal(r.positions[-1], q)


@pytest.mark.parametrize("straight", [False, True])
def test_small_move(planner, spec, straight):
    q = home(spec, "left")
    target = planner.fk("left", q)
    target[2] += 0.0005
    r = planner.plan_to_pose("left", q, target, straight_line=straight)
    assert r.status == "success", r.message
    assert_pose_close(planner.fk("left", r.positions[-1]), target, pos_m=1e-4)


def test_straight_line_into_a_joint_limit_is_no_path(planner, spec):
    """IK exists, but the straight screw motion would turn the wrist-roll joint past its limit:
    no_path (with the IK accuracy reported), while a free-space plan still succeeds."""
    q = home(spec, "left")
    q[5] = planner._arms["left"].limits[5, 1] - 0.1
    start = planner.fk("left", q)
    target = start.copy()
    target[3:] = quat_mul(start[3:], axis_angle_quat([1, 0, 0], 0.4))
    assert planner.ik("left", target, q).ok
    r = planner.plan_to_pose("left", q, target, straight_line=True)
    assert r.status == "no_path"
    assert r.positions is None and r.position_error_m is not None
    free = planner.plan_to_pose("left", q, target)
    assert free.status == "success", free.message
    assert_pose_close(planner.fk("left", free.positions[-1]), target)
