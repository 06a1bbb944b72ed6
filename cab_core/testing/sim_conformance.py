"""Conformance checks that every :class:`cab_core.contracts.simulator.Simulator` backend must pass.

The suite imports no simulator. It generates its own tiny world (a one-arm robot URDF with two
revolute joints, a two-finger prismatic gripper, a TCP link and a camera link; a scene with a table,
a cube, a ball, a cylinder, a kinematic capsule, a convex mesh, a static post, a falling ball, an
articulated box with a hinged lid, and a fixed camera) and runs each check against a backend's
*factory*: a zero-argument callable that returns a fresh, unbuilt simulator able to render.

``pytest --cab-conformance=sims`` runs every check on every installed simulator
(:mod:`cab_core.testing.pytest_plugin`); by hand, one check is a call::

    from cab_core.testing import sim_conformance as sc

    sc.check_contacts(lambda: MySimulator({"render": True}))

Checks in :data:`NEEDS_RENDERER` capture images; the rest also pass on a physics-only build.
Behaviour the suite pins down beyond the contract's docstrings: ``set_object_pose`` zeroes the
body's velocity; ``step(0)`` is a no-op; a robot at rest touches nothing.

Every check builds its own simulator(s) and closes them. Assets are written once per process to a
temporary directory (or to ``workdir`` when given); they are deterministic.

World layout (metres, world frame +x right, +y forward, +z up): the table top is at z = 0.74; the
robot base stands at (0, -0.55, 0) and its arm reaches forward (+y) at z = 0.82 above the table's
near edge; joint1 yaws the arm about +z (positive turns it towards -x, where the static ``post``
stands), joint2 pitches it about +x (positive lifts the hand).
"""
from __future__ import annotations

import atexit
import math
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cab_core.contracts.embodiment import ArmSpec, EmbodimentSpec, GripperSpec
from cab_core.contracts.scene import (
    ArticulatedObject,
    Body,
    Box,
    CameraSpec,
    Capsule,
    Cylinder,
    Material,
    Mesh,
    SceneSpec,
    Shape,
    Sphere,
)
from cab_core.contracts.simulator import Contact, SimState, Simulator
from cab_core.errors import BadCommand, RendererUnavailable, SimulatorError
from cab_core.geometry import intrinsics, look_at_cv, pose_inv, pose_mul, quat_angle, quat_to_mat, transform_point
from cab_core.testing import isolation_conformance as _isolation
from cab_core.testing.appearance_conformance import check_appearance  # the tasks' colours

SimFactory = Callable[[], Simulator]

# -- the test robot -------------------------------------------------------------------------------

ROBOT_BASE = (0.0, -0.55, 0.0, 1.0, 0.0, 0.0, 0.0)
ARM_JOINTS = ("joint1", "joint2")
FINGER_JOINTS = ("finger_a_joint", "finger_b_joint")
FINGER_LINKS = ("finger_a", "finger_b")
ROBOT_LINKS = ("base_link", "link1", "link2", "ee_link", "tcp_link", "camera_link") + FINGER_LINKS
FINGER_OPEN = 0.04
WRIST_CAMERA = "wrist_cam"
HEAD_CAMERA = "overview"
TIMESTEP = 1.0 / 250.0
CUBE_MASS = 0.1
TABLE_TOP = 0.74
POST_XY = (-0.20, -0.55)


def _inertial(mass: float, half: tuple[float, float, float], xyz=(0.0, 0.0, 0.0)) -> str:
    hx, hy, hz = (2 * h for h in half)
    ixx = mass * (hy * hy + hz * hz) / 12.0
    iyy = mass * (hx * hx + hz * hz) / 12.0
    izz = mass * (hx * hx + hy * hy) / 12.0
    return (f'<inertial><origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="0 0 0"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx:.8g}" ixy="0" ixz="0" iyy="{iyy:.8g}" iyz="0" izz="{izz:.8g}"/></inertial>')


def _box_link(name: str, half, xyz=(0.0, 0.0, 0.0), mass: float = 1.0, rgba="0.6 0.6 0.65 1",
              collision: bool = True) -> str:
    size = " ".join(f"{2 * h:g}" for h in half)
    origin = f'<origin xyz="{xyz[0]:g} {xyz[1]:g} {xyz[2]:g}" rpy="0 0 0"/>'
    geo = f'<geometry><box size="{size}"/></geometry>'
    col = f"<collision>{origin}{geo}</collision>" if collision else ""
    return (f'<link name="{name}">{_inertial(mass, half, xyz)}'
            f'<visual>{origin}{geo}<material name="{name}_mat"><color rgba="{rgba}"/></material></visual>'
            f"{col}</link>")


def _rpy_from_matrix(m: np.ndarray) -> tuple[float, float, float]:
    """URDF rpy (R = Rz(yaw) Ry(pitch) Rx(roll)) of a rotation matrix."""
    pitch = math.asin(max(-1.0, min(1.0, -m[2, 0])))
    if abs(math.cos(pitch)) > 1e-9:
        roll = math.atan2(m[2, 1], m[2, 2])
        yaw = math.atan2(m[1, 0], m[0, 0])
    else:  # gimbal lock: put everything in yaw
        roll = 0.0
        yaw = math.atan2(-m[0, 1], m[1, 1])
    return roll, pitch, yaw


def robot_urdf() -> str:
    """The test arm. ee_link: +x approach (world +y at home), +y finger-opening line, +z up.
    camera_link is an OpenCV-convention frame looking along the approach axis."""
    cam_rot = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns: cam x,y,z in ee
    r, p, y = _rpy_from_matrix(cam_rot)
    fa = ("finger_a", (0.085, 0.01, 0.0), "0 1 0")
    fb = ("finger_b", (0.085, -0.01, 0.0), "0 -1 0")
    fingers = "".join(
        _box_link(n, (0.035, 0.005, 0.01), (0.035, 0.0, 0.0), mass=0.1, rgba="0.2 0.2 0.2 1")
        + f'<joint name="{n}_joint" type="prismatic"><parent link="ee_link"/><child link="{n}"/>'
          f'<origin xyz="{o[0]} {o[1]} {o[2]}" rpy="0 0 0"/><axis xyz="{ax}"/>'
          f'<limit lower="0" upper="{FINGER_OPEN}" effort="200" velocity="1"/></joint>'
        for n, o, ax in (fa, fb))
    return f"""<?xml version="1.0"?>
<robot name="cab_test_arm">
{_box_link("base_link", (0.05, 0.05, 0.39), (0.0, 0.0, 0.40), mass=5.0)}
{_box_link("link1", (0.04, 0.04, 0.02), mass=1.0, rgba="0.3 0.3 0.8 1")}
<joint name="joint1" type="revolute"><parent link="base_link"/><child link="link1"/>
  <origin xyz="0 0 0.82" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="500" velocity="3"/></joint>
{_box_link("link2", (0.03, 0.15, 0.03), (0.0, 0.15, 0.0), mass=1.0, rgba="0.3 0.8 0.3 1")}
<joint name="joint2" type="revolute"><parent link="link1"/><child link="link2"/>
  <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/><limit lower="-1.5" upper="1.5" effort="500" velocity="3"/></joint>
{_box_link("ee_link", (0.03, 0.03, 0.03), (0.03, 0.0, 0.0), mass=0.3, rgba="0.8 0.3 0.3 1")}
<joint name="ee_fixed" type="fixed"><parent link="link2"/><child link="ee_link"/>
  <origin xyz="0 0.30 0" rpy="0 0 {math.pi / 2}"/></joint>
<link name="tcp_link">{_inertial(0.01, (0.005, 0.005, 0.005))}</link>
<joint name="tcp_fixed" type="fixed"><parent link="ee_link"/><child link="tcp_link"/>
  <origin xyz="0.12 0 0" rpy="0 0 0"/></joint>
<link name="camera_link">{_inertial(0.01, (0.005, 0.005, 0.005))}</link>
<joint name="camera_fixed" type="fixed"><parent link="ee_link"/><child link="camera_link"/>
  <origin xyz="0.0 0 0.05" rpy="{r} {p} {y}"/></joint>
{fingers}
</robot>
"""


def robot_srdf() -> str:
    pairs = [("finger_a", "finger_b"), ("link2", "finger_a"), ("link2", "finger_b"),
             ("base_link", "link2"), ("link1", "ee_link")]
    body = "".join(f'<disable_collisions link1="{a}" link2="{b}" reason="Default"/>' for a, b in pairs)
    return f'<?xml version="1.0"?><robot name="cab_test_arm">{body}</robot>\n'


def lidbox_urdf() -> str:
    """A box with a lid hinged at its back edge: one revolute joint, 0 closed, positive opens."""
    return f"""<?xml version="1.0"?>
<robot name="lidbox">
{_box_link("base", (0.06, 0.06, 0.03), mass=0.5, rgba="0.8 0.7 0.2 1")}
{_box_link("lid", (0.06, 0.06, 0.005), (0.0, -0.06, 0.005), mass=0.05, rgba="0.2 0.7 0.8 1")}
<joint name="hinge" type="revolute"><parent link="base"/><child link="lid"/>
  <origin xyz="0 0.06 0.03" rpy="0 0 0"/><axis xyz="-1 0 0"/>
  <limit lower="0" upper="1.8" effort="10" velocity="5"/></joint>
</robot>
"""


def cube_obj(half: float = 0.02) -> str:
    h = half
    v = [(-h, -h, -h), (h, -h, -h), (h, h, -h), (-h, h, -h), (-h, -h, h), (h, -h, h), (h, h, h), (-h, h, h)]
    faces = [(1, 3, 2), (1, 4, 3), (5, 6, 7), (5, 7, 8), (1, 2, 6), (1, 6, 5),
             (2, 3, 7), (2, 7, 6), (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8)]
    return "".join(f"v {x:g} {y:g} {z:g}\n" for x, y, z in v) + "".join(f"f {a} {b} {c}\n" for a, b, c in faces)


_WORKDIR: Path | None = None


def assets_dir(workdir: str | Path | None = None) -> Path:
    """Write the test assets (idempotent) and return their directory."""
    global _WORKDIR
    if workdir is None:
        if _WORKDIR is None:
            _WORKDIR = Path(tempfile.mkdtemp(prefix="cab-sim-conformance-"))
            atexit.register(shutil.rmtree, _WORKDIR, True)
        d = _WORKDIR
    else:
        d = Path(workdir)
    d.mkdir(parents=True, exist_ok=True)
    for name, text in (("cab_test_arm.urdf", robot_urdf()), ("cab_test_arm.srdf", robot_srdf()),
                       ("lidbox.urdf", lidbox_urdf()), ("cube.obj", cube_obj())):
        p = d / name
        if not p.exists() or p.read_text() != text:
            p.write_text(text)
    return d


def make_embodiment(workdir: str | Path | None = None) -> EmbodimentSpec:
    d = assets_dir(workdir)
    gripper = GripperSpec(joints=FINGER_JOINTS, finger_links=FINGER_LINKS, closed_target=0.0,
                          open_target=FINGER_OPEN, gap_at_zero_m=0.02, gap_per_unit=1.0)
    arm = ArmSpec(name="right", joints=ARM_JOINTS, base_link="base_link", ee_link="ee_link",
                  tcp_link="tcp_link", camera_link="camera_link", gripper=gripper,
                  home_qpos=(0.0, 0.0), links=ROBOT_LINKS[1:])
    wrist = CameraSpec(WRIST_CAMERA, width=160, height=120, fovy_deg=37.0, mount_link="camera_link")
    return EmbodimentSpec(name="cab_test_arm", urdf=str(d / "cab_test_arm.urdf"),
                          srdf=str(d / "cab_test_arm.srdf"), base_pose=ROBOT_BASE,
                          arms={"right": arm}, cameras=(wrist,), drive_stiffness=1000.0,
                          drive_damping=200.0, gripper_stiffness=1000.0, gripper_damping=200.0)


def make_scene(workdir: str | Path | None = None) -> SceneSpec:
    d = assets_dir(workdir)
    up = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)  # x axis -> world z (stand a cylinder)
    bodies = [
        Body("table", [Shape(Box((0.4, 0.3, 0.025)), material=Material(color=(0.5, 0.35, 0.2, 1)))],
             pose=(0.0, 0.0, TABLE_TOP - 0.025, 1, 0, 0, 0), kind="static"),
        Body("cube", [Shape(Box((0.025, 0.025, 0.025)), material=Material(color=(0.9, 0.1, 0.1, 1)))],
             pose=(0.15, 0.10, TABLE_TOP + 0.025, 1, 0, 0, 0), mass=CUBE_MASS),
        Body("ball", [Shape(Sphere(0.02), material=Material(color=(0.1, 0.2, 0.9, 1)))],
             pose=(0.28, -0.15, TABLE_TOP + 0.02, 1, 0, 0, 0), density=400.0),
        Body("can", [Shape(Cylinder(0.03, 0.04), material=Material(color=(0.1, 0.7, 0.2, 1)))],
             pose=(0.0, 0.18, TABLE_TOP + 0.04) + up),
        Body("wand", [Shape(Capsule(0.015, 0.05), material=Material(color=(0.9, 0.9, 0.1, 1)))],
             pose=(0.30, 0.20, 0.95, 1, 0, 0, 0), kind="kinematic"),
        Body("block", [Shape(Mesh(str(d / "cube.obj"), scale=(1.0, 1.0, 1.5)),
                             material=Material(color=(0.7, 0.2, 0.7, 1), static_friction=0.8,
                                               dynamic_friction=0.7))],
             pose=(-0.28, 0.12, TABLE_TOP + 0.03, 1, 0, 0, 0), mass=0.05,
             linear_damping=0.1, angular_damping=0.1),
        Body("post", [Shape(Box((0.02, 0.02, 0.12)))], pose=(POST_XY[0], POST_XY[1], 0.85, 1, 0, 0, 0),
             kind="static"),
        Body("dropper", [Shape(Sphere(0.02))], pose=(0.9, 0.7, 0.6, 1, 0, 0, 0), density=1000.0,
             angular_damping=0.0),
    ]
    lidbox = ArticulatedObject("lidbox", str(d / "lidbox.urdf"),
                               pose=(-0.15, 0.02, TABLE_TOP + 0.03, 1, 0, 0, 0), fix_root=False,
                               qpos=(0.0,), joint_damping=0.05)
    head = CameraSpec(HEAD_CAMERA, width=320, height=240, fovy_deg=45.0,
                      pose=tuple(look_at_cv((0.0, -1.0, 1.45), (0.0, 0.0, TABLE_TOP))))
    return SceneSpec(bodies=bodies, articulations=[lidbox], cameras=[head], timestep=TIMESTEP)


def build(factory: SimFactory, workdir: str | Path | None = None) -> Simulator:
    sim = factory()
    sim.build(make_scene(workdir), make_embodiment(workdir))
    return sim


# -- state capture ---------------------------------------------------------------------------------


def world_state(sim: Simulator) -> dict[str, np.ndarray]:
    """Everything the contract exposes about the dynamic state, as arrays (for comparisons)."""
    out = {"qpos": np.asarray(sim.get_qpos(), float), "qvel": np.asarray(sim.get_qvel(), float),
           "targets": np.asarray(sim.get_drive_targets(), float)}
    for name in sim.object_names():
        out[f"{name}.pose"] = np.asarray(sim.get_object_pose(name), float)
        out[f"{name}.vel"] = np.asarray(sim.get_object_velocity(name), float)
        out[f"{name}.qpos"] = np.asarray(sim.get_object_qpos(name), float)
    out["tcp"] = np.asarray(sim.get_link_pose("tcp_link"), float)
    return out


def _max_diff(a: dict, b: dict) -> tuple[float, str]:
    assert a.keys() == b.keys(), (sorted(a), sorted(b))
    worst, where = 0.0, ""
    for k in a:
        assert a[k].shape == b[k].shape, (k, a[k].shape, b[k].shape)
        if a[k].size:
            d = float(np.max(np.abs(a[k] - b[k])))
            if d > worst:
                worst, where = d, k
    return worst, where


def _assert_bit_equal(a: dict, b: dict, what: str) -> None:
    for k in a:
        assert np.array_equal(a[k], b[k]), f"{what}: {k} differs: {a[k]} vs {b[k]}"


def _motion_script(sim: Simulator, steps: int, phase: float = 0.0) -> None:
    """Drive both arm joints and the gripper along a smooth path, one target per step."""
    base = np.asarray(sim.get_drive_targets(), float).copy()
    for i in range(steps):
        t = (i + phase) * sim.timestep
        tgt = base.copy()
        tgt[0] = -0.4 * math.sin(2.0 * t)
        tgt[1] = 0.3 * math.sin(3.0 * t)
        tgt[2] = tgt[3] = FINGER_OPEN * (0.5 + 0.5 * math.cos(4.0 * t))
        sim.set_drive_targets(tgt)
        sim.step(1)


# -- checks ---------------------------------------------------------------------------------------


def check_build_and_names(factory: SimFactory) -> None:
    """Names, joint order, timestep, initial robot state, idempotent close."""
    sim = build(factory)
    try:
        scene, emb = make_scene(), make_embodiment()
        assert sim.object_names() == scene.names()
        assert list(sim.joint_names) == emb.joint_order()
        assert sorted(sim.camera_names()) == sorted([HEAD_CAMERA, WRIST_CAMERA])
        assert abs(sim.timestep - TIMESTEP) < 1e-12
        q = sim.get_qpos()
        assert q.shape == (4,) and q.dtype == np.float64 and np.all(np.isfinite(q))
        assert sim.get_qvel().shape == (4,)
        assert sim.get_drive_targets().shape == (4,)
        for name in scene.names():
            p = sim.get_object_pose(name)
            assert p.shape == (7,) and abs(np.linalg.norm(p[3:]) - 1.0) < 1e-5
        # spawn poses are honoured (before any step)
        np.testing.assert_allclose(sim.get_object_pose("cube")[:3], scene.body("cube").pose[:3], atol=1e-6)
        np.testing.assert_allclose(sim.get_object_pose("lidbox")[:3], scene.articulations[0].pose[:3], atol=1e-6)
        np.testing.assert_allclose(sim.get_object_qpos("lidbox"), [0.0], atol=1e-6)
        base = sim.get_link_pose("base_link")
        np.testing.assert_allclose(base, ROBOT_BASE, atol=1e-6)
        versions = sim.versions()
        assert isinstance(versions, dict) and versions and all(isinstance(v, str) for v in versions.values())
    finally:
        sim.close()
    sim.close()  # idempotent


def check_seeded_reset_identical(factory: SimFactory) -> None:
    """Two builds of the same spec give identical states, trajectories and images."""
    a, b = build(factory), build(factory)
    try:
        _assert_bit_equal(world_state(a), world_state(b), "fresh builds")
        for cam in a.camera_names():
            assert np.array_equal(a.render(cam), b.render(cam)), f"{cam}: images of two builds differ"
        _motion_script(a, 120)
        _motion_script(b, 120)
        _assert_bit_equal(world_state(a), world_state(b), "after 120 identical steps")
        for cam in a.camera_names():
            assert np.array_equal(a.render(cam), b.render(cam)), f"{cam}: images differ after stepping"
    finally:
        a.close()
        b.close()


def check_sequential_builds_identical(factory: SimFactory) -> None:
    """A world built after another was used and closed in the same process (a warm worker's next
    attempt) starts, steps and renders exactly as the first did: nothing leaks across builds."""
    def run_once() -> tuple[dict, dict]:
        sim = build(factory)
        try:
            images = {cam: sim.render(cam) for cam in sim.camera_names()}
            _motion_script(sim, 120)
            images.update({f"{cam}@120": sim.render(cam) for cam in sim.camera_names()})
            return world_state(sim), images
        finally:
            sim.close()

    state1, images1 = run_once()
    other = build(factory)  # a different history in between: stepped, snapshotted, rendered, closed
    try:
        _motion_script(other, 60, phase=17.0)
        other.restore_state(other.save_state())
        other.render(HEAD_CAMERA)
    finally:
        other.close()
    state2, images2 = run_once()
    _assert_bit_equal(state1, state2, "second build in the process")
    for k in images1:
        assert np.array_equal(images1[k], images2[k]), f"{k}: images differ in the second build"


def check_snapshot_restore_exact(factory: SimFactory, n_steps: int = 150) -> None:
    """A restore reproduces the snapshot bit-exactly; replays from the snapshot agree to 1e-6."""
    sim = build(factory)
    try:
        _motion_script(sim, 60)  # robot moving, objects settling
        snap = sim.save_state()
        assert isinstance(snap, SimState) and isinstance(snap.data, bytes) and snap.backend
        s0 = world_state(sim)
        _motion_script(sim, 80, phase=60)
        sim.set_object_pose("cube", (0.1, 0.0, 1.2, 1, 0, 0, 0))
        sim.set_object_qpos("lidbox", [0.7])
        sim.restore_state(snap)
        _assert_bit_equal(s0, world_state(sim), "after restore")
        _motion_script(sim, n_steps, phase=60)
        run1 = world_state(sim)
        sim.restore_state(snap)
        _motion_script(sim, n_steps, phase=60)
        run2 = world_state(sim)
        worst, where = _max_diff(run1, run2)
        assert worst <= 1e-6, f"replay from the same snapshot diverged by {worst:g} at {where}"
    finally:
        sim.close()


def check_snapshot_portable(factory: SimFactory, n_steps: int = 150) -> None:
    """A snapshot restores into another simulator built from the same spec (replay from records),
    exactly, and both continue alike (1e-6)."""
    sim, other = build(factory), build(factory)
    try:
        _motion_script(sim, 60)
        snap = sim.save_state()
        s0 = world_state(sim)
        other.step(7)  # a different history
        other.restore_state(snap)
        _assert_bit_equal(s0, world_state(other), "restore into another build")
        _motion_script(sim, n_steps, phase=60)
        _motion_script(other, n_steps, phase=60)
        worst, where = _max_diff(world_state(sim), world_state(other))
        assert worst <= 1e-6, f"the two builds diverged by {worst:g} at {where} after the restore"
    finally:
        sim.close()
        other.close()


def check_bad_commands(factory: SimFactory) -> None:
    """Malformed commands raise BadCommand and change nothing."""
    sim = build(factory)
    try:
        before = world_state(sim)
        n = len(sim.joint_names)
        bad_calls = [
            lambda: sim.get_link_pose("no_such_link"),
            lambda: sim.get_object_pose("no_such_object"),
            lambda: sim.set_object_pose("no_such_object", (0, 0, 1, 1, 0, 0, 0)),
            lambda: sim.get_object_velocity("no_such_object"),
            lambda: sim.get_object_qpos("no_such_object"),
            lambda: sim.set_object_qpos("no_such_object", [0.0]),
            lambda: sim.get_object_link_pose("lidbox", "no_such_link"),
            lambda: sim.get_object_link_pose("no_such_object", "lid"),
            lambda: sim.camera_pose("no_such_camera"),
            lambda: sim.camera_intrinsics("no_such_camera"),
            lambda: sim.camera_size("no_such_camera"),
            lambda: sim.render("no_such_camera"),
            lambda: sim.set_drive_targets(np.zeros(n + 1)),
            lambda: sim.set_drive_targets(np.zeros((n, 1))),
            # bad input on purpose, lists as well as arrays: each must be refused with BadCommand
            lambda: sim.set_drive_targets([0.0, float("nan")] + [0.0] * (n - 2)),  # type: ignore[arg-type]
            lambda: sim.set_drive_targets([0.0, float("inf")] + [0.0] * (n - 2)),  # type: ignore[arg-type]
            lambda: sim.set_drive_targets(["a"] * n),  # type: ignore[arg-type]
            lambda: sim.set_qpos(np.zeros(n - 1)),
            lambda: sim.set_qpos([float("nan")] * n),  # type: ignore[arg-type]
            lambda: sim.set_object_pose("cube", (0, 0, 1)),
            lambda: sim.set_object_pose("cube", (0, 0, float("nan"), 1, 0, 0, 0)),
            lambda: sim.set_object_pose("cube", (0, 0, 1, 0, 0, 0, 0)),
            lambda: sim.set_object_qpos("lidbox", [0.1, 0.2]),
            lambda: sim.set_object_qpos("lidbox", [float("nan")]),
            lambda: sim.set_object_qpos("cube", [0.1]),
            lambda: sim.step(-1),
            lambda: sim.restore_state(SimState(backend="no_such_backend", data=b"")),
            lambda: sim.restore_state(SimState(backend=sim.save_state().backend, data=b"garbage")),
        ]
        for i, call in enumerate(bad_calls):
            try:
                call()
            except BadCommand:
                continue
            except Exception as e:  # noqa: BLE001
                raise AssertionError(f"bad call #{i} raised {type(e).__name__}, not BadCommand: {e}") from e
            raise AssertionError(f"bad call #{i} was accepted")
        _assert_bit_equal(before, world_state(sim), "after rejected commands")
        sim.step(0)  # a no-op, not an error
    finally:
        sim.close()


def check_drive_tracking(factory: SimFactory) -> None:
    """Position drives reach a target within 1 s of simulated time; set_qpos teleports."""
    sim = build(factory)
    try:
        target = np.array([-0.5, 0.3, 0.01, 0.03])
        sim.set_drive_targets(target)
        np.testing.assert_allclose(sim.get_drive_targets(), target, atol=1e-7)
        sim.step(int(round(1.0 / sim.timestep)))
        err = np.abs(sim.get_qpos() - target)
        assert np.all(err[:2] < 0.01), f"arm joints off target by {err[:2]} rad after 1 s"
        assert np.all(err[2:] < 0.002), f"finger joints off target by {err[2:]} m after 1 s"
        assert np.all(np.abs(sim.get_qvel()) < 0.05), f"not settled: qvel {sim.get_qvel()}"
        q = np.array([0.3, 0.2, 0.02, 0.02])
        sim.set_qpos(q)
        np.testing.assert_allclose(sim.get_qpos(), q, atol=1e-6)
        np.testing.assert_allclose(sim.get_drive_targets(), q, atol=1e-7)
        sim.step(25)
        np.testing.assert_allclose(sim.get_qpos(), q, atol=2e-3)  # holds where it was put
        # the TCP follows forward kinematics: 0.12 m ahead of ee_link along its +x axis
        ee, tcp = sim.get_link_pose("ee_link"), sim.get_link_pose("tcp_link")
        np.testing.assert_allclose(tcp, pose_mul(ee, (0.12, 0, 0, 1, 0, 0, 0)), atol=1e-5)
    finally:
        sim.close()


def _contact_map(contacts: list[Contact]) -> dict[frozenset, Contact]:
    out: dict[frozenset, Contact] = {}
    for c in contacts:
        key = frozenset((c.a, c.b))
        assert key not in out, f"pair {sorted(key)} reported twice"
        out[key] = c
    return out


def _valid_contact_name(sim: Simulator, name: str) -> bool:
    if name == "ground" or name in sim.object_names():
        return True
    head, _, link = name.partition("/")
    if head == "robot":
        return link in ROBOT_LINKS
    return head == "lidbox" and link in ("base", "lid")


def check_contacts(factory: SimFactory) -> None:
    """Resting contacts report named pairs with impulses in N*s; the robot's links are named."""
    sim = build(factory)
    try:
        sim.step(150)
        contacts = sim.get_contacts()
        assert contacts == sim.get_contacts(), "get_contacts must not change between steps"
        pairs = _contact_map(contacts)
        for c in contacts:
            assert c.a != c.b and _valid_contact_name(sim, c.a) and _valid_contact_name(sim, c.b), c
            assert c.impulse > 0.0 and math.isfinite(c.impulse), c
        cube = pairs.get(frozenset(("cube", "table")))
        assert cube is not None, f"no cube-table contact among {sorted(map(sorted, pairs))}"
        expected = CUBE_MASS * 9.81 * sim.timestep  # N*s per step, resting
        assert 0.7 * expected < cube.impulse < 1.3 * expected, (cube.impulse, expected)
        if cube.point is not None:
            p, c0 = np.asarray(cube.point), sim.get_object_pose("cube")[:3]
            assert abs(p[2] - TABLE_TOP) < 0.005 and np.all(np.abs(p[:2] - c0[:2]) < 0.03), p
        assert frozenset(("lidbox/base", "table")) in pairs, sorted(map(sorted, pairs))
        assert frozenset(("dropper", "ground")) in pairs, sorted(map(sorted, pairs))
        assert not any(n.startswith("robot/") for c in contacts for n in (c.a, c.b))
        # swing the arm into the static post
        tgt = sim.get_drive_targets()
        tgt[0] = 1.6
        sim.set_drive_targets(tgt)
        sim.step(250)
        robot = [c for c in sim.get_contacts() if "post" in (c.a, c.b)]
        assert robot, "the arm swung into the post but no contact was reported"
        other = {c.b if c.a == "post" else c.a for c in robot}
        assert all(n.startswith("robot/") and n[6:] in ROBOT_LINKS for n in other), other
        assert sim.get_qpos()[0] < 1.5, "the post did not stop the arm"
    finally:
        sim.close()


def check_cameras(factory: SimFactory) -> None:
    """Images, intrinsics, fixed and mounted camera poses."""
    sim = build(factory)
    try:
        scene, emb = make_scene(), make_embodiment()
        specs = {c.name: c for c in list(scene.cameras) + list(emb.cameras)}
        for name, spec in specs.items():
            assert sim.camera_size(name) == (spec.height, spec.width)
            np.testing.assert_allclose(sim.camera_intrinsics(name),
                                       intrinsics(spec.width, spec.height, spec.fovy_deg), rtol=1e-5)
            img = sim.render(name)
            assert img.shape == (spec.height, spec.width, 3) and img.dtype == np.uint8, (img.shape, img.dtype)
            assert img.std() > 2.0, f"{name}: the image is blank"
        head = sim.camera_pose(HEAD_CAMERA)
        np.testing.assert_allclose(head[:3], specs[HEAD_CAMERA].pose[:3], atol=1e-5)
        assert abs(abs(float(np.dot(head[3:], specs[HEAD_CAMERA].pose[3:]))) - 1.0) < 1e-5
        # the table is in front of the head camera: its centre projects inside the image
        p_cam = transform_point(pose_inv(head), (0.0, 0.0, TABLE_TOP))
        uv = (sim.camera_intrinsics(HEAD_CAMERA) @ p_cam)[:2] / p_cam[2]
        assert p_cam[2] > 0 and 0 < uv[0] < 320 and 0 < uv[1] < 240, uv
        # mounted camera = mount link pose * local pose, and it moves with the link
        wrist0 = sim.camera_pose(WRIST_CAMERA)
        np.testing.assert_allclose(wrist0, pose_mul(sim.get_link_pose("camera_link"), specs[WRIST_CAMERA].pose),
                                   atol=1e-5)
        img0 = sim.render(WRIST_CAMERA)
        sim.set_qpos([0.6, 0.4, FINGER_OPEN, FINGER_OPEN])  # type: ignore[arg-type]  # a list: backends take one
        sim.step(1)
        wrist1 = sim.camera_pose(WRIST_CAMERA)
        assert np.linalg.norm(wrist1[:3] - wrist0[:3]) > 0.05, "the wrist camera did not move with its link"
        np.testing.assert_allclose(wrist1, pose_mul(sim.get_link_pose("camera_link"), specs[WRIST_CAMERA].pose),
                                   atol=1e-5)
        assert not np.array_equal(img0, sim.render(WRIST_CAMERA)), "the wrist image did not change"
        # the wrist camera looks along the approach axis (+x of ee_link)
        ee = sim.get_link_pose("ee_link")
        np.testing.assert_allclose(quat_to_mat(wrist1[3:])[:, 2], quat_to_mat(ee[3:])[:, 0], atol=1e-5)
        # rendering does not touch the physics state
        s = world_state(sim)
        sim.render(HEAD_CAMERA)
        _assert_bit_equal(s, world_state(sim), "after render")
    finally:
        sim.close()


def check_timestep(factory: SimFactory) -> None:
    """One step is ``timestep`` seconds: a free-falling ball covers g t^2 / 2."""
    sim = build(factory)
    try:
        z0 = sim.get_object_pose("dropper")[2]
        n = 50
        sim.step(n)
        t = n * sim.timestep
        dz = z0 - sim.get_object_pose("dropper")[2]
        assert abs(dz - 0.5 * 9.81 * t * t) < 0.01, (dz, 0.5 * 9.81 * t * t)
        vz = sim.get_object_velocity("dropper")[2]
        assert abs(vz + 9.81 * t) < 0.02, (vz, -9.81 * t)
    finally:
        sim.close()


def check_object_api(factory: SimFactory) -> None:
    """Teleports, velocities, articulated-object joints and links, kinematic and static bodies."""
    sim = build(factory)
    try:
        sim.step(10)
        assert sim.get_object_velocity("cube").shape == (6,)
        assert sim.get_object_qpos("cube").shape == (0,)
        assert sim.get_object_qpos("lidbox").shape == (1,)
        pose = np.array([0.2, -0.1, 0.9, math.cos(0.3), 0.0, 0.0, math.sin(0.3)])
        sim.set_object_pose("cube", pose)
        np.testing.assert_allclose(sim.get_object_pose("cube"), pose, atol=1e-6)
        np.testing.assert_allclose(sim.get_object_velocity("cube"), np.zeros(6), atol=1e-9)
        sim.step(1)
        assert sim.get_object_velocity("cube")[2] < 0, "a teleported dynamic body falls"
        sim.set_object_qpos("lidbox", [0.8])
        np.testing.assert_allclose(sim.get_object_qpos("lidbox"), [0.8], atol=1e-6)
        root = sim.get_object_pose("lidbox")
        lid = sim.get_object_link_pose("lidbox", "lid")
        # the lid link's frame sits on the hinge, (0, 0.06, 0.03) in the root frame; opening turns it
        # by the joint angle and lifts the lid's centre, (0, -0.06, 0.005) in its frame, above the hinge
        np.testing.assert_allclose(lid[:3], transform_point(root, (0.0, 0.06, 0.03)), atol=1e-5)
        assert abs(quat_angle(lid[3:], root[3:]) - 0.8) < 1e-4, quat_angle(lid[3:], root[3:])
        assert transform_point(lid, (0.0, -0.06, 0.005))[2] > lid[2] + 0.03, lid
        np.testing.assert_allclose(sim.get_object_link_pose("lidbox", "base"), root, atol=1e-6)
        # kinematic bodies stay where code puts them, under gravity
        wand = np.array([0.25, 0.2, 1.0, 1.0, 0.0, 0.0, 0.0])
        sim.set_object_pose("wand", wand)
        sim.step(50)
        np.testing.assert_allclose(sim.get_object_pose("wand"), wand, atol=1e-6)
        np.testing.assert_allclose(sim.get_object_pose("table")[:3], (0.0, 0.0, TABLE_TOP - 0.025), atol=1e-6)
        # the standing cylinder (axis along local x, rotated upright) stays upright on the table
        can = sim.get_object_pose("can")
        assert abs(can[2] - (TABLE_TOP + 0.04)) < 0.003, can
        # the convex mesh rests on the table (height 0.06 with its z scale of 1.5)
        block = sim.get_object_pose("block")
        assert abs(block[2] - (TABLE_TOP + 0.03)) < 0.003, block
    finally:
        sim.close()


def check_render_samples(factory: SimFactory) -> None:
    """Rendering later from samples (optional: a backend whose ``render_sample`` gives None renders
    in the loop): the frames equal those rendered at the time, bit for bit, on a fixed and on a
    mounted camera, with a teleported body and an opened lid among them; taking samples and
    rendering from them leave the world as it was, and the run goes on bit-identically to the same
    run without them."""
    a, b = build(factory), build(factory)
    try:
        if a.render_sample() is None:
            return
        samples: list = []
        frames: dict[str, list] = {HEAD_CAMERA: [], WRIST_CAMERA: []}

        def script(sim, keep: bool) -> None:
            for k in range(6):
                _motion_script(sim, 25, phase=25 * k)
                if k == 2:
                    sim.set_object_pose("cube", (0.1, 0.05, 0.95, math.cos(0.4), 0.0, math.sin(0.4), 0.0))
                    sim.set_object_qpos("lidbox", [0.7])
                for cam in frames:
                    img = sim.render(cam)
                    if keep:
                        frames[cam].append(img)
                if keep:
                    samples.append(sim.render_sample())

        script(a, True)
        script(b, False)
        before = world_state(a)
        for cam, want in frames.items():
            got: list[np.ndarray] = []
            a.render_samples(cam, samples, got.append)
            assert len(got) == len(want)
            for i, (x, y) in enumerate(zip(got, want)):
                assert x.dtype == np.uint8 and np.array_equal(x, y), (
                    f"{cam}: frame {i} rendered from its sample differs from the one rendered then "
                    f"({int(np.count_nonzero(np.any(x != y, axis=-1)))} pixels)")
        _assert_bit_equal(before, world_state(a), "after render_samples")
        _assert_bit_equal(world_state(a), world_state(b), "a run with samples vs without")
        _motion_script(a, 100, phase=150)
        _motion_script(b, 100, phase=150)
        _assert_bit_equal(world_state(a), world_state(b), "stepping after render_samples")
        assert np.array_equal(a.render(HEAD_CAMERA), b.render(HEAD_CAMERA)), "render after render_samples"
    finally:
        a.close()
        b.close()


def _rack(n_collision: int = 20, n_visual_only: int = 30) -> Body:
    """A dynamic plate of many small collision boxes carrying many decorative (visual-only) beads:
    more shapes than some engines take on one link, and more visual than collision shapes."""
    boxes = [Shape(Box((0.006, 0.006, 0.004)), pose=(-0.03 + 0.015 * (i % 5), -0.02 + 0.013 * (i // 5), 0.0,
                                                    1, 0, 0, 0)) for i in range(n_collision)]
    beads = [Shape(Sphere(0.005), pose=(-0.03 + 0.012 * (i % 6), -0.025 + 0.012 * (i // 6), 0.008, 1, 0, 0, 0),
                   material=Material(color=(0.9, 0.8, 0.1, 1)), collision=False) for i in range(n_visual_only)]
    return Body("rack", boxes + beads, pose=(0.05, -0.12, TABLE_TOP + 0.06, 1, 0, 0, 0), mass=0.1)


def check_physics_independent_of_rendering(rendering: SimFactory, physics_only: SimFactory) -> None:
    """The same world built with and without rendering steps bit for bit alike, pictures taken
    along the way included: whether a machine renders never changes a verdict. The scene adds a body
    with more collision and (visual-only) shapes than one engine link may take."""
    scene = make_scene()
    scene.bodies.append(_rack())
    emb = make_embodiment()
    a, b = rendering(), physics_only()
    try:
        a.build(scene, emb)
        b.build(scene, emb)
        for k in range(3):
            _motion_script(a, 80, phase=80 * k)
            _motion_script(b, 80, phase=80 * k)
            for cam in a.camera_names():
                a.render(cam)
            _assert_bit_equal(world_state(a), world_state(b), f"rendering vs physics-only build, step {80 * (k + 1)}")
        # every shape is drawn where its body now is: a fresh world posed like this one looks the same
        elsewhere = make_scene()  # the rack spawned elsewhere, then posed
        elsewhere.bodies.append(_rack())
        elsewhere.bodies[-1].pose = (-0.2, -0.2, TABLE_TOP + 0.1, 0, 1, 0, 0)
        c = rendering()
        try:
            c.build(elsewhere, emb)
            c.set_qpos(a.get_qpos())
            for name in a.object_names():
                c.set_object_pose(name, a.get_object_pose(name))
                if a.get_object_qpos(name).size:
                    c.set_object_qpos(name, a.get_object_qpos(name))
            x, y = a.render(HEAD_CAMERA), c.render(HEAD_CAMERA)
            assert np.count_nonzero(np.any(x != y, axis=-1)) <= 10, (
                f"the moved world and a world posed like it look different "
                f"({int(np.count_nonzero(np.any(x != y, axis=-1)))} pixels)")
        finally:
            c.close()
    finally:
        a.close()
        b.close()


# -- textures -------------------------------------------------------------------------------------

STRIPE_A = (235, 200, 40)  # yellow
STRIPE_B = (40, 70, 210)  # blue
TEXTURE_CAMERA = "texture_cam"
_PANEL_CENTRE = (0.6, 0.4, 0.3)
_PANEL_HALF = (0.2, 0.15, 0.15)


def stripes_png(workdir: str | Path | None = None) -> Path:
    """A 64 x 64 RGB PNG of diagonal stripes, 8 pixels wide, alternating :data:`STRIPE_A` and
    :data:`STRIPE_B` (seamless when repeated)."""
    from PIL import Image

    path = assets_dir(workdir) / "stripes.png"
    if not path.exists():
        y, x = np.mgrid[0:64, 0:64]
        m = ((x + y) // 8) % 2
        img = np.where(m[..., None] == 0, np.array(STRIPE_A, np.uint8), np.array(STRIPE_B, np.uint8))
        tmp = path.with_suffix(".tmp.png")
        Image.fromarray(img.astype(np.uint8)).save(tmp)
        tmp.replace(path)
    return path


def texture_scene(texture: str | None) -> SceneSpec:
    """A static box (the panel: its top and its front face, normal -y, in view of
    :data:`TEXTURE_CAMERA`); a sphere, a cylinder and a capsule dropped onto the back of its top (out
    of the sampled middle of the faces) and a plain cube among them. The panel and the three round
    bodies wear ``texture`` over a grey colour (None: plain grey)."""
    grey = Material(color=(0.5, 0.5, 0.5, 1.0), texture=texture)
    cx, cy, cz = _PANEL_CENTRE
    top = cz + _PANEL_HALF[2]
    along_y = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))  # local x (the axis) -> world y
    bodies = [
        Body("panel", [Shape(Box(_PANEL_HALF), material=grey)], pose=(*_PANEL_CENTRE, 1, 0, 0, 0), kind="static"),
        Body("t_ball", [Shape(Sphere(0.03), material=grey)], pose=(cx + 0.16, cy + 0.115, top + 0.04, 1, 0, 0, 0)),
        Body("t_roll", [Shape(Cylinder(0.02, 0.03), material=grey)], pose=(cx - 0.16, cy + 0.115, top + 0.03)
             + along_y),
        Body("t_pill", [Shape(Capsule(0.02, 0.04), material=grey)], pose=(cx - 0.05, cy + 0.125, top + 0.03,
                                                                           1, 0, 0, 0)),
        Body("cube", [Shape(Box((0.02, 0.02, 0.02)), material=Material(color=(0.9, 0.1, 0.1, 1)))],
             pose=(cx + 0.07, cy + 0.12, top + 0.03, 1, 0, 0, 0), mass=CUBE_MASS),
    ]
    cam = CameraSpec(TEXTURE_CAMERA, width=320, height=240, fovy_deg=45.0,
                     pose=tuple(look_at_cv((cx, cy - 0.85, cz + 0.55), (cx, cy, cz))))
    return SceneSpec(bodies=bodies, cameras=[cam], timestep=TIMESTEP)


def _face_pixels(sim: Simulator, image: np.ndarray, face: str) -> np.ndarray:
    """The pixels (n x 3) at a 16 x 16 grid of points over the middle 60% of a face of the panel
    (``top`` or ``front``), projected with the simulator's camera pose and intrinsics."""
    cx, cy, cz = _PANEL_CENTRE
    hx, hy, hz = _PANEL_HALF
    s = np.linspace(-0.6, 0.6, 16)
    a, b = np.meshgrid(s, s)
    if face == "top":
        pts = np.stack([cx + a.ravel() * hx, cy + b.ravel() * hy, np.full(a.size, cz + hz)], axis=1)
    else:
        pts = np.stack([cx + a.ravel() * hx, np.full(a.size, cy - hy), cz + b.ravel() * hz], axis=1)
    cam = sim.camera_pose(TEXTURE_CAMERA)
    K = sim.camera_intrinsics(TEXTURE_CAMERA)
    out = []
    for p in pts:
        q = transform_point(pose_inv(cam), p)
        u, v = (K @ q)[:2] / q[2]
        assert q[2] > 0 and 0 <= u < image.shape[1] and 0 <= v < image.shape[0], f"{face} face out of view"
        out.append(image[int(v), int(u)])
    return np.asarray(out, float)


def _stripe_share(px: np.ndarray) -> tuple[float, float]:
    """Shares of pixels of the yellow and of the blue stripe, told by hue (light scales them)."""
    r, g, b = px[:, 0], px[:, 1], px[:, 2]
    yellow = (r > b + 50) & (g > b + 30)
    blue = b > r + 50
    return float(np.mean(yellow)), float(np.mean(blue))


def check_textures(factory: SimFactory) -> None:
    """``Material.texture`` on primitives: a box wearing a high-contrast stripes image shows the
    stripes on its top and on its side (a face normal to y: an engine that projects the image along
    one axis streaks it there), in both stripe colours, where the plain grey box is uniform; the
    textured sphere, cylinder and capsule render; a world with textures steps bit for bit like the
    same world without (textures are visual only); a missing or unreadable texture file is a
    SimulatorError naming the file, at build."""
    png = stripes_png()
    emb = make_embodiment()
    a, b = factory(), factory()
    try:
        a.build(texture_scene(str(png)), emb)
        b.build(texture_scene(None), emb)
        ia, ib = a.render(TEXTURE_CAMERA), b.render(TEXTURE_CAMERA)
        for face in ("top", "front"):
            pa, pb = _face_pixels(a, ia, face), _face_pixels(b, ib, face)
            sa, sb = float(pa.std(axis=0).mean()), float(pb.std(axis=0).mean())
            assert sb < 15.0, f"{face} face of the plain box is not uniform (std {sb:.1f})"
            assert sa > 30.0 and sa > 3 * sb, (
                f"{face} face of the textured box shows no pattern (std {sa:.1f}, plain box {sb:.1f})")
            ya, ba = _stripe_share(pa)
            assert ya > 0.15 and ba > 0.15, (
                f"{face} face of the textured box lacks a stripe colour (yellow {ya:.2f}, blue {ba:.2f} of "
                f"its pixels)")
            assert _stripe_share(pb) == (0.0, 0.0), f"{face} face of the plain box shows stripe colours"
        _assert_bit_equal(world_state(a), world_state(b), "textured vs plain world, built")
        for k in range(3):
            _motion_script(a, 80, phase=80 * k)
            _motion_script(b, 80, phase=80 * k)
            ra, rb = a.render(TEXTURE_CAMERA), b.render(TEXTURE_CAMERA)
            assert ra.std() > 2.0 and rb.std() > 2.0
            _assert_bit_equal(world_state(a), world_state(b), f"textured vs plain world, step {80 * (k + 1)}")
        ball = a.get_object_pose("t_ball")
        assert ball[2] < _PANEL_CENTRE[2] + _PANEL_HALF[2] + 0.035, f"the textured ball did not land: {ball}"
    finally:
        a.close()
        b.close()
    bad = assets_dir() / "not-an-image.png"
    bad.write_bytes(b"this is not a PNG file")
    for path in (assets_dir() / "missing-texture.png", bad):
        sim = factory()
        try:
            try:
                sim.build(texture_scene(str(path)), emb)
            except SimulatorError as e:
                assert str(path) in str(e), f"the error does not name the texture file {path}: {e}"
            else:
                raise AssertionError(f"a build with texture file {path.name} did not raise SimulatorError")
        finally:
            sim.close()



CHECKS: list[Callable[[SimFactory], object]] = [  # a check raises, or returns None or its figures
    check_build_and_names,
    check_seeded_reset_identical,
    check_sequential_builds_identical,
    check_snapshot_restore_exact,
    check_snapshot_portable,
    check_bad_commands,
    check_drive_tracking,
    check_contacts,
    check_cameras,
    check_timestep,
    check_object_api,
    check_render_samples,
    check_textures,
    check_appearance,
]


# Checks that render images; the others also run on a physics-only build.
NEEDS_RENDERER: tuple[Callable[[SimFactory], None], ...] = (check_seeded_reset_identical,
                                                            check_sequential_builds_identical, check_cameras,
                                                            check_render_samples, check_textures,
                                                            check_appearance)


def check_id(check: Callable) -> str:
    return check.__name__.removeprefix("check_")


def render_diagnosis(factory: SimFactory) -> str | None:
    """None if ``factory``'s simulator renders on this machine, else its RendererUnavailable
    diagnosis (run the checks of :data:`NEEDS_RENDERER` only where this is None)."""
    sim = factory()
    try:
        sim.build(SceneSpec(), make_embodiment())
    except RendererUnavailable as e:
        return str(e)
    finally:
        sim.close()
    return None


def run_all(factory: SimFactory) -> dict[str, str]:
    """Run every check outside pytest; returns ``{check: "ok" | error text}``."""
    out: dict[str, str] = {}
    for check in CHECKS:
        try:
            check(factory)
            out[check_id(check)] = "ok"
        except Exception as e:  # noqa: BLE001 (a report, not control flow)
            out[check_id(check)] = f"{type(e).__name__}: {e}"
    return out

# far-away bodies change nothing: cab_core.testing.isolation_conformance on this module's world


def check_isolation(factory: SimFactory) -> dict:
    """The world's bodies move alike with and without far-away extra bodies (1 mm, 0.57 deg)."""
    return _isolation.check_isolation(factory, _isolation.isolation_scene(make_scene(), TABLE_TOP), make_embodiment(),
                                      lambda sim, n, start: _motion_script(sim, n, phase=start))


CHECKS.append(check_isolation)
