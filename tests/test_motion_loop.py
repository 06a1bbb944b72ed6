"""The motion loop kept close to raw physics (cab-bench's motion/raw-physics ratio) without changing
what an attempt does: the video rendered after the attempt from state samples is the video rendered
in the loop, frame for frame; taking samples changes no physics; trajectories stream the same
targets; latch polling answers as the verifier's evaluate; the faster geometry helpers give the same
numbers. Speed itself is measured by ``cab-bench``, never here."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cab_core import geometry
from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.engine.episode import Episode, VerdictTracker
from cab_core.attempt.records import writer as recording
from cab_core.attempt.runner import attempt_spec, run_attempt
from cab_core.attempt.spec import AttemptSpec
from cab_core.plugins import all_tasks, create
from cab_core.tools import motion
from cab_core.tools.context import ObservationStore, RobotContext
from cab_suite_codeaction.catalog import task_info

SIMS = ["mujoco", "pybullet", "sapien"]


# ==============================================================================================
# geometry: the same numbers as the plain numpy formulation
# ==============================================================================================
def _normalize_reference(q):
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError("degenerate")
    return q / n


def _mat_reference(q):
    w, x, y, z = _normalize_reference(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def test_quaternion_helpers_give_the_numbers_of_the_numpy_formulation():
    rng = np.random.default_rng(7)
    for i in range(20000):
        m = rng.normal(size=(4, 7)) * 10 ** rng.uniform(-4, 3, size=(4, 7))
        q = m[:, i % 7] if i % 2 else m[0, 3:7]  # strided columns and contiguous slices
        if i % 5 == 0:
            q = q.astype(np.float32)
        assert np.array_equal(geometry.quat_normalize(q), _normalize_reference(q))
        assert np.array_equal(geometry.quat_to_mat(q), _mat_reference(q))
        pose, p = m[1], m[2, :3]
        want = _mat_reference(pose[3:7]) @ p + pose[:3]
        assert np.array_equal(geometry.transform_point(pose, p), want)
    for bad in ([0.0, 0.0, 0.0, 0.0], [np.nan, 1.0, 0.0, 0.0], [np.inf, 0.0, 0.0, 0.0]):
        with pytest.raises(ValueError, match="degenerate quaternion"):
            geometry.quat_normalize(bad)


# ==============================================================================================
# trajectory streaming: the same targets, step by step, as the per-step formulation
# ==============================================================================================
JOINTS = ["l1", "l2", "l3", "lg", "r1", "r2", "r3", "rg"]


class _LagSim:
    """Joints follow their targets with a lag; records every target handed over."""
    timestep = 0.004

    def __init__(self):
        self.joint_names = list(JOINTS)
        self.t = np.linspace(0.1, 0.8, len(JOINTS))
        self.q = self.t.copy()
        self.v = np.zeros(len(JOINTS))
        self.log: list[tuple[np.ndarray, np.ndarray]] = []

    def get_drive_targets(self):
        return self.t.copy()

    def set_drive_targets(self, t, v=None):
        self.t = np.array(t, float)
        self.log.append((self.t.copy(), np.zeros(len(t)) if v is None else np.array(v, float)))

    def step(self, n=1):
        for _ in range(n):
            dq = 0.3 * (self.t - self.q)
            self.q = self.q + dq
            self.v = dq / self.timestep

    def get_qpos(self):
        return self.q.copy()

    def get_qvel(self):
        return self.v.copy()


class _Clock:
    def __init__(self, sim):
        self.sim, self.steps = sim, 0

    def step(self, n=1):
        for _ in range(n):
            self.sim.step(1)
            self.steps += 1


def _ctx(sim):
    emb = SimpleNamespace(arms={"left": SimpleNamespace(joints=["l1", "l2", "l3"]),
                                "right": SimpleNamespace(joints=["r1", "r2", "r3"])})
    return RobotContext(sim, None, emb, _Clock(sim), ObservationStore())  # type: ignore[arg-type]


def _execute_reference(ctx, trajs, settle=True):
    """motion._execute as it was written before the rows were laid out ahead of the loop."""
    def set_arm_targets(targets, velocities=None):
        t = ctx.sim.get_drive_targets().copy()
        v = np.zeros_like(t)
        for arm, q in targets.items():
            idx = [ctx.sim.joint_names.index(j) for j in ctx.arm(arm).joints]
            t[idx] = q
            if velocities is not None:
                v[idx] = velocities[arm]
        ctx.sim.set_drive_targets(t, v)

    n = max((len(v) for v in trajs.values()), default=0)
    steps0, dt = ctx.clock.steps, ctx.sim.timestep
    vel = {a: np.vstack([np.diff(tr, axis=0) / dt, np.zeros((1, tr.shape[1]))]) if len(tr) > 1 else np.zeros_like(tr)
           for a, tr in trajs.items()}
    for i in range(n):
        set_arm_targets({a: tr[min(i, len(tr) - 1)] for a, tr in trajs.items()},
                        {a: (vel[a][i] if i < len(vel[a]) else np.zeros(vel[a].shape[1])) for a in trajs})
        ctx.clock.step(1)
    if trajs:
        set_arm_targets({a: tr[-1] for a, tr in trajs.items()})
    if settle and trajs:
        final = {a: tr[-1] for a, tr in trajs.items()}
        for _ in range(motion.SETTLE_MAX_STEPS):
            err = max(float(np.max(np.abs(ctx.arm_qpos(a) - q))) for a, q in final.items())
            v = float(np.max(np.abs(ctx.sim.get_qvel())))
            if err < 2e-3 and v < 0.05:
                break
            ctx.clock.step(1)
    if ctx.clock.steps > steps0:
        ctx.tick += 1
    return ctx.clock.steps - steps0


@pytest.mark.parametrize("lengths", [{"left": 37}, {"left": 30, "right": 52}, {"right": 1}, {"left": 2, "right": 9}, {}])
def test_execute_streams_the_targets_of_the_per_step_formulation(lengths):
    rng = np.random.default_rng(len(lengths) * 100 + sum(lengths.values()))
    trajs = {a: np.cumsum(rng.normal(0, 0.01, size=(n, 3)), axis=0) + 0.2 for a, n in lengths.items()}
    a, b = _LagSim(), _LagSim()
    ca, cb = _ctx(a), _ctx(b)
    steps = motion._execute(ca, trajs)
    assert steps == _execute_reference(cb, trajs)
    assert ca.tick == cb.tick and ca.clock.steps == cb.clock.steps
    assert len(a.log) == len(b.log)
    for (ta, va), (tb, vb) in zip(a.log, b.log):
        assert np.array_equal(ta, tb) and np.array_equal(va, vb)
    assert np.array_equal(a.q, b.q)


def test_arm_and_finger_readings_follow_the_joint_order():
    sim = _LagSim()
    ctx = _ctx(sim)
    assert np.array_equal(ctx.arm_qpos("right"), sim.q[[4, 5, 6]])
    assert np.array_equal(ctx.joint_indices(["rg", "l1"]), [7, 0])


# ==============================================================================================
# attempts: video from state samples == video rendered in the loop; samples change no physics
# ==============================================================================================
SCRIPT = [("move_delta", {"arm": "left", "dx": 0.0, "dy": 0.06, "dz": -0.03}),
          ("set_gripper", {"arm": "left", "pos": 0.4}),
          ("move_both_delta", {"left_delta": [0.02, -0.03, 0.0], "right_delta": [-0.03, 0.02, -0.04]}),
          ("capture_head", {}),
          ("move_delta", {"arm": "right", "dx": 0.0, "dy": -0.05, "dz": 0.03})]


def _attempt(sim_name: str, out: Path, video: str, monkeypatch) -> dict:
    """One scripted attempt; ``video``: 'samples' (the default path), 'loop' (the simulator made to
    refuse samples) or 'off'. Returns the raw frames handed to the encoder, the end state and the
    result."""
    frames: list[np.ndarray] = []
    add = recording.VideoWriter.add

    def keep(self, frame):
        frames.append(np.array(frame, dtype=np.uint8, copy=True))
        add(self, frame)

    with monkeypatch.context() as m:
        m.setattr(recording.VideoWriter, "add", keep)
        return _scripted(sim_name, out, video, frames)


def _scripted(sim_name: str, out: Path, video: str, frames: list) -> dict:
    task = "beat_block_hammer"
    spec = AttemptSpec(task=task, seed=task_info(task).seed, attempt=1, sim=sim_name, embodiment="aloha_agilex",
                       planner="pin", harness="direct", model="scripted", output_dir=out,
                       budget_tool_calls=100, budget_sim_seconds=100.0, budget_wall_seconds=1e4,
                       record={"video": video != "off", "video_every_steps": 25, "video_size": [160, 120]})
    sim = create("simulators", sim_name, {"name": sim_name})
    if video == "loop":
        sim.render_sample = lambda: None
    ep = Episode(spec, all_tasks()[task], sim, create("planners", "pin", {}), create("embodiments", "aloha_agilex", {}))
    try:
        payloads = [ep.call(name, args).payload for name, args in SCRIPT]
        for p in payloads:
            assert "error" not in p, p
        res = ep.finish()
        state = {n: ep.sim.get_object_pose(n) for n in ep.sim.object_names()}
        state["robot_qpos"], state["robot_qvel"] = ep.sim.get_qpos(), ep.sim.get_qvel()
    finally:
        ep.close()
    return {"frames": frames, "state": state, "result": res,
            "snapshots": (out / "privileged" / "snapshots.jsonl").read_text()}


def _decoded(path: Path) -> list[np.ndarray]:
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path))
    meta = gen.__next__()
    w, h = meta["size"]
    return [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen]


@pytest.mark.sim
@pytest.mark.parametrize("sim_name", SIMS)
def test_the_video_from_state_samples_is_the_video_rendered_in_the_loop(sim_name, tmp_path, monkeypatch):
    later = _attempt(sim_name, tmp_path / "samples", "samples", monkeypatch)
    loop = _attempt(sim_name, tmp_path / "loop", "loop", monkeypatch)
    off = _attempt(sim_name, tmp_path / "off", "off", monkeypatch)
    assert later["result"]["video"]["rendered"] == "after the attempt"
    assert loop["result"]["video"]["rendered"] == "in the loop"
    assert off["result"]["video"] is None and not off["frames"]
    # the frames handed to the encoder: the same, bit for bit, one every 25 steps plus the first
    steps = later["result"]["budget"]["physics_steps"]
    assert len(later["frames"]) == len(loop["frames"]) == steps // 25 + 1 == later["result"]["video"]["frames"]
    for i, (a, b) in enumerate(zip(later["frames"], loop["frames"])):
        assert a.shape == (120, 160, 3) and np.array_equal(a, b), f"frame {i} differs"
    assert later["frames"][0].std() > 2.0 and not np.array_equal(later["frames"][0], later["frames"][-1])
    # the encoded videos decode to the same pictures
    da, db = _decoded(tmp_path / "samples" / "video.mp4"), _decoded(tmp_path / "loop" / "video.mp4")
    assert len(da) == len(db) == len(later["frames"])
    assert all(np.array_equal(a, b) for a, b in zip(da, db))
    # and the video changes no physics: the same end state and snapshots with it (either way) or without
    for other in (loop, off):
        assert other["state"].keys() == later["state"].keys()
        for k, v in later["state"].items():
            assert np.array_equal(v, other["state"][k]), k
        assert other["snapshots"] == later["snapshots"]
        assert other["result"]["verdict"] == later["result"]["verdict"]


# ==============================================================================================
# latch polling: Verifier.holds answers as evaluate().success at every step of oracle attempts
# ==============================================================================================
@pytest.mark.sim
@pytest.mark.parametrize("task", ["beat_block_hammer", "click_bell", "press_stapler", "dump_bin_bigbin"])
def test_latch_polling_answers_as_evaluate(task, tmp_path, monkeypatch):
    from hydra import compose, initialize_config_module

    seen = {True: 0, False: 0}
    poll = VerdictTracker.poll

    def checked(self, step):
        h = self.v.holds(self.w)
        assert h == self.v.evaluate(self.w).success, f"step {step}: holds {h}"
        seen[h] += 1
        poll(self, step)

    monkeypatch.setattr(VerdictTracker, "poll", checked)
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(
            ["+sim=mujoco", "+model=oracle", f"task={task}", "record.video=false"]))
    res = run_attempt(attempt_spec(cfg, tmp_path / "a"))
    assert res["verdict"]["success"] is True, res["verdict"]
    assert seen[True] > 0 and seen[False] > 100, seen
