"""The attempt record: one directory per attempt, written as the attempt goes.

    events.jsonl          append-only: every call, its arguments, the result the agent saw, timings
    observations/         every image the agent was shown (obs_NNNN.png)
    programs/             every run_code submission (prog_NNN.py)
    video.mp4             head-view video in simulated time (separate recording camera); complete
                          when present (video.partial.mp4 while it is encoded)
    privileged/           host-only: scene info and state snapshots (never shown to the agent)
    result.json           written atomically at the end: once the verdict is recorded (``video``
                          null while the video is still to be rendered), and again, atomically,
                          with the video listed

Paths inside records are relative to the attempt directory; no machine path is stored.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from cab_core.attempt.records.observers import Observers
from cab_core.attempt.records.result_format import RECORD_VERSION, dumps, write_json_atomic  # noqa: F401  (re-exported)
from cab_core.errors import ConfigError


class VideoWriter:
    """H.264 MP4 through imageio-ffmpeg, frames pushed as they are rendered. The frames go to
    ``<stem>.partial.mp4`` until :meth:`close`, which renames it to ``path``: a video file under its
    own name is always complete (a process that dies while rendering leaves only the partial one).

    The encoder (an ``ffmpeg`` process, about 16 MiB) starts with the first frame, not when the
    writer is made: an attempt whose frames are rendered after it (from state samples) does not keep
    one running while it waits on its model. A writer closed without a frame starts it then, so the
    file is what an encoder given no frame writes."""

    def __init__(self, path: Path, fps: float, size_wh: tuple[int, int]):
        import imageio_ffmpeg

        self.path = path
        self.part = path.with_suffix(".partial" + path.suffix)
        self.frames = 0
        self.closed = False
        self._write_frames = imageio_ffmpeg.write_frames
        self._fps = fps
        self._size = size_wh
        self._gen: Any = None
        self._ended = False  # close() has run (``closed``: and the file is complete under its name)

    @property
    def started(self) -> bool:
        """Whether the encoder process has been started (by the first frame, or by :meth:`close`)."""
        return self._gen is not None or self._ended

    def _start(self) -> Any:
        if self._gen is None:
            self._gen = self._write_frames(str(self.part), self._size, fps=self._fps, codec="libx264",
                                           quality=None, bitrate=None, macro_block_size=8,
                                           output_params=["-crf", "23", "-preset", "veryfast"],
                                           ffmpeg_log_level="error")
            self._gen.send(None)
        return self._gen

    def add(self, frame: np.ndarray) -> None:
        if self._ended:
            raise ValueError(f"{self.path.name} is closed")
        self._start().send(np.ascontiguousarray(frame, dtype=np.uint8))
        self.frames += 1

    def close(self) -> None:
        """Finish the file and give it its name (idempotent; after a failure, a no-op)."""
        if self._ended:
            return
        try:
            self._start().close()
        finally:
            self._gen = None
            self._ended = True
        self.part.replace(self.path)
        self.closed = True


class Recorder:
    """Writes one attempt's record. ``observers`` (:class:`cab_core.plugins.ObserverSpec`) are
    created once the folder exists and follow the record as it is written (:mod:`cab_core.attempt.records.observers`)."""

    def __init__(self, root: Path, observers: Iterable[Any] = ()):
        self.root = Path(root)
        if (self.root / "events.jsonl").exists() or (self.root / "result.json").exists():
            raise ConfigError(f"{self.root} already holds an attempt's records; choose another output directory")
        self.root.mkdir(parents=True, exist_ok=True)
        (self.root / "observations").mkdir(exist_ok=True)
        (self.root / "programs").mkdir(exist_ok=True)
        (self.root / "privileged").mkdir(exist_ok=True)
        self._events = open(self.root / "events.jsonl", "a", buffering=1)
        self._snap = open(self.root / "privileged" / "snapshots.jsonl", "a", buffering=1)
        self._seq = 0
        self.tags: dict[str, Any] = {}  # fields added to every event while set (a fork's prefix: cab_core.attempt.fork)
        self._lock = threading.Lock()
        self._programs = 0
        self.video: VideoWriter | None = None
        self.t0 = time.monotonic()
        self.observers = Observers()
        self._detached(self.observers.create(list(observers), str(self.root)))

    # -- events -------------------------------------------------------------------------------
    def event(self, kind: str, **data: Any) -> dict:
        with self._lock:
            self._seq += 1
            ev = {"seq": self._seq, "kind": kind, "t_wall": round(time.monotonic() - self.t0, 4), **data, **self.tags}
            line = dumps(ev)
            self._events.write(line + "\n")
            faults = self.observers.dispatch("on_event", line)  # in order, after the event is written
        self._detached(faults)
        return ev

    def _detached(self, faults: list[tuple[str, str, str]]) -> None:
        for name, stage, error in faults:
            self.event("observer_detached", observer=name, stage=stage, error=error)

    def snapshot(self, label: str, state: dict) -> None:
        with self._lock:
            self._snap.write(dumps({"label": label, **state}) + "\n")

    def write_private(self, name: str, obj: Any) -> None:
        write_json_atomic(self.root / "privileged" / name, obj)

    # -- artefacts ----------------------------------------------------------------------------
    def save_observation(self, obs) -> str:
        from PIL import Image

        rel = f"observations/{obs.obs_id}.png"
        Image.fromarray(obs.image).save(self.root / rel, compress_level=1)
        return rel

    def save_program(self, code: str) -> str:
        self._programs += 1
        rel = f"programs/prog_{self._programs:03d}.py"
        (self.root / rel).write_text(code, encoding="utf-8", errors="backslashreplace")  # lone surrogates kept visible
        return rel

    def open_video(self, fps: float, size_wh: tuple[int, int]) -> VideoWriter:
        """The attempt's video writer (``video.mp4``), opened; also ``self.video``."""
        self.video = VideoWriter(self.root / "video.mp4", fps, size_wh)
        return self.video

    # -- end ----------------------------------------------------------------------------------
    def write_result(self, result: dict) -> None:
        """The verdict's record: ``result.json`` (atomically) and the end of the event and snapshot
        logs. The video and the observers may follow (:meth:`finish`)."""
        write_json_atomic(self.root / "result.json", result)
        self._close_logs()

    def finish(self, result: dict) -> None:
        """The complete record: the video closed, ``result.json`` written again (atomically) when
        :meth:`write_result` wrote it before, the observers' ``on_result``; everything closed."""
        if self.video is not None:
            self.video.close()
        write_json_atomic(self.root / "result.json", result)
        self.observers.dispatch("on_result", dumps(result))  # a fault is logged (the record is complete)
        self.close()

    def _close_logs(self) -> None:
        for f in (self._events, self._snap):
            try:
                f.close()
            except Exception:
                pass

    def close(self) -> None:
        self._close_logs()
        if self.video is not None:
            self.video.close()
