"""One attempt, in three parts a reader finds by name:

* building the world: :class:`~cab_core.attempt.engine.world.BuiltWorld` (instance, simulator, planner,
  robot at home, settled);
* serving the agent's calls under budgets: :class:`~cab_core.attempt.engine.serving.CallServer`;
* finishing: the hidden verdict (:class:`~cab_core.attempt.engine.finishing.VerdictTracker`), the
  checkpoints and ``result.json``.

:class:`Episode` puts them together and is what harnesses talk to (the protocol
:class:`cab_core.contracts.harness.AttemptSession`). The host owns everything privileged; agents
see only tool results."""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cab_core.attempt.budget import BudgetLedger
from cab_core.attempt.engine.contract import attempt_contract
from cab_core.attempt.engine.finishing import VerdictTracker, attempt_checkpoints, versions
from cab_core.attempt.engine.serving import CallServer, StepClock, ToolResponse
from cab_core.attempt.engine.world import RECORD_CAMERA, BuiltWorld, close_quietly, with_parts
from cab_core.attempt.fork import FORK_TOLERANCE_M, ForkPoint, compare_prefix, link_parent
from cab_core.attempt.records.result_format import RECORD_VERSION, AttemptRecord, MalformedRecord
from cab_core.attempt.records.writer import Recorder, VideoWriter
from cab_core.contracts.task import SceneInstance, Task
from cab_core.contracts.verifier import WorldView
from cab_core.errors import AttemptEnded
from cab_core.kits.jsonfiles import read_jsonl
from cab_core.plugins import select_record_observers
from cab_core.tools import build_registry
from cab_core.tools.context import ObservationStore, RobotContext

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.attempt.spec import AttemptSpec

__all__ = ["Episode", "RECORD_CAMERA", "ToolResponse"]

log = logging.getLogger("cab")


class Episode:
    """The episode host for one attempt. Use as a context manager or call ``close()``."""

    def __init__(self, spec: AttemptSpec, task: Task, sim, planner, embodiment, observers=None):
        """``observers``: the record observers (:func:`cab_core.plugins.select_record_observers`);
        None: those ``spec.record`` selects among the installed ones."""
        self.spec = spec
        self.task = task
        self.sim = sim
        self.planner = planner
        self.emb = embodiment
        self.out = Path(spec.output_dir)
        if observers is None:
            observers = select_record_observers(spec.record)
        self.recorder = Recorder(self.out, observers)
        self.ended = False
        self.termination: dict | None = None
        self.result: dict | None = None  # result.json as written (AttemptRecord.dump())
        self.record: AttemptRecord | None = None  # the same, typed
        self.agent: dict | None = None  # who played, when the harness knows (cab_core.kits.harness.agent_info)
        self._t_start = time.monotonic()
        self.fork: ForkPoint | None = None  # where a fork started (cab_core.attempt.fork)
        self._fork_record: dict | None = None
        self._setup()
        if spec.fork:
            made = self.replay_prefix(ForkPoint.load(self.out / spec.fork["parent"], spec.fork["at"]))
            self._fork_record = {k: made[k] for k in ("parent", "at", "calls_made_again", "exact", "max_tcp_error_m",
                                                      "max_object_error_m", "lineage")}
            if spec.fork.get("planner"):  # fork.planner=own: another planner made the prefix again
                self._fork_record["planner"] = dict(spec.fork["planner"])

    @classmethod
    def open(cls, spec: AttemptSpec, observers=None) -> Episode:
        """The attempt ``spec`` describes, its task, simulator, planner and embodiment created
        through the plugin registry (the simulator is closed again if building fails)."""
        return with_parts(spec, lambda task, sim, planner, emb: cls(spec, task, sim, planner, emb, observers))

    # -- set-up -------------------------------------------------------------------------------
    def _setup(self) -> None:
        spec = self.spec
        t0 = time.monotonic()
        rec = spec.record or {}
        self._video_every = int(rec.get("video_every_steps", 25)) if rec.get("video", True) else 0
        video_size: tuple[int, int] | None = None
        if self._video_every:
            width, height = rec.get("video_size", [320, 240])
            video_size = (width, height)
        self.built = BuiltWorld(spec, self.task, self.sim, self.planner, self.emb, video_size)
        self.instance: SceneInstance = self.built.instance
        self.perturbation = self.built.perturbation
        self.randomization = self.built.randomization
        self.ledger = BudgetLedger.create(spec.budget_tool_calls, spec.budget_sim_seconds,
                                          spec.budget_wall_seconds, self.sim.timestep,
                                          spec.run_code_max_internal_calls, spec.budget_cost_usd)
        self.clock = StepClock(self.sim, self.ledger)
        self.obs = ObservationStore(on_add=self.recorder.save_observation)
        self.ctx = RobotContext(self.sim, self.planner, self.emb, self.clock, self.obs)
        self.world = WorldView(self.sim, self.emb, self.ctx.gripper_cmd, self.instance.info)
        self.world.remember_start()
        self.verifier = self.task.verifier(self.instance)
        self.verdict = VerdictTracker(self.verifier, self.world, self.sim.timestep)
        if self.verifier.scoring == "latch":
            self.clock.callbacks.append(self.verdict.poll)
        self._video_samples: list | None = None
        self._video_render_seconds: float | None = None
        self._video_error: str | None = None
        self._records_complete = False  # finish_video() has run
        if video_size is not None:  # as self._video_every
            video = self.recorder.open_video(1.0 / (self.sim.timestep * self._video_every), video_size)
            first = self.sim.render_sample()
            if first is not None:  # the video is rendered from state samples once the attempt is over
                self._video_samples = [first]
                self.clock.callbacks.append(self._video_sample)
            else:  # a simulator that cannot render from samples: frames rendered in the loop
                video.add(self.sim.render(RECORD_CAMERA))
                self.clock.callbacks.append(self._video_frame)
        self.registry = build_registry()
        self.server = CallServer(spec, self.registry, self.ctx, self.ledger, self.clock, self.recorder, self.image,
                                 on_end=self._end, on_physics=self._snapshot, ended=lambda: self.ended)
        self.recorder.write_private("scene_info.json", self.built.scene_info())
        self._snapshot("start")
        self.setup_seconds = time.monotonic() - t0
        self.recorder.event("attempt_start", task=spec.task, seed=spec.seed, attempt=spec.attempt,
                            instruction=self.task.info.instruction, budget=self.ledger.remaining(),
                            setup_seconds=round(self.setup_seconds, 3), config=spec.as_record())

    def replay_prefix(self, point: ForkPoint, tolerance: float = FORK_TOLERANCE_M) -> dict:
        """Make the parent's calls up to ``point.at`` again in this episode (just set up, a fork:
        :mod:`cab_core.attempt.fork`), each event of them marked ``fork_prefix``; check the world
        against the parent's records (:func:`~cab_core.attempt.fork.compare_prefix`, which raises
        :class:`~cab_core.attempt.fork.ForkDiverged` when it differs); carry the parent's
        wall-clock spend over; record the ``fork`` event and link the parent to this attempt.
        Returns the ``fork`` event's fields."""
        t0 = time.monotonic()
        self.fork = point
        self.recorder.tags = {"fork_prefix": True}
        try:
            for tool, args in point.calls():
                try:
                    self.call(tool, args)
                except AttemptEnded:
                    break
        finally:
            self.recorder.tags = {}
        made = [e for e in read_jsonl(self.out / "events.jsonl") if e.get("fork_prefix")]
        snaps = read_jsonl(self.out / "privileged" / "snapshots.jsonl")
        compared = compare_prefix(point, made, snaps, self.server.calls, tolerance)
        self.ledger.carry_wall(point.wall_seconds)
        fields = {**point.as_record(self.out), "calls_made_again": len(point.calls()),
                  "snapshots_compared": compared["snapshots_compared"], "exact": compared["exact"],
                  "max_tcp_error_m": compared["max_tcp_error_m"], "max_object_error_m": compared["max_object_error_m"],
                  "parent_wall_seconds": point.wall_seconds, "prefix_seconds": round(time.monotonic() - t0, 3),
                  "lineage": point.lineage}
        self.recorder.event("fork", **fields)
        link_parent(point, self.out)
        return fields

    def _video_frame(self, step: int) -> None:
        if step % self._video_every == 0 and self.recorder.video is not None:
            self.recorder.video.add(self.sim.render(RECORD_CAMERA))

    def _video_sample(self, step: int) -> None:
        """What the video frame of this step takes, kept for later (:meth:`Simulator.render_sample`:
        a read that changes nothing, a few microseconds): rendering 320x240 costs more than the
        25 physics steps between two frames, so it is kept out of the motion loop."""
        if step % self._video_every == 0 and self._video_samples is not None:
            self._video_samples.append(self.sim.render_sample())

    def _render_video(self) -> str | None:
        """The frames of the samples taken during the attempt, rendered and encoded now that its
        physics is over: the same frames the loop would have rendered, bit for bit
        (:meth:`Simulator.render_samples`), and the world is left as it was. Returns what went
        wrong (the frames rendered until then are kept), None when nothing did."""
        samples, self._video_samples = self._video_samples, None
        if not samples or self.recorder.video is None:
            return None
        t0 = time.monotonic()
        try:
            self.sim.render_samples(RECORD_CAMERA, samples, self.recorder.video.add)
        except Exception as e:  # never lose the attempt because its video failed
            log.warning("the video could not be rendered: %r", e)
            return f"rendering failed: {e!r}"
        finally:
            self._video_render_seconds = time.monotonic() - t0
        return None

    def _video_block(self, error: str | None = None) -> dict | None:
        """``result.json``'s ``video``: the file once it is complete under its name, else None."""
        video = self.recorder.video
        if video is None or not video.closed:
            return None
        block = {"file": "video.mp4", "frames": video.frames, "every_steps": self._video_every,
                 "rendered": "in the loop" if self._video_render_seconds is None else "after the attempt",
                 "render_seconds": None if self._video_render_seconds is None
                 else round(self._video_render_seconds, 3)}
        if error is not None:
            block["error"] = error
        return block

    def _snapshot(self, label: str) -> None:
        """A privileged snapshot of the world for the record (never for the agent)."""
        self.recorder.snapshot(label, self.built.snapshot(self.ctx, self.clock.steps, self.server.calls,
                                                          self.verdict.latched))

    # -- the session API (cab_core.contracts.harness.AttemptSession) ---------------------------
    @property
    def instruction(self) -> str:
        return self.task.info.instruction

    @property
    def claim(self) -> dict:
        return self.server.claim

    @property
    def tool_errors(self) -> int:
        return self.server.tool_errors

    @property
    def sandbox(self):
        return self.server.sandbox

    def tool_specs(self) -> list[dict]:
        return [t.spec() for t in self.registry.values()]

    def image(self, obs_id: str) -> np.ndarray:
        return self.obs.get(obs_id).image

    def call(self, name: str, args: dict | None = None) -> ToolResponse:
        """One direct tool call by the agent (charged, except ``done``)."""
        return self.server.call(name, args, lambda: self.termination)

    # -- the end ------------------------------------------------------------------------------
    def _end(self, reason: str, detail: str = "") -> None:
        if not self.ended:
            self.ended = True
            self.termination = {"reason": reason, "detail": detail}

    def end(self, reason: str, detail: str = "") -> None:
        """Harness-side ending (agent stopped, provider failure...)."""
        self._end(reason, detail)

    def finish(self) -> dict:
        """Score and write ``result.json`` (atomically): the verdict is recorded when this returns,
        so a harness answers ``done`` right after it. A video rendered from the attempt's samples
        is not written yet (``video`` is null until then): :meth:`finish_video` renders it, after
        the answer, and writes ``result.json`` again with it; :meth:`close` calls it. Idempotent."""
        if self.result is not None:
            return self.result
        if not self.ended:
            self._end("no_done", "the agent stopped without calling done")
        try:
            verdict = self.verdict.final()
        except Exception as e:  # never lose the attempt because scoring failed
            verdict = {"success": False, "error": repr(e)}
        self._snapshot("end")
        checkpoints = attempt_checkpoints(self.built, self.out, verdict)
        self.server.close()
        if self.recorder.video is not None and not self._video_samples:
            self._close_video(self.recorder.video)  # frames rendered in the loop: the video is complete now
        s = self.spec
        fields = dict(
            record_version=RECORD_VERSION,
            task=s.task, seed=s.seed, attempt=s.attempt, sim=s.sim, embodiment=s.embodiment,
            planner=s.planner, model=s.model, harness=s.harness, agent=self.agent,
            instruction=self.task.info.instruction,
            scoring=self.verifier.scoring,
            perturbation=self.perturbation,
            randomization=self.randomization,
            fork=self._fork_record,
            verdict=verdict,
            termination=self.termination,
            claim=self.claim,
            budget=self.ledger.summary(),
            timing={"wall_seconds": round(time.monotonic() - self._t_start, 3),
                    "setup_seconds": round(self.setup_seconds, 3)},
            counts={"charged_calls": self.server.calls, "observations": len(self.obs._obs),
                    "tool_errors": self.tool_errors},
            sandbox={"confinement": getattr(self.sandbox, "confinement", None),
                     "layers": getattr(self.sandbox, "confinement_layers", None),
                     "note": getattr(self.sandbox, "confinement_note", None)},
            versions=self.versions(),
            checkpoints=checkpoints,
            video=self._video_block(self._video_error),
            contract=self._contract(),
        )
        try:
            self.record = AttemptRecord.build(**fields)
            self.result = self.record.dump()
        except MalformedRecord as e:  # never lose the attempt: written as assembled; readers refuse it
            self.recorder.event("record_invalid", problems=e.problems)
            self.result = {k: v for k, v in fields.items() if not (v is None and k in AttemptRecord.omit_if_none)}
        self.recorder.event("attempt_end", termination=self.termination, claim=self.claim)
        self.recorder.write_result(self.result)
        return self.result

    def _contract(self) -> dict | None:
        """The attempt's comparison contract (:mod:`cab_core.attempt.engine.contract`): from its spec and,
        where the harness learnt it, the serving engine; None (the key left out) if it cannot be
        computed, which the attempt's events say."""
        serving = (self.agent or {}).get("serving") if isinstance(self.agent, dict) else None
        try:
            return attempt_contract(self.spec, serving if isinstance(serving, dict) else None)
        except Exception as e:  # noqa: BLE001  (never lose the attempt for its contract)
            self.recorder.event("contract_error", error=f"{type(e).__name__}: {e}")
            return None

    def _close_video(self, video: VideoWriter, error: str | None = None) -> None:
        try:
            video.close()
        except Exception as e:  # the encoder failed: no video is listed, the record is kept
            log.warning("the video could not be written: %r", e)
            error = error or f"encoding failed: {e!r}"
        self._video_error = error

    def finish_video(self) -> dict:
        """What may wait until ``done`` is answered: the video rendered from the attempt's samples,
        then ``result.json`` written again (atomically) with it listed, and the record observers'
        ``on_result``. An interruption or a failure while rendering keeps the verdict: the frames
        rendered until then are listed with the error. Idempotent; :meth:`finish` first if needed."""
        result = self.finish()
        if self._records_complete:
            return result
        self._records_complete = True
        error: str | None = "interrupted"
        try:
            error = self._render_video()
        finally:
            if self.recorder.video is not None and not self.recorder.video.closed:
                self._close_video(self.recorder.video, error)
            block = self._video_block(self._video_error)
            if block is not None and block["render_seconds"] is None:
                del block["render_seconds"]  # as the record writes it (Video.omit_if_none)
            result["video"] = block  # in place: the dict finish() returned is the record's
            timing = result.get("timing")
            if self._video_render_seconds is not None and isinstance(timing, dict):
                timing["wall_seconds"] = round(time.monotonic() - self._t_start, 3)  # the whole attempt, video included
            if self.record is not None:
                try:
                    self.record = AttemptRecord.build(**result)
                except MalformedRecord as e:  # cannot be from the video block alone; kept as written
                    log.warning("result.json with its video is not a valid record: %s", e)
            self.recorder.finish(result)
        return result

    def versions(self) -> dict:
        return versions(self.sim, self.planner)

    def close(self) -> None:
        try:
            self.finish_video()
        finally:
            close_quietly(self.sim)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

