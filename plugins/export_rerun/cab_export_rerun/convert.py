"""One attempt's record as a Rerun recording (``attempt.rrd``), read from the attempt's folder.

The same function serves the record observer (at the end of an attempt) and ``cab-export`` (records
that exist). Entity paths and timelines (``docs/export.md``):

timelines
    ``sim_time`` (duration, simulated seconds: physics step x ``budget.sim_dt``) on everything that
    happens in time; ``event`` (sequence: the ``seq`` of the event in ``events.jsonl``) on what comes
    from an event (calls, images, programs); ``snapshot`` (sequence: the line of
    ``privileged/snapshots.jsonl``, from 0) on what comes from a snapshot; ``checkpoint``
    (sequence: subgoals then spatial checkpoints, from 0) on the checkpoint entries. Several events,
    snapshots or checkpoints can share one simulated time (a capture does not step physics; every
    checkpoint not attained is logged at the end): the sequences tell them apart.

``world``                                  view coordinates: right-handed, +z up (static)
``world/cameras/<camera>``                 the camera's pose (``E``, world to camera) and pinhole (``K``)
                                           at each observation it took
``world/cameras/<camera>/image``           each image the agent saw (the PNG as recorded), at the
                                           simulated time of the call that took it
``world/cameras/<camera>/annotated``       images the agent saw that a tool drew on (an overlay, a legend)
``video``                                  the recording camera's video (``video.mp4``, static) and one
                                           frame reference per frame, at its simulated time
``world/robot/<arm>/tcp``                  each arm's TCP pose, per privileged snapshot
``robot/<arm>/gripper_cmd``                gripper command (1 open, 0 closed), per snapshot
``robot/<arm>/finger_gap_m``               distance between the fingers, per snapshot
``world/objects/<object>``                 each object's pose, per snapshot
``world/objects/<object>/shape_<i>``       its shapes' geometry, in its frame (static; :mod:`.scene`)
``world/object_links/<object>/<link>``     an articulated object's link poses, per snapshot
``world/object_links/<object>/<link>/visual_<i>``   the link's URDF visuals (static)
``objects/<object>/qpos``                  an articulated object's joint positions, per snapshot
``robot/<arm>/joints/<joint>``             an arm's joint positions (rad or m), wherever a call's result
                                           reports them (``get_robot_state``): the snapshots hold no
                                           arm joint angles
``log/calls``                              one entry per charged or ``done`` call: tool, arguments, status
``log/internal_calls``                     one entry per robot call made from inside ``run_code``
``log/events``                             every other event (start, end, tool errors, refusals...)
``log/checkpoints``                        each subgoal and spatial checkpoint: attained when, or not
``log/verdict``                            the verdict, termination and claim, at the end
``programs/<prog_NNN>``                    each ``run_code`` program, as a document, at its call
``attempt/result``, ``attempt/instruction``, ``attempt/scene_info``   documents (static)
``log/scene``                              why the scene's geometry is missing, when it is (static)
"""
from __future__ import annotations

import json
import os
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from cab_core.errors import CabError
from cab_core.kits.jsonfiles import read_json_object, read_jsonl

from .scene import log_scene

FILE = "attempt.rrd"
APP_ID = "cab"
ARG_TEXT_LIMIT = 2000  # characters of a call's arguments shown in its log entry
TCP_AXES_M, OBJECT_AXES_M, LINK_AXES_M = 0.1, 0.05, 0.03  # length of the axes drawn at each pose (TransformAxes3D)

CALL_KINDS = {"call": "log/calls", "internal_call": "log/internal_calls"}


def _read_jsonl(path: Path) -> list[dict]:
    return read_jsonl(path) if path.exists() else []


def _xyzw(pose) -> np.ndarray:
    """The quaternion of a cab pose ``[x, y, z, qw, qx, qy, qz]`` in Rerun's order (x, y, z, w)."""
    w, x, y, z = (float(v) for v in pose[3:7])
    return np.array([x, y, z, w])


def _timestep(result: dict, events: list[dict]) -> float:
    dt = (result.get("budget") or {}).get("sim_dt")
    if isinstance(dt, (int, float)) and dt > 0:
        return float(dt)
    for e in events:  # a record written before sim_dt was: the first call that stepped
        if e.get("physics_steps") and e.get("sim_seconds"):
            return float(e["sim_seconds"]) / float(e["physics_steps"])
    raise ValueError("the record does not tell the simulator's timestep (result.json budget.sim_dt)")


def _text(obj: Any, limit: int = ARG_TEXT_LIMIT) -> str:
    s = json.dumps(obj, separators=(", ", ": "), default=str)
    return s if len(s) <= limit else s[:limit - 3] + "..."


def call_status(event: dict) -> tuple[str, str]:
    """``(status text, log level)`` of a call event: the action's status, a tool's error code, or ok."""
    result = event.get("result") if isinstance(event.get("result"), dict) else {}
    if event.get("status"):
        st = str(event["status"])
        return st, ("INFO" if st in ("SUCCESS", "OK", "COMPLETED") else "WARN")
    if result.get("error") or result.get("code"):
        code = result.get("code") or "error"
        msg = str(result.get("error") or "")
        return f"{code}: {msg}"[:300].rstrip(": "), "ERROR"
    if result.get("ok") is False:
        return "not ok", "WARN"
    return "ok", "INFO"


def _call_line(e: dict, program: str | None) -> str:
    args = e.get("arguments")
    shown = f"programs/{program}" if program and isinstance(args, dict) and "code" in args else _text(args)
    status, _ = call_status(e)
    extra = []
    if e.get("physics_steps"):
        extra.append(f"{e['physics_steps']} steps")
    if e.get("sim_seconds") is not None:
        extra.append(f"{e['sim_seconds']} sim s")
    if e.get("wall_seconds") is not None:
        extra.append(f"{e['wall_seconds']} wall s")
    if e.get("obs_ids"):
        extra.append("images " + ", ".join(e["obs_ids"]))
    if e.get("charged") is False:
        extra.append("not charged")
    tail = f" [{'; '.join(extra)}]" if extra else ""
    return f"#{e.get('seq')} {e.get('tool')}({shown}) -> {status}{tail}"


def _summaries(obj: Any, out: dict[str, dict]) -> None:
    """Every observation summary (a mapping with ``obs_id`` and ``camera``) inside a tool result."""
    if isinstance(obj, dict):
        if isinstance(obj.get("obs_id"), str) and isinstance(obj.get("camera"), str):
            out.setdefault(obj["obs_id"], obj)
        for v in obj.values():
            _summaries(v, out)
    elif isinstance(obj, list):
        for v in obj:
            _summaries(v, out)


class _Writer:
    """Logs into one recording; every log is strict (a wrong value raises instead of a warning)."""

    def __init__(self, rec):
        import rerun as rr

        self.rr, self.rec = rr, rec

    def at(self, sim_s: float | None, seq: int | None = None, snapshot: int | None = None,
           checkpoint: int | None = None) -> None:
        self.rec.reset_time()
        if sim_s is not None:
            self.rec.set_time("sim_time", duration=float(sim_s))
        if seq is not None:
            self.rec.set_time("event", sequence=int(seq))
        if snapshot is not None:
            self.rec.set_time("snapshot", sequence=int(snapshot))
        if checkpoint is not None:
            self.rec.set_time("checkpoint", sequence=int(checkpoint))

    def log(self, path: str, *what, static: bool = False) -> None:
        self.rec.log(path, *what, static=static, strict=True)


def _document(title: str, obj: Any) -> str:
    return f"# {title}\n\n```json\n{json.dumps(obj, indent=2, default=str)}\n```\n"


def _result_markdown(r: dict) -> str:
    v, t, c, b = r.get("verdict") or {}, r.get("termination") or {}, r.get("claim") or {}, r.get("budget") or {}
    lines = [f"# {r.get('task')} (seed {r.get('seed')}, attempt {r.get('attempt')})", "",
             f"- model {r.get('model')}, harness {r.get('harness')}, simulator {r.get('sim')}",
             f"- verdict: success = {v.get('success')}",
             f"- termination: {t.get('reason')} ({t.get('detail')})",
             f"- claim: {c.get('success_claim')}: {c.get('report')}",
             f"- tool calls {b.get('tool_calls_used')} / {b.get('tool_calls_limit')}, simulated s "
             f"{b.get('sim_seconds_used')} / {b.get('sim_seconds_limit')}", "",
             "```json", json.dumps(r, indent=2, default=str), "```", ""]
    return "\n".join(lines)


def _log_observation(w: _Writer, root: Path, obs_id: str, summary: dict | None) -> bool:
    png = root / "observations" / f"{obs_id}.png"
    if not png.exists():
        return False
    rr = w.rr
    camera = (summary or {}).get("camera") or "unknown"
    derived = bool((summary or {}).get("annotation") or (summary or {}).get("source_obs_id"))
    snap = (summary or {}).get("cam_pose_snapshot") or {}
    if snap.get("E") is not None and snap.get("K") is not None:
        E = np.asarray(snap["E"], float)
        h, wd = (snap.get("size_hw") or [None, None])[:2]
        w.log(f"world/cameras/{camera}", rr.Transform3D(translation=E[:3, 3], mat3x3=E[:3, :3],
                                                        relation=rr.TransformRelation.ChildFromParent))
        w.log(f"world/cameras/{camera}", rr.Pinhole(image_from_camera=np.asarray(snap["K"], float),
                                                    **({"resolution": [wd, h]} if h and wd else {})))
    w.log(f"world/cameras/{camera}/{'annotated' if derived else 'image'}",
          rr.EncodedImage(contents=png.read_bytes(), media_type="image/png"))
    return True


def _log_snapshot(w: _Writer, i: int, snap: dict, dt: float) -> None:
    rr = w.rr
    w.at(float(snap.get("physics_step") or 0) * dt, snapshot=i)
    for arm, a in sorted((snap.get("arms") or {}).items()):
        if a.get("tcp_pose"):
            p = a["tcp_pose"]
            w.log(f"world/robot/{arm}/tcp", rr.Transform3D(translation=np.asarray(p[:3], float), quaternion=_xyzw(p)),
                  rr.TransformAxes3D(TCP_AXES_M))
        for k in ("gripper_cmd", "finger_gap_m"):
            if isinstance(a.get(k), (int, float)):
                w.log(f"robot/{arm}/{k}", rr.Scalars(np.array([float(a[k])])))
    for name, o in sorted((snap.get("objects") or {}).items()):
        p = o.get("pose")
        if p:
            w.log(f"world/objects/{name}", rr.Transform3D(translation=np.asarray(p[:3], float), quaternion=_xyzw(p)),
                  rr.TransformAxes3D(OBJECT_AXES_M))
        if o.get("qpos"):
            w.log(f"objects/{name}/qpos", rr.Scalars(np.asarray(o["qpos"], float)))
        for link, lp in sorted((o.get("links") or {}).items()):
            w.log(f"world/object_links/{name}/{link}",
                  rr.Transform3D(translation=np.asarray(lp[:3], float), quaternion=_xyzw(lp)), rr.TransformAxes3D(LINK_AXES_M))


def _log_joint_states(w: _Writer, result: Any) -> None:
    """Joint positions a tool result reports (``arms.<arm>.joint_state``: names and positions)."""
    arms = result.get("arms") if isinstance(result, dict) else None
    for arm, a in sorted(arms.items()) if isinstance(arms, dict) else []:
        js = a.get("joint_state") if isinstance(a, dict) else None
        if not isinstance(js, dict) or not js.get("names") or not js.get("positions"):
            continue
        for name, q in zip(js["names"], js["positions"]):
            if isinstance(q, (int, float)):
                w.log(f"robot/{arm}/joints/{name}", w.rr.Scalars(np.array([float(q)])))


def _log_video(w: _Writer, root: Path, result: dict, dt: float) -> int:
    """The recording camera's MP4 as a video asset and one frame reference per frame (on
    ``sim_time``: frame i shows physics step i x ``video.every_steps``). Returns the frames."""
    rr = w.rr
    video = result.get("video") or {}
    path = root / str(video.get("file") or "video.mp4")
    every = video.get("every_steps")
    if not path.exists() or not every:
        return 0
    asset = rr.AssetVideo(path=path)
    w.rec.reset_time()
    w.log("video", asset, static=True)
    ts = np.asarray(asset.read_frame_timestamps_nanos(), dtype=np.int64)
    if len(ts):
        sim = np.arange(len(ts), dtype=np.float64) * float(every) * dt
        w.rec.send_columns("video", indexes=[rr.TimeColumn("sim_time", duration=sim)],
                           columns=rr.VideoFrameReference.columns_nanos(ts), strict=True)
    return int(len(ts))


def convert(attempt_dir: str | os.PathLike, out: str | os.PathLike | None = None, video: bool = True) -> Path:
    """Write the attempt in ``attempt_dir`` (a finished record: ``result.json``, ``events.jsonl``...)
    as a Rerun recording to ``out`` (default ``<attempt_dir>/attempt.rrd``; written to a temporary
    file and renamed, so a reader never sees half a file). Returns the path written."""
    import rerun as rr

    root = Path(attempt_dir)
    out = Path(out) if out is not None else root / FILE
    result = read_json_object(root / "result.json")
    events = _read_jsonl(root / "events.jsonl")
    snapshots = _read_jsonl(root / "privileged" / "snapshots.jsonl")
    dt = _timestep(result, events)

    rec = rr.RecordingStream(APP_ID, recording_id=str(uuid.uuid5(uuid.NAMESPACE_URL, str(root.resolve()))),
                             send_properties=False)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    rec.save(tmp)
    try:
        _write(_Writer(rec), root, result, events, snapshots, dt, video)
        rec.flush()
    except BaseException:
        rec.disconnect()
        tmp.unlink(missing_ok=True)
        raise
    rec.disconnect()
    os.replace(tmp, out)
    return out


def _write(w: _Writer, root: Path, result: dict, events: list[dict], snapshots: list[dict], dt: float,
           video: bool) -> None:
    rr = w.rr
    w.rec.reset_time()
    w.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    w.log("attempt/result", rr.TextDocument(_result_markdown(result), media_type=rr.MediaType.MARKDOWN), static=True)
    if result.get("instruction"):
        w.log("attempt/instruction", rr.TextDocument(str(result["instruction"])), static=True)
    scene = root / "privileged" / "scene_info.json"
    scene_info = read_json_object(scene) if scene.exists() else {}
    if scene_info:
        w.log("attempt/scene_info", rr.TextDocument(_document("scene info (privileged)", scene_info),
                                                    media_type=rr.MediaType.MARKDOWN), static=True)
    try:
        log_scene(w, result, scene_info, snapshots)
    except CabError as e:  # the task's plugin not installed, a record that names no task or embodiment
        w.log("log/scene", rr.TextLog(f"the scene's geometry is not drawn: {e}", level="ERROR"), static=True)

    summaries: dict[str, dict] = {}
    shown: set[str] = set()
    programs: set[str] = set()
    step = 0
    for e in events:
        kind = e.get("kind")
        if isinstance(e.get("physics_step_end"), int):
            step = e["physics_step_end"]
        w.at(step * dt, e.get("seq"))
        result_ = e.get("result")
        _summaries(result_, summaries)
        for obs_id in e.get("obs_ids") or []:
            if obs_id not in shown and _log_observation(w, root, obs_id, summaries.get(obs_id)):
                shown.add(obs_id)
        _log_joint_states(w, result_)
        program = result_.get("program") if isinstance(result_, dict) and e.get("tool") == "run_code" else None
        if kind in CALL_KINDS:
            _, level = call_status(e)
            w.log(CALL_KINDS[kind], rr.TextLog(_call_line(e, program), level=level))
        else:
            w.log("log/events", rr.TextLog(f"#{e.get('seq')} {kind}: {_text({k: v for k, v in e.items() if k not in ('seq', 'kind', 'traceback')}, 600)}",
                                           level="ERROR" if kind in ("host_fault", "tool_error", "video_error",
                                                                     "observer_detached") else "INFO"))
        if program and (root / "programs" / program).exists():
            code = (root / "programs" / program).read_text(errors="replace")
            w.log(f"programs/{Path(program).stem}",
                  rr.TextDocument(f"# {program} (event {e.get('seq')})\n\n```python\n{code}\n```\n",
                                  media_type=rr.MediaType.MARKDOWN))
            programs.add(program)

    end_step = max([step] + [int(s.get("physics_step") or 0) for s in snapshots])
    end = end_step * dt
    last_seq = max([int(e["seq"]) for e in events if isinstance(e.get("seq"), int)], default=0)
    w.at(end, last_seq)
    for png in sorted((root / "observations").glob("*.png")) if (root / "observations").is_dir() else []:
        if png.stem not in shown and _log_observation(w, root, png.stem, summaries.get(png.stem)):
            shown.add(png.stem)  # an image no event names (a record cut short): at the end
    for prog in sorted((root / "programs").glob("*.py")) if (root / "programs").is_dir() else []:
        if prog.name not in programs:
            w.log(f"programs/{prog.stem}", rr.TextDocument(f"# {prog.name}\n\n```python\n{prog.read_text(errors='replace')}\n```\n",
                                                          media_type=rr.MediaType.MARKDOWN))

    for i, snap in enumerate(snapshots):
        _log_snapshot(w, i, snap, dt)

    _log_checkpoints(w, result.get("checkpoints"), dt, end)
    v, t, c = result.get("verdict") or {}, result.get("termination") or {}, result.get("claim") or {}
    w.at(end)
    w.log("log/verdict", rr.TextLog(f"success={v.get('success')} termination={t.get('reason')} "
                                    f"claim={c.get('success_claim')}: {c.get('report')}",
                                    level="INFO" if v.get("success") else "WARN"))
    if video:
        _log_video(w, root, result, dt)


def _log_checkpoints(w: _Writer, ck: Any, dt: float, end: float) -> None:
    rr = w.rr
    if not isinstance(ck, dict):
        return
    if ck.get("error"):
        w.at(end)
        w.log("log/checkpoints", rr.TextLog(f"checkpoints could not be evaluated: {ck['error']}", level="ERROR"))
        return
    items = [("subgoal", s, s.get("text")) for s in ck.get("subgoals") or []] + \
            [("spatial", s, f"{s.get('name')} ({s.get('arm')})") for s in ck.get("spatial") or []]
    for i, (what, s, label) in enumerate(items):
        first = s.get("first") or {}
        at = first.get("physics_step")
        w.at(end if not s.get("attained") or at is None else int(at) * dt, checkpoint=i)
        if s.get("attained"):
            where = f" at call {first.get('calls')}, step {at} ({first.get('label')})" if at is not None else \
                " (by the latched event)"
            w.log("log/checkpoints", rr.TextLog(f"{what} {s.get('index')} attained{where}: {label}", level="INFO"))
        else:
            w.log("log/checkpoints", rr.TextLog(f"{what} {s.get('index')} not attained: {label}", level="WARN"))
