"""aloha_agilex embodiment: generated URDF/SRDF, frames, cameras, gripper mapping (no simulator)."""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.errors import ConfigError
from cab_core.geometry import axis_angle_quat, euler_quat, intrinsics, pose_to_mat, quat_to_mat
from cab_core.plugins import build_plugin_manager, create
from cab_embodiment_aloha import embodiment as emb
from cab_embodiment_aloha import kinematics, plugin
from cab_embodiment_aloha.params import DEFAULT_PARAMS
from cab_embodiment_aloha.urdf import build_srdf, build_urdf

# Facts (FACTS.md B.2/B.3/A.4)
HOME_TCP = {"left": (-0.300, -0.194, 0.942), "right": (0.305, -0.193, 0.941)}
HEAD_E = np.array([[1, 0, 0, 0.032], [0, -0.8, -0.6, 0.45], [0, 0.6, -0.8, 1.35]])
ARMS = {"left": "fl", "right": "fr"}


@pytest.fixture(scope="module")
def spec(aloha_spec) -> EmbodimentSpec:
    return aloha_spec


@pytest.fixture(scope="module")
def urdf(spec):
    return URDFModel(spec.urdf)


class URDFModel:
    """Independent forward kinematics straight from the URDF text (checks the generator's file,
    not its own kinematics module)."""

    def __init__(self, path: str):
        self.root = ET.parse(path).getroot()
        self.links = {e.get("name"): e for e in self.root.findall("link")}
        self.joints = {e.get("name"): e for e in self.root.findall("joint")}
        self.parent_joint = {j.find("child").get("link"): j for j in self.joints.values()}

    @staticmethod
    def _origin(e) -> np.ndarray:
        o = e.find("origin")
        xyz = np.array([float(v) for v in (o.get("xyz") if o is not None else "0 0 0").split()])
        rpy = np.array([float(v) for v in ((o.get("rpy") or "0 0 0") if o is not None else "0 0 0").split()])
        t = np.eye(4)
        t[:3, :3] = quat_to_mat(euler_quat(*rpy))
        t[:3, 3] = xyz
        return t

    def link_mat(self, link: str, q: dict[str, float]) -> np.ndarray:
        """Pose of ``link`` in the URDF root frame for joint values ``q`` (missing = 0)."""
        chain = []
        while link in self.parent_joint:
            j = self.parent_joint[link]
            chain.append(j)
            link = j.find("parent").get("link")
        t = np.eye(4)
        for j in reversed(chain):
            t = t @ self._origin(j)
            v = q.get(j.get("name"), 0.0)
            ax = j.find("axis")
            axis = np.array([float(a) for a in ax.get("xyz").split()]) if ax is not None else None
            m = np.eye(4)
            if j.get("type") == "revolute":
                m[:3, :3] = quat_to_mat(axis_angle_quat(axis, v))
            elif j.get("type") == "prismatic":
                m[:3, 3] = axis * v
            t = t @ m
        return t

    def world(self, spec, link: str, q: dict[str, float]) -> np.ndarray:
        return pose_to_mat(spec.base_pose) @ self.link_mat(link, q)


def home_q(spec, grip: float = 1.0) -> dict[str, float]:
    q = {}
    for a in spec.arms.values():
        q.update(zip(a.joints, a.home_qpos))
        g = a.gripper
        for j in g.joints:
            q[j] = g.closed_target + grip * (g.open_target - g.closed_target)
    return q


# --- generation --------------------------------------------------------------------------


def test_generation_is_deterministic(tmp_path):
    assert build_urdf(DEFAULT_PARAMS) == build_urdf(DEFAULT_PARAMS)
    assert build_srdf(DEFAULT_PARAMS) == build_srdf(DEFAULT_PARAMS)
    a = emb.generate(DEFAULT_PARAMS, tmp_path / "a")
    b = emb.generate(DEFAULT_PARAMS, tmp_path / "b")
    assert a.name == b.name == f"aloha_agilex-{DEFAULT_PARAMS.digest()}"
    for name in (emb.URDF_NAME, emb.SRDF_NAME, emb.META_NAME):
        assert (a / name).read_bytes() == (b / name).read_bytes()


def test_digest_follows_parameters():
    other = DEFAULT_PARAMS.with_overrides({"forearm": DEFAULT_PARAMS.forearm + 0.01})
    assert other.digest() != DEFAULT_PARAMS.digest()
    assert DEFAULT_PARAMS.with_overrides({}).digest() == DEFAULT_PARAMS.digest()


def test_cache_is_reused_and_regenerated_when_missing(tmp_path):
    folder = emb.generate(DEFAULT_PARAMS, tmp_path)
    stamp = (folder / emb.URDF_NAME).stat().st_mtime_ns
    assert emb.generate(DEFAULT_PARAMS, tmp_path) == folder
    assert (folder / emb.URDF_NAME).stat().st_mtime_ns == stamp
    for f in folder.iterdir():
        f.unlink()
    folder.rmdir()
    again = emb.generate(DEFAULT_PARAMS, tmp_path)
    assert again == folder and (again / emb.URDF_NAME).is_file()
    assert [p.name for p in tmp_path.iterdir()] == [folder.name]  # no temporary folder left


def test_spec_paths_live_in_the_cache(spec, tmp_path_factory):
    assert Path(spec.urdf).is_file() and Path(spec.srdf).is_file()
    assert Path(spec.urdf).parent.parent.name == "embodiments"
    assert Path(spec.urdf).parent.name.startswith("aloha_agilex-")


def test_unknown_parameter_is_a_config_error():
    with pytest.raises(ConfigError, match="bogus"):
        emb.factory({"params": {"bogus": 1.0}})


# --- names ---------------------------------------------------------------------------------


@pytest.mark.parametrize("arm", ["left", "right"])
def test_joint_and_link_names(urdf, spec, arm):
    x = ARMS[arm]
    for i in range(1, 7):
        assert urdf.joints[f"{x}_joint{i}"].get("type") == "revolute"
    for i in (7, 8):
        j = urdf.joints[f"{x}_joint{i}"]
        assert j.get("type") == "prismatic"
        assert j.find("mimic") is None
        assert j.find("parent").get("link") == f"{x}_link6"
        lim = j.find("limit")
        assert (float(lim.get("lower")), float(lim.get("upper"))) == (0.0, 0.047)
    for link in (f"{x}_base_link", *[f"{x}_link{i}" for i in range(1, 9)], f"{x}_tcp", f"{x}_camera"):
        assert link in urdf.links
    a = spec.arms[arm]
    assert a.joints == tuple(f"{x}_joint{i}" for i in range(1, 7))
    assert (a.ee_link, a.tcp_link, a.camera_link, a.base_link) == (
        f"{x}_link6", f"{x}_tcp", f"{x}_camera", f"{x}_base_link")
    assert a.gripper.joints == (f"{x}_joint7", f"{x}_joint8")
    assert a.gripper.finger_links == (f"{x}_link7", f"{x}_link8")
    assert set(a.gripper.finger_links) <= set(a.links)
    # every URDF link below the arm's base belongs to the arm
    below = {link for link in urdf.links if link.startswith(f"{x}_")}
    assert set(a.links) == below


def test_no_mimic_joints_anywhere(urdf):
    assert not any(j.find("mimic") is not None for j in urdf.joints.values())


def test_srdf_lists_adjacent_pairs_only(spec, urdf):
    root = ET.parse(spec.srdf).getroot()
    pairs = [(d.get("link1"), d.get("link2"), d.get("reason")) for d in root.findall("disable_collisions")]
    assert pairs
    for a, b, reason in pairs:
        assert reason == "Adjacent"
        ja, jb = urdf.parent_joint.get(a), urdf.parent_joint.get(b)
        assert (jb is not None and jb.find("parent").get("link") == a) or (
            ja is not None and ja.find("parent").get("link") == b)


def test_every_link_has_positive_mass(urdf):
    for name, link in urdf.links.items():
        m = float(link.find("inertial/mass").get("value"))
        assert m > 0, name
        inertia = link.find("inertial/inertia")
        assert all(float(inertia.get(k)) > 0 for k in ("ixx", "iyy", "izz")), name


def test_joint_order(spec):
    order = spec.joint_order()
    assert order[:8] == [f"fl_joint{i}" for i in range(1, 9)]
    assert order[8:] == [f"fr_joint{i}" for i in range(1, 9)]


# --- home pose and frames ----------------------------------------------------------------


@pytest.mark.parametrize("arm", ["left", "right"])
def test_home_tcp_matches_facts(spec, urdf, arm):
    t = urdf.world(spec, f"{ARMS[arm]}_tcp", home_q(spec))
    assert np.linalg.norm(t[:3, 3] - HOME_TCP[arm]) < 0.01
    approach, opening = t[:3, 0], t[:3, 1]
    assert np.degrees(np.arccos(np.clip(approach @ [0, 1, 0], -1, 1))) < 0.6
    assert abs(opening @ [0, 1, 0]) < 0.01  # the opening line is horizontal-ish, across y
    # the generator's own kinematics agrees with the URDF
    k = kinematics.tcp_pose_world(DEFAULT_PARAMS, arm, spec.arms[arm].home_qpos)
    assert np.allclose(pose_to_mat(k), t, atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kinematics_module_matches_urdf(spec, urdf, seed):
    rng = np.random.default_rng(seed)
    for arm in ("left", "right"):
        q = rng.uniform(-1.5, 1.5, 6)
        t = urdf.world(spec, f"{ARMS[arm]}_tcp", dict(zip(spec.arms[arm].joints, q)))
        assert np.allclose(pose_to_mat(kinematics.tcp_pose_world(DEFAULT_PARAMS, arm, q)), t, atol=1e-6)


@pytest.mark.parametrize("arm", ["left", "right"])
def test_tcp_is_012_ahead_of_flange(spec, urdf, arm):
    q = home_q(spec)
    flange = urdf.world(spec, f"{ARMS[arm]}_link6", q)
    tcp = urdf.world(spec, f"{ARMS[arm]}_tcp", q)
    assert np.allclose(np.linalg.inv(flange) @ tcp[:, 3], [0.12, 0, 0, 1], atol=1e-9)
    assert np.allclose(flange[:3, :3], tcp[:3, :3], atol=1e-9)
    assert spec.tcp_offset_m == 0.12


# --- gripper -----------------------------------------------------------------------------


def test_gripper_spec_values(spec):
    for a in spec.arms.values():
        g = a.gripper
        assert g.closed_target == pytest.approx(-0.01)  # beyond the closed limit (0): squeezes
        assert g.open_target == pytest.approx(0.045)
        assert g.gap_at_zero_m == pytest.approx(0.048)
        assert g.gap_per_unit == 1.0
        assert g.max_opening_m == pytest.approx(0.08)
        assert g.tip_ahead_of_tcp_m == pytest.approx(0.0354)
        gap_open = g.gap_at_zero_m + g.gap_per_unit * 2 * g.open_target
        assert 0.048 <= gap_open <= 0.142
        assert gap_open == pytest.approx(0.138)


@pytest.mark.parametrize("grip", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("arm", ["left", "right"])
def test_finger_geometry(spec, urdf, arm, grip):
    """Finger-link origins 0.0354 m behind the TCP, on the opening line, gap = 0.048 + q7 + q8."""
    x = ARMS[arm]
    g = spec.arms[arm].gripper
    q = home_q(spec, grip)
    qf = np.clip(g.closed_target + grip * (g.open_target - g.closed_target), 0.0, 0.047)
    q.update({j: float(qf) for j in g.joints})
    tcp = urdf.world(spec, f"{x}_tcp", q)
    inv = np.linalg.inv(tcp)
    a = (inv @ urdf.world(spec, f"{x}_link7", q))[:3, 3]
    b = (inv @ urdf.world(spec, f"{x}_link8", q))[:3, 3]
    assert a[0] == pytest.approx(-0.0354, abs=1e-9) and b[0] == pytest.approx(-0.0354, abs=1e-9)
    assert abs(a[2]) < 1e-9 and abs(b[2]) < 1e-9
    assert a[1] > 0 > b[1]  # link7 on +y (opening line), link8 on -y
    assert np.linalg.norm(a - b) == pytest.approx(g.gap_at_zero_m + 2 * qf, abs=1e-9)


def test_finger_pads_reach_the_tip_plane(urdf):
    """The pad's far face lies 0.0708 ahead of the finger-link origin (tip plane 0.0354 ahead of
    the TCP) and its inner face 0.023 inward of the origin."""
    for x in ARMS.values():
        for i, inward in ((7, -1.0), (8, 1.0)):
            boxes = []
            for c in urdf.links[f"{x}_link{i}"].findall("collision"):
                size = np.array([float(v) for v in c.find("geometry/box").get("size").split()])
                xyz = np.array([float(v) for v in c.find("origin").get("xyz").split()])
                boxes.append((xyz - size / 2, xyz + size / 2))
            assert max(hi[0] for _, hi in boxes) == pytest.approx(0.0708)
            inner = min(lo[1] for lo, _ in boxes) if inward < 0 else max(hi[1] for _, hi in boxes)
            assert inner == pytest.approx(0.023 * inward)


# --- cameras -----------------------------------------------------------------------------


def test_camera_names_and_intrinsics(spec):
    cams = {c.name: c for c in spec.cameras}
    assert set(cams) == {"head_camera", "left_camera", "right_camera"}
    head = cams["head_camera"]
    assert (head.width, head.height, head.fovy_deg, head.mount_link) == (640, 480, 37.0, None)
    assert intrinsics(640, 480, 37.0)[0, 0] == pytest.approx(717.284, abs=1e-3)
    for name, link in (("left_camera", "fl_camera"), ("right_camera", "fr_camera")):
        c = cams[name]
        assert (c.width, c.height, c.fovy_deg, c.mount_link) == (320, 240, 37.0, link)
        assert c.pose == (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
        assert intrinsics(320, 240, 37.0)[0, 0] == pytest.approx(358.642, abs=1e-3)


def test_head_camera_extrinsics_match_facts(spec):
    head = next(c for c in spec.cameras if c.name == "head_camera")
    world_from_cam = pose_to_mat(head.pose)
    e = np.linalg.inv(world_from_cam)[:3]  # world -> camera
    assert np.allclose(e, HEAD_E, atol=1e-6)


def _project(cam_world: np.ndarray, p, w=320, h=240, fovy=37.0):
    pc = (np.linalg.inv(cam_world) @ np.r_[p, 1.0])[:3]
    k = intrinsics(w, h, fovy)
    return (k @ (pc / pc[2]))[:2], pc[2]


@pytest.mark.parametrize("grip", [0.0, 1.0])
@pytest.mark.parametrize("arm", ["left", "right"])
def test_wrist_camera_sees_fingertips(spec, urdf, arm, grip):
    x = ARMS[arm]
    q = home_q(spec, grip)
    cam = urdf.world(spec, f"{x}_camera", q)
    tcp = urdf.world(spec, f"{x}_tcp", q)
    # OpenCV axes: +z looks roughly along the approach, +y points roughly down the gripper's -z
    assert cam[:3, 2] @ tcp[:3, 0] > np.cos(np.radians(30))
    assert cam[:3, 1] @ -tcp[:3, 2] > np.cos(np.radians(30))
    assert cam[:3, 0] @ -tcp[:3, 1] > 0.99
    for i in (7, 8):
        f = urdf.world(spec, f"{x}_link{i}", q)
        side = -1.0 if i == 7 else 1.0  # inward direction in the finger frame
        for tip in ([0.0708, 0.023 * side, 0.0], [0.0708, 0.018 * side, 0.013]):
            (u, v), depth = _project(cam, (f @ np.r_[tip, 1.0])[:3])
            assert depth > 0.1  # beyond the near plane
            assert 0 <= u < 320 and 0 <= v < 240, (i, tip, u, v)
    # what lies 0.1 m in front of the fingertips is in view, above the fingertips in the image
    (u, v), _ = _project(cam, (tcp @ np.r_[0.0354 + 0.1, 0, 0, 1.0])[:3])
    (ut, vt), _ = _project(cam, (tcp @ np.r_[0.0354, 0, 0, 1.0])[:3])
    assert 0 <= u < 320 and 0 <= v < vt < 240


# --- facts and plugin --------------------------------------------------------------------


def test_facts_for_get_embodiment(spec):
    f = spec.facts
    assert f["motion"]["max_single_displacement_m"] == 0.30
    assert f["gripper"]["max_opening_m"] == 0.08
    assert f["gripper"]["finger_gap_range_m"] == [0.048, 0.142]
    assert f["gripper"]["finger_origin_behind_tcp_m"] == 0.0354
    assert f["gripper"]["fingertip_plane_ahead_of_tcp_m"] == 0.0354
    assert f["tcp"]["flange_to_tcp_m"] == 0.12
    assert set(f["cameras"]) == {"head_camera", "left_camera", "right_camera"}
    text = repr(f)
    assert "urdf" not in text.lower() and "/" not in str(f["cameras"])  # no paths


def test_drive_parameters(spec):
    assert (spec.drive_stiffness, spec.drive_damping) == (1000.0, 200.0)
    assert (spec.gripper_stiffness, spec.gripper_damping) == (1000.0, 200.0)
    assert spec.base_pose == pytest.approx((0.0, -0.65, 0.0, 0.70710678, 0.0, 0.0, 0.70710678))


def test_plugin_hook_registers_the_factory(spec):
    reg = plugin.cab_embodiments()
    assert set(reg) == {"aloha_agilex"}
    assert reg["aloha_agilex"] is emb.factory


def test_entry_point_is_declared():
    from importlib.metadata import entry_points

    eps = {e.name: e.value for e in entry_points(group="cab")}
    assert eps.get("embodiment_aloha") == "cab_embodiment_aloha.plugin"


def test_plugin_manager_creates_the_embodiment(spec):
    pm = build_plugin_manager(extra=[plugin], autoload=False)
    made = create("embodiments", "aloha_agilex", {}, pm=pm)
    assert made.urdf == spec.urdf and made.arms.keys() == {"left", "right"}
