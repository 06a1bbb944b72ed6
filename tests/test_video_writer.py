"""The attempt's video writer starts its encoder (ffmpeg) with the first frame: an attempt waiting on its
model keeps no ffmpeg process, and the video is still written completely."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from cab_core.attempt.records.writer import VideoWriter
from cab_core.sweep.memory import descendants


def _ffmpegs() -> list[int]:
    """ffmpeg processes below this one."""
    out = []
    for pid in descendants(os.getpid())[1:]:
        try:
            if "ffmpeg" in Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace"):
                out.append(pid)
        except OSError:
            continue
    return out


def _decoded(path: Path) -> list[np.ndarray]:
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path))
    w, h = next(gen)["size"]
    return [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen]


def _frames(n: int) -> list[np.ndarray]:
    return [np.full((48, 64, 3), 40 * i, dtype=np.uint8) for i in range(n)]


def test_the_encoder_starts_with_the_first_frame_and_the_file_is_complete(tmp_path):
    v = VideoWriter(tmp_path / "video.mp4", 10.0, (64, 48))
    assert not v.started and _ffmpegs() == [] and not v.part.exists()
    frames = _frames(5)
    v.add(frames[0])
    assert v.started and len(_ffmpegs()) == 1
    for f in frames[1:]:
        v.add(f)
    v.close()
    assert v.closed and v.frames == 5 and not v.part.exists() and _ffmpegs() == []
    decoded = _decoded(tmp_path / "video.mp4")
    assert len(decoded) == 5
    assert [round(float(np.median(d)) / 40) for d in decoded] == [0, 1, 2, 3, 4]  # the frames, in order
    v.close()  # idempotent
    with pytest.raises(ValueError, match="video.mp4 is closed"):
        v.add(frames[0])


def test_a_writer_closed_without_frames_writes_what_an_encoder_given_none_writes(tmp_path):
    v = VideoWriter(tmp_path / "video.mp4", 10.0, (64, 48))
    v.close()
    assert v.closed and v.frames == 0 and (tmp_path / "video.mp4").exists() and _ffmpegs() == []


@pytest.mark.sim
def test_no_ffmpeg_runs_while_an_attempt_waits_and_its_video_is_complete(tmp_path):
    """An attempt whose frames are rendered from state samples after it: no encoder during its calls
    (the time it waits on its model), every sampled frame in ``video.mp4`` at the end."""
    pytest.importorskip("mujoco")
    from cab_core.attempt.engine.episode import Episode
    from cab_core.attempt.spec import AttemptSpec
    from cab_core.plugins import all_tasks, create, task_info

    task = "click_bell"
    spec = AttemptSpec(task=task, seed=task_info(task).seed, attempt=1, sim="mujoco", embodiment="aloha_agilex",
                       planner="pin", harness="direct", model="scripted", output_dir=tmp_path,
                       budget_tool_calls=100, budget_sim_seconds=100.0, budget_wall_seconds=1e4,
                       record={"video": True, "video_every_steps": 25, "video_size": [160, 120]})
    ep = Episode(spec, all_tasks()[task], create("simulators", "mujoco", {"name": "mujoco"}),
                 create("planners", "pin", {}), create("embodiments", "aloha_agilex", {}))
    try:
        assert ep.recorder.video is not None and not ep.recorder.video.started and _ffmpegs() == []
        for name, args in [("move_delta", {"arm": "left", "dx": 0.0, "dy": 0.0, "dz": 0.03}),
                           ("set_gripper", {"arm": "left", "pos": 0.5})]:
            assert "error" not in ep.call(name, args).payload
            assert _ffmpegs() == [] and not ep.recorder.video.started  # between calls: waiting on the model
        samples = len(ep._video_samples or [])
        assert samples > 2
        result = ep.finish()
    finally:
        ep.close()
    assert result["video"]["frames"] == samples and result["video"]["file"] == "video.mp4"
    assert len(_decoded(tmp_path / "video.mp4")) == samples and _ffmpegs() == []
