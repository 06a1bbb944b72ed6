"""``cab-bench``: wall-time figures of the robot API on this machine, beside the raw simulator
figures of the same scene, so the host's overhead reads as a ratio.

Targets (2-core CPU): non-image, non-motion tools p50 <= 5 ms; capture_head p50 <= 60 ms;
motion at least 3x faster than real time, and its wall time per simulated second at most 2x that
of raw physics with the arms moving (recording on: the video is rendered from state samples after
the attempt, reported beside it); reset <= 3 s.
"""
from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from cab_core.apps.bench_startup import print_startup, startup
from cab_core.attempt.engine.episode import Episode
from cab_core.attempt.spec import AttemptSpec
from cab_core.config import default_selection
from cab_core.plugins import task_info

NON_IMAGE = [
    ("get_embodiment", {}),
    ("get_camera_info", {"camera": "head_camera"}),
    ("get_arm_pose", {"arm": "left"}),
    ("get_gripper_state", {"arm": "right"}),
    ("get_robot_state", {}),
    ("get_grasp_contact", {"arm": "left"}),
    ("project", None),
    ("ray", None),
    ("plane_intersect", None),
    ("grasp_quat_candidates", {"approach_axis_world": [0, 0, -1], "opening_axis_world": [1, 0, 0]}),
    ("scale_from_object_size", None),
    ("check_tcp_pose_reachability", {"arm": "left", "target_xyz": [-0.2, 0.0, 0.9]}),
]


def _pct(xs: list[float], p: float) -> float:
    return float(np.percentile(np.asarray(xs), p)) if xs else float("nan")


def _open_episodes(task: str, sim_name: str, out_dir: Path) -> tuple[Episode, list[float]]:
    """Three attempts opened one after the other (the first two closed): the third, still open, and the
    wall time of each opening."""
    info = task_info(task)
    d = default_selection(("embodiment", "planner"))
    resets = []
    for i in range(3):
        spec = AttemptSpec(task=task, seed=info.seed, attempt=i + 1, sim=sim_name, embodiment=d["embodiment"],
                           planner=d["planner"], harness="direct", model="bench", output_dir=out_dir / f"attempt-{i + 1}",
                           budget_tool_calls=100000, budget_sim_seconds=1e6, budget_wall_seconds=1e6,
                           sim_cfg={"name": sim_name})
        t0 = time.perf_counter()
        ep = Episode.open(spec)
        resets.append(time.perf_counter() - t0)
        if i < 2:
            ep.close()
    return ep, resets


def _timed_calls(ep: Episode, name: str, args: dict | None, n: int) -> dict:
    """p50 and p95 wall time (ms) of ``n`` calls of tool ``name``; a call answered with an error raises."""
    xs = []
    for _ in range(n):
        t0 = time.perf_counter()
        r = ep.call(name, args)
        xs.append(time.perf_counter() - t0)
        if "error" in r.payload:
            raise RuntimeError(f"{name}: {r.payload['error']}")
    return {"p50_ms": 1e3 * _pct(xs, 50), "p95_ms": 1e3 * _pct(xs, 95), "n": n}


def _tool_figures(ep: Episode, n: int) -> dict[str, dict]:
    """The non-image tools' figures (those that need an observation given the head camera's), then capture_head's."""
    obs = ep.call("capture_head").payload["obs_id"]
    dyn = {
        "project": {"obs_id": obs, "xyz": [0.0, 0.0, 0.75]},
        "ray": {"obs_id": obs, "px": [320, 300]},
        "plane_intersect": {"obs_id": obs, "px": [320, 300], "plane_point_xyz": [0, 0, 0.74],
                            "plane_normal_xyz": [0, 0, 1], "plane_offset_sigma_m": 0.005},
        "scale_from_object_size": {"obs_id": obs, "bbox": [300, 280, 340, 320], "extent_axis": "width",
                                   "known_extent_m": 0.05},
    }
    figures = {name: _timed_calls(ep, name, dyn.get(name, args), n) for name, args in NON_IMAGE}
    figures["capture_head"] = _timed_calls(ep, "capture_head", None, n)
    return figures


def _motion_figures(ep: Episode) -> dict:
    """Six 8 cm moves of the left arm, back and forth: wall time per simulated second and real-time factor."""
    wall = 0.0
    sim_s = 0.0
    for k in range(6):
        d = 0.08 if k % 2 == 0 else -0.08
        t0 = time.perf_counter()
        r = ep.call("move_delta", {"arm": "left", "dx": 0.0, "dy": d, "dz": 0.0})
        wall += time.perf_counter() - t0
        sim_s += r.payload["execution"]["physics_steps"] * ep.sim.timestep
    return {"wall_s_per_sim_s": wall / max(sim_s, 1e-9), "realtime_factor": sim_s / max(wall, 1e-9), "sim_s": sim_s}


def _raw_figures(ep: Episode, n: int) -> tuple[dict, float]:
    """The simulator's own figures on the same scene, without the API: physics with the arms moving (targets
    streamed straight to the simulator, 1000 steps) and the head camera's render; and the wall seconds of
    one raw physics step."""
    sim = ep.sim
    dt = sim.timestep
    base = sim.get_drive_targets().copy()
    t0 = time.perf_counter()
    for i in range(1000):
        sim.set_drive_targets(base + 0.1 * np.sin(2 * np.pi * i * dt))
        sim.step(1)
    raw_step = (time.perf_counter() - t0) / 1000
    rs = []
    for _ in range(n):
        t0 = time.perf_counter()
        sim.render("head_camera")
        rs.append(time.perf_counter() - t0)
    raw = {"step_rate_hz": 1.0 / raw_step, "realtime_factor_physics_only": (1.0 / raw_step) * dt,
           "render_head_p50_ms": 1e3 * _pct(rs, 50)}
    return raw, raw_step


def run(task: str, sim_name: str, n: int, out_dir: Path) -> dict:
    ep, resets = _open_episodes(task, sim_name, out_dir)
    dt = ep.sim.timestep
    figures = _tool_figures(ep, n)
    motion = _motion_figures(ep)
    raw, raw_step = _raw_figures(ep, n)
    versions = ep.versions()
    video = ep.finish_video().get("video") or {}  # the attempt's video: rendered now, from the motion's samples
    ep.close()
    if video.get("render_seconds") is not None:
        motion["video_after_attempt_s_per_sim_s"] = video["render_seconds"] / max(motion["sim_s"], 1e-9)
    non_image_p50 = [v["p50_ms"] for k, v in figures.items() if k not in ("capture_head", "check_tcp_pose_reachability")]
    return {
        "task": task, "sim": sim_name, "n": n, "tools": figures,
        "reset_s": {"p50": statistics.median(resets), "all": resets},
        "motion": motion, "raw": raw,
        "ratios": {"capture_head_over_raw_render": figures["capture_head"]["p50_ms"] / raw["render_head_p50_ms"],
                   "motion_wall_per_sim_s_over_raw_physics": motion["wall_s_per_sim_s"] / (raw_step / dt)},
        "targets": {
            "non_image_tools_p50_le_5ms": max(non_image_p50) <= 5.0,
            "capture_head_p50_le_60ms": figures["capture_head"]["p50_ms"] <= 60.0,
            "motion_ge_3x_realtime": motion["realtime_factor"] >= 3.0,
            "motion_le_2x_raw_physics": motion["wall_s_per_sim_s"] / (raw_step / dt) <= 2.0,
            "reset_le_3s": statistics.median(resets) <= 3.0,
        },
        "versions": versions,
    }


def main() -> None:
    ap = argparse.ArgumentParser(prog="cab-bench", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default=None, help="task (default: the default configuration's)")
    ap.add_argument("--sim", default=None, help="simulator(s) (default: the default configuration's)")
    ap.add_argument("-n", type=int, default=30, help="repetitions per tool")
    ap.add_argument("--out", default=None, help="JSON file to write (default: outputs/bench/<time>.json)")
    ap.add_argument("--startup", action="store_true",
                    help="only the start-up of an attempt on each simulator of --sim (comma-separated): cold "
                         "process, warm cache, warm worker (cab_core.apps.bench_startup)")
    a = ap.parse_args()
    if a.sim is None or a.task is None:
        chosen = default_selection(("sim", "task"))
        a.sim, a.task = a.sim or chosen["sim"], a.task or chosen["task"]
    out = Path(a.out) if a.out else Path("outputs") / "bench" / f"{time.strftime('%Y-%m-%d_%H-%M-%S')}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    if a.startup:
        task = a.task
        res = startup([s.strip() for s in a.sim.split(",") if s.strip()], task)
        print_startup(res, task)
        out.write_text(json.dumps({"startup": res, "task": task}, indent=2))
        print(f"wrote {out}")
        return
    with tempfile.TemporaryDirectory() as td:
        res = run(a.task, a.sim, a.n, Path(td))
    print(f"cab-bench: {res['task']} on {res['sim']} ({res['versions']['simulator']})")
    print(f"{'tool':<30}{'p50 ms':>10}{'p95 ms':>10}")
    for k, v in res["tools"].items():
        print(f"{k:<30}{v['p50_ms']:>10.2f}{v['p95_ms']:>10.2f}")
    print(f"{'reset (s, p50 of 3)':<30}{res['reset_s']['p50']:>10.2f}")
    m, r = res["motion"], res["raw"]
    print(f"{'motion wall s per sim s':<30}{m['wall_s_per_sim_s']:>10.3f}   ({m['realtime_factor']:.1f}x real time)")
    if "video_after_attempt_s_per_sim_s" in m:
        print(f"{'video after attempt s per sim s':<30}{m['video_after_attempt_s_per_sim_s']:>10.3f}   (rendered from state samples)")
    print(f"{'raw step rate, arms moving (Hz)':<30}{r['step_rate_hz']:>10.0f}   ({r['realtime_factor_physics_only']:.1f}x real time)")
    print(f"{'raw head render p50 (ms)':<30}{r['render_head_p50_ms']:>10.2f}")
    for k, v in res["ratios"].items():
        print(f"{'ratio ' + k:<60}{v:>8.2f}")
    for k, v in res["targets"].items():
        print(f"target {k}: {'met' if v else 'MISSED'}")
    out.write_text(json.dumps(res, indent=2, default=str))
    print(f"wrote {out}")
