"""The rules every simulator backend shares (cab_core.contracts.simsupport)."""
from dataclasses import replace

import numpy as np
import pytest

from cab_core.contracts.scene import Body, Box, CameraSpec, SceneSpec, Shape
from cab_core.contracts.simsupport import (
    PairContacts,
    camera_mount,
    check_camera_spec,
    check_object_names,
    live_or_error,
    object_link_or_bad,
    pack_state,
    pose_or_bad,
    robot_link_or_bad,
    simulator_options,
    start_joint_values,
    step_count_or_bad,
    timestep_option,
    unpack_state,
    vector_or_bad,
)
from cab_core.contracts.simulator import Contact, SimState
from cab_core.errors import BadCommand, ConfigError, SimulatorError
from cab_core.testing import sim_conformance as sc


def test_start_joint_values_open_the_grippers_at_home():
    emb = sc.make_embodiment()
    assert start_joint_values(emb) == {"joint1": 0.0, "joint2": 0.0, "finger_a_joint": sc.FINGER_OPEN,
                                       "finger_b_joint": sc.FINGER_OPEN}
    arm = emb.arms["right"]
    closed = replace(emb, arms={"right": replace(arm, home_qpos=(0.1, 0.2, 0.0, 0.01))})
    assert start_joint_values(closed)["finger_b_joint"] == 0.01
    with pytest.raises(BadCommand, match="home_qpos has 3 values"):
        start_joint_values(replace(emb, arms={"right": replace(arm, home_qpos=(0.1, 0.2, 0.3))}))


@pytest.mark.parametrize("name", ["", "a/b", "robot", "ground", "dup"])
def test_bad_object_names_are_refused(name):
    box = [Shape(Box((0.1, 0.1, 0.1)))]
    bodies = [Body("dup", box), Body(name, box)]
    with pytest.raises(BadCommand, match=repr(name)):
        check_object_names(SceneSpec(bodies=bodies))
    check_object_names(SceneSpec(bodies=[Body("dup", box), Body("other", box)]))


def test_malformed_values_are_bad_commands():
    assert pose_or_bad([0, 0, 1, 2, 0, 0, 0]) == (0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0)
    np.testing.assert_array_equal(vector_or_bad([1, 2], 2, "x"), [1.0, 2.0])
    for bad in ([1, 2, 3], [1, float("nan")], ["a", "b"], [[1, 2]]):
        with pytest.raises(BadCommand, match="x:"):
            vector_or_bad(bad, 2, "x")
    with pytest.raises(BadCommand):
        pose_or_bad([0, 0, 1, 0, 0, 0, 0])


def test_snapshot_pack_round_trip_and_refusals():
    arrays = {"qpos": np.array([0.1, -0.2]), "steps": np.array(7, np.int64)}
    contacts = [Contact("cube", "table", 0.004, (0.1, 0.2, 0.74)), Contact("ground", "robot/link1", 0.5)]
    state = pack_state("toy", "layout-1", arrays, contacts)
    d, c = unpack_state(state, "toy", "layout-1")
    assert sorted(d) == ["qpos", "steps"] and np.array_equal(d["qpos"], arrays["qpos"]) and int(d["steps"]) == 7
    assert c == contacts
    for bad, match in ((SimState("other", state.data), "not a toy state"), (SimState("toy", b"garbage"), "corrupt"),
                       (object(), "not a toy state")):
        with pytest.raises(BadCommand, match=match):
            unpack_state(bad, "toy", "layout-1")
    with pytest.raises(BadCommand, match="different scene"):
        unpack_state(state, "toy", "layout-2")
    # an archive that lost one of its arrays is refused by name, not with a KeyError later
    import io

    with np.load(io.BytesIO(state.data), allow_pickle=False) as z:
        kept = {k: z[k] for k in z.files if k != "qpos"}
    buf = io.BytesIO()
    np.savez(buf, **kept)
    with pytest.raises(BadCommand, match=r"missing \['qpos'\]"):
        unpack_state(SimState("toy", buf.getvalue()), "toy", "layout-1")


def test_step_counts():
    assert step_count_or_bad(np.int64(3)) == 3 and step_count_or_bad(0) == 0
    for bad in (-1, True, 1.5, "2", None):
        with pytest.raises(BadCommand, match="step count"):
            step_count_or_bad(bad)


def test_pair_contacts_sum_per_sorted_pair_and_skip_unnamed_or_self():
    acc = PairContacts()
    acc.add("table", "cube", 1.0, 0.2, 0.4, 1.0)
    acc.add("cube", "table", 3.0, 0.6, 0.0, 2.0, k=3)
    acc.add("a", None, 9.0, 0.0, 0.0, 0.0)
    acc.add("cube", "cube", 9.0, 0.0, 0.0, 0.0)
    acc.add("ball", "cube", 0.5, 0.1, 0.1, 0.1)
    assert acc.contacts() == [Contact("ball", "cube", 0.5, (0.1, 0.1, 0.1)),
                              Contact("cube", "table", 4.0, (0.2, 0.1, 0.75))]
    assert acc.contacts(0.5)[1].impulse == 2.0


def test_camera_spec_and_mount_refusals():
    spec = CameraSpec("head", 64, 48, 60.0, mount_link="link1")
    check_camera_spec(spec, {})
    with pytest.raises(BadCommand, match="duplicate camera name 'head'"):
        check_camera_spec(spec, {"head": None})
    with pytest.raises(BadCommand, match="bad size or field of view"):
        check_camera_spec(replace(spec, fovy_deg=180.0), {})
    assert camera_mount(spec, {"link1": 0}) == 0
    assert camera_mount(replace(spec, mount_link=None), {}) is None
    with pytest.raises(BadCommand, match="mount link 'link1' is not a robot link"):
        camera_mount(spec, {})


def test_options_and_timestep():
    assert simulator_options(None, {"render"}, "toy") == {}
    assert simulator_options({"render": False, "_private": 1}, {"render"}, "toy") == {"render": False, "_private": 1}
    with pytest.raises(ConfigError, match=r"unknown toy simulator option\(s\) \['rendr'\]; known: \['render'\]"):
        simulator_options({"rendr": True}, {"render"}, "toy")
    assert timestep_option({}, "toy") is None and timestep_option({"timestep": 1}, "toy") == 1.0
    for bad in (0, -0.1, True, "0.002"):
        with pytest.raises(ConfigError, match="toy timestep must be a positive number"):
            timestep_option({"timestep": bad}, "toy")


def test_live_or_error_says_closed_or_never_built():
    handle = object()
    assert live_or_error(handle, False) is handle
    with pytest.raises(SimulatorError, match="closed"):
        live_or_error(None, True)
    with pytest.raises(SimulatorError, match=r"build\(\) was not called"):
        live_or_error(None, False)


def test_link_lookups_accept_the_contact_form_and_refuse_unknown_links():
    links = {"base": -1, "tcp_link": 3}
    assert robot_link_or_bad(links, "base") == -1 and robot_link_or_bad(links, "robot/tcp_link") == 3
    for bad in ("robot/", "lidbox/tcp_link", None, 3):
        with pytest.raises(BadCommand, match="unknown robot link"):
            robot_link_or_bad(links, bad)
    assert object_link_or_bad({"lid": 1}, "lidbox", "lid") == 1
    with pytest.raises(BadCommand, match="unknown link 'robot/lid' of object 'lidbox'"):
        object_link_or_bad({"lid": 1}, "lidbox", "robot/lid")
