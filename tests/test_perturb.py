"""Small perturbations of an instance (cab_core.attempt.variation.perturb): bounded, in the table plane, drawn from
(perturb seed, scene seed), recorded; the config section is checked before anything starts."""
import math

import numpy as np
import pytest
from suite_helpers import _cache  # noqa: F401  (autouse: generated assets in a temp cache)

from cab_core.attempt.variation.perturb import Perturbation, perturb_scene
from cab_core.errors import ConfigError
from cab_core.plugins import all_tasks


def yaw(q):
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@pytest.mark.parametrize("task", ["stack_blocks_three", "open_microwave", "click_bell"])
def test_objects_move_a_little_in_the_table_plane_and_parameters_scale_a_little(task):
    t = all_tasks()[task]
    before, after = t.build(3, None).scene, t.build(3, None).scene
    p = Perturbation(seed=7)
    drawn = perturb_scene(after, p, 3)
    objs = [*zip(before.bodies, after.bodies), *zip(before.articulations, after.articulations)]
    assert set(drawn) == {b.name for b, _ in objs}
    for b, a in objs:
        d = drawn[b.name]
        assert math.hypot(a.pose[0] - b.pose[0], a.pose[1] - b.pose[1]) <= 1e-3 + 1e-12
        assert a.pose[2] == b.pose[2]  # never into the table
        turn = (yaw(a.pose[3:]) - yaw(b.pose[3:]) + math.pi) % (2 * math.pi) - math.pi
        assert abs(math.degrees(turn)) <= 0.5 + 1e-6 and turn == pytest.approx(math.radians(d["yaw_deg"]), abs=1e-9)
        assert (a.pose[0] - b.pose[0], a.pose[1] - b.pose[1]) == pytest.approx((d["dx_m"], d["dy_m"]), abs=1e-12)
        for k, v in d.items():
            if k.endswith("_scale"):
                assert abs(v - 1) <= 0.02
        if hasattr(b, "shapes"):
            for sb, sa in zip(b.shapes, a.shapes):
                assert sa.material.static_friction == pytest.approx(sb.material.static_friction * d["friction_scale"])
                assert sa.material.restitution == pytest.approx(sb.material.restitution * d["restitution_scale"])
            if b.mass is not None:
                assert a.mass == pytest.approx(b.mass * d["mass_scale"])
            else:
                assert a.density == pytest.approx(b.density * d["mass_scale"])
        else:
            assert a.joint_friction == pytest.approx(b.joint_friction * d["joint_friction_scale"])


def test_the_same_seeds_draw_the_same_noise_and_other_seeds_other_noise():
    t = all_tasks()["stack_blocks_three"]
    draw = lambda p, s: perturb_scene(t.build(s, None).scene, Perturbation(seed=p), s)  # noqa: E731
    assert draw(1, 5) == draw(1, 5)
    assert draw(1, 5) != draw(2, 5)
    assert draw(1, 5)["red_block"] != draw(1, 6)["red_block"]


def test_zero_noise_changes_nothing():
    t = all_tasks()["stack_blocks_three"]
    scene = t.build(0, None).scene
    perturb_scene(scene, Perturbation(seed=1, position_m=0.0, angle_deg=0.0, physics_fraction=0.0), 0)
    ref = t.build(0, None).scene
    for a, b in zip(scene.bodies, ref.bodies):
        assert np.allclose(a.pose, b.pose, atol=1e-15) and a.shapes == b.shapes


@pytest.mark.parametrize("cfg, line", [
    ({"seed": -1}, "perturb.seed must be a non-negative integer or null, got -1"),
    ({"seed": True}, "perturb.seed must be a non-negative integer or null, got True"),
    ({"seed": 1, "position_m": 0.2}, "perturb.position_m must be a number in [0, 0.05], got 0.2"),
    ({"seed": 1, "angle_deg": float("nan")}, "perturb.angle_deg must be a number in [0, 10], got nan"),
    ({"seed": 1, "physics_fraction": "0.1"}, "perturb.physics_fraction must be a number in [0, 0.5], got '0.1'"),
    ({"seed": 1, "mass": 0.1}, "unknown perturb key(s) mass; valid: seed, position_m, angle_deg, physics_fraction"),
])
def test_bad_settings_are_one_line(cfg, line):
    with pytest.raises(ConfigError) as e:
        Perturbation.from_cfg(cfg)
    assert str(e.value) == line


def test_no_seed_is_no_perturbation():
    assert Perturbation.from_cfg({"seed": None, "position_m": 0.001}) is None
    assert Perturbation.from_cfg({"seed": 4}).as_record() == {"seed": 4, "position_m": 0.001, "angle_deg": 0.5,
                                                              "physics_fraction": 0.02}
