"""One attempt: build the world, serve the tools under budgets, score with the hidden verifier,
record everything. The host owns everything privileged; agents see only tool results."""
from __future__ import annotations

import platform
import time
import traceback
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__, numerics
from .budget import BudgetLedger
from .errors import AttemptEnded, BudgetExhausted, CabError, ObservationUnavailable, ToolArgumentError
from .faults import is_infrastructure_fault, tool_error_payload
from .perturb import Perturbation, perturb_scene
from .recording import RECORD_VERSION, Recorder
from .robot.context import ObservationStore, RobotContext
from .scene import CameraSpec
from .task import SceneInstance, Task
from .verifier import Evaluation, Verifier, WorldView, deciding_margin

RECORD_CAMERA = "record_camera"


@dataclass
class AttemptSpec:
    """One attempt, fully resolved and validated from the Hydra config."""
    task: str
    seed: int
    attempt: int
    sim: str
    embodiment: str
    planner: str
    harness: str
    model: str
    output_dir: Path
    budget_tool_calls: int
    budget_sim_seconds: float
    budget_wall_seconds: float
    run_code_max_internal_calls: int = 500
    sandbox: dict = field(default_factory=dict)
    record: dict = field(default_factory=lambda: {"video": True, "video_every_steps": 25, "video_size": [320, 240]})
    sim_cfg: dict = field(default_factory=dict)
    planner_cfg: dict = field(default_factory=dict)
    embodiment_cfg: dict = field(default_factory=dict)
    model_cfg: dict = field(default_factory=dict)
    harness_cfg: dict = field(default_factory=dict)
    perturb: dict | None = None  # cab_core.perturb.Perturbation fields; None: the instance as sampled

    def as_record(self) -> dict:
        """Everything but the output directory: what a replay needs to rebuild the attempt."""
        return {k: v for k, v in asdict(self).items() if k != "output_dir"}


@dataclass
class ToolResponse:
    """What an agent gets back from one call."""
    name: str
    payload: dict
    obs_ids: list[str]
    ended: bool = False
    status: str | None = None


class StepClock:
    """The only way physics advances during an attempt: charges simulated time, polls latches,
    feeds the video. ``callbacks`` are called with the step count after every step."""

    def __init__(self, sim, ledger: BudgetLedger):
        self.sim = sim
        self.ledger = ledger
        self.steps = 0
        self.callbacks: list = []

    def step(self, n: int = 1) -> None:
        sim_step, charge, callbacks = self.sim.step, self.ledger.charge_steps, self.callbacks
        for _ in range(int(n)):
            sim_step(1)
            self.steps += 1
            charge(1)
            for cb in callbacks:
                cb(self.steps)


class VerdictTracker:
    """Hidden scoring. Latch tasks poll (``Verifier.holds``) every ``poll_every`` steps; an event
    already true at the start is voided until it has been false once."""

    #: a latched event's margin is the widest it reached over the polls where it held, within this
    #: much simulated time after it latched: the event latches the first step it holds, when a
    #: moving quantity has only just crossed its threshold
    LATCH_MARGIN_WINDOW_S = 1.0

    def __init__(self, verifier: Verifier, world: WorldView, timestep: float = 0.004):
        self.v = verifier
        self.w = world
        self.window_steps = max(1, int(round(self.LATCH_MARGIN_WINDOW_S / timestep)))
        self.baseline: Evaluation = verifier.evaluate(world)
        self.armed = not self.baseline.success
        self.latched = False
        self.latched_at_step: int | None = None
        self.observed = self.baseline.success
        self.at_latch: Evaluation | None = None  # the event's evaluation where it held widest
        self.at_latch_step: int | None = None

    def poll(self, step: int) -> None:
        if self.v.scoring != "latch" or step % self.v.poll_every:
            return
        if self.latched:
            if step - self.latched_at_step <= self.window_steps:
                self._widen(step)
            return
        if self.v.holds(self.w):
            self.observed = True
            if self.armed:
                self.latched, self.latched_at_step = True, step
                self.at_latch = self.v.evaluate(self.w)
                self._at_latch_fraction = self._deciding_fraction(self.at_latch)
                self.at_latch_step = step
        else:
            self.armed = True

    @staticmethod
    def _deciding_fraction(ev: Evaluation) -> float:
        return min((m.fraction for k, m in ev.margins.items() if ev.predicates.get(k)), default=float("inf"))

    def _widen(self, step: int) -> None:
        """Within the window after latching: keep the evaluation where the event held widest."""
        ev = self.v.evaluate(self.w)
        if ev.success:
            f = self._deciding_fraction(ev)
            if f > self._at_latch_fraction:
                self.at_latch, self._at_latch_fraction, self.at_latch_step = ev, f, step

    def final(self) -> dict:
        ev = self.v.evaluate(self.w)
        req = self.v.final_requirements(self.w)
        guard = self.v.guard(self.w)
        core = self.latched if self.v.scoring == "latch" else ev.success
        success = bool(core and all(req.values()) and all(guard.values()))
        # margins of what decided the verdict: a latched event's predicates where it held widest
        # (within the window after latching), otherwise as they are at the end; then the final
        # requirements and the guard
        decisive = self.at_latch if self.v.scoring == "latch" and self.at_latch is not None else ev
        preds = {**decisive.predicates, **req, **guard}
        margins = {**decisive.margins, **self.v.final_requirement_margins(self.w), **self.v.guard_margins(self.w)}
        if self.v.scoring == "latch" and not self.latched:
            preds = {**preds, "event_latched": False}  # the event never latched: no threshold can flip it
        return {
            "success": success,
            "scoring": self.v.scoring,
            "final_state_success": bool(ev.success),
            "predicates": {k: bool(v) for k, v in ev.predicates.items()},
            "values": {k: float(v) for k, v in ev.values.items()},
            "final_requirements": {k: bool(v) for k, v in req.items()},
            "guard": {k: bool(v) for k, v in guard.items()},
            "latch": {"latched": self.latched, "at_step": self.latched_at_step, "armed_at_start": not self.baseline.success}
            if self.v.scoring == "latch" else None,
            "baseline_success": bool(self.baseline.success),
            "margins": {k: m.as_record() for k, m in margins.items()},
            # "latch": the event's widest moment within the window after it latched, at that step
            "margins_at": "latch" if decisive is self.at_latch else "final",
            "margins_at_step": self.at_latch_step if decisive is self.at_latch else None,
            "margin": deciding_margin(preds, margins, success),
        }


class Episode:
    """The episode host for one attempt. Use as a context manager or call ``close()``."""

    def __init__(self, spec: AttemptSpec, task: Task, sim, planner, embodiment, observers=None):
        """``observers``: the record observers (:func:`cab_core.observers.select`); None: those
        ``spec.record`` selects among the installed ones."""
        self.spec = spec
        self.task = task
        self.sim = sim
        self.planner = planner
        self.emb = embodiment
        self.out = Path(spec.output_dir)
        if observers is None:
            from .observers import select

            observers = select(spec.record)
        self.recorder = Recorder(self.out, observers)
        self.ended = False
        self.termination: dict | None = None
        self.claim: dict = {"success_claim": None, "report": None}
        self.sandbox = None
        self.result: dict | None = None
        self.agent: dict | None = None  # who played, when the harness knows (cab_core.agent_record)
        self._t_start = time.monotonic()
        self._calls = 0
        self.tool_errors = 0  # exceptions raised while serving the agent's calls (cab_core.faults)
        self._setup()

    # -- set-up -------------------------------------------------------------------------------
    def _setup(self) -> None:
        from .tools import build_registry

        spec = self.spec
        t0 = time.monotonic()
        self.instance: SceneInstance = self.task.build(spec.seed, self.emb)
        scene = self.instance.scene
        self.perturbation = None
        if spec.perturb is not None:
            p = Perturbation(**spec.perturb)
            self.perturbation = {**p.as_record(), "objects": perturb_scene(scene, p, spec.seed)}
        rec = spec.record or {}
        self._video_every = int(rec.get("video_every_steps", 25)) if rec.get("video", True) else 0
        if self._video_every:
            head = next(c for c in self.emb.cameras if c.name == "head_camera")
            w, h = rec.get("video_size", [320, 240])
            scene.cameras.append(CameraSpec(RECORD_CAMERA, int(w), int(h), head.fovy_deg, head.pose))
        self.sim.build(scene, self.emb)
        self.planner.setup(self.emb, self.sim.timestep)
        home = []
        for arm in sorted(self.emb.arms):
            a = self.emb.arms[arm]
            home += list(a.home_qpos) + [a.gripper.open_target] * len(a.gripper.joints)
        self.sim.set_qpos(np.asarray(home, float))
        self.sim.step(self.task.settle_steps())  # uncharged settling before the agent starts
        self.ledger = BudgetLedger.create(spec.budget_tool_calls, spec.budget_sim_seconds,
                                          spec.budget_wall_seconds, self.sim.timestep,
                                          spec.run_code_max_internal_calls)
        self.clock = StepClock(self.sim, self.ledger)
        self.obs = ObservationStore(on_add=self._on_observation)
        self.ctx = RobotContext(self.sim, self.planner, self.emb, self.clock, self.obs)
        self.world = WorldView(self.sim, self.emb, self.ctx.gripper_cmd, self.instance.info)
        self.verifier = self.task.verifier(self.instance)
        self.verdict = VerdictTracker(self.verifier, self.world, self.sim.timestep)
        if self.verifier.scoring == "latch":
            self.clock.callbacks.append(self.verdict.poll)
        self._video_samples: list | None = None
        self._video_render_seconds: float | None = None
        if self._video_every:
            self.recorder.open_video(1.0 / (self.sim.timestep * self._video_every), tuple(rec.get("video_size", [320, 240])))
            first = self.sim.render_sample()
            if first is not None:  # the video is rendered from state samples once the attempt is over
                self._video_samples = [first]
                self.clock.callbacks.append(self._video_sample)
            else:  # a simulator that cannot render from samples: frames rendered in the loop
                self.recorder.video.add(self.sim.render(RECORD_CAMERA))
                self.clock.callbacks.append(self._video_frame)
        self.registry = build_registry()
        self.recorder.write_private("scene_info.json", {"task": spec.task, "seed": spec.seed, "info": self.instance.info,
                                                        "objects": self.sim.object_names(),
                                                        "perturbation": self.perturbation})
        self._snapshot("start")
        self.setup_seconds = time.monotonic() - t0
        self.recorder.event("attempt_start", task=spec.task, seed=spec.seed, attempt=spec.attempt,
                            instruction=self.task.info.instruction, budget=self.ledger.remaining(),
                            setup_seconds=round(self.setup_seconds, 3), config=spec.as_record())

    def _video_frame(self, step: int) -> None:
        if step % self._video_every == 0 and self.recorder.video is not None:
            self.recorder.video.add(self.sim.render(RECORD_CAMERA))

    def _video_sample(self, step: int) -> None:
        """What the video frame of this step takes, kept for later (:meth:`Simulator.render_sample`:
        a read that changes nothing, a few microseconds): rendering 320x240 costs more than the
        25 physics steps between two frames, so it is kept out of the motion loop."""
        if step % self._video_every == 0 and self._video_samples is not None:
            self._video_samples.append(self.sim.render_sample())

    def _render_video(self) -> None:
        """The frames of the samples taken during the attempt, rendered and encoded now that its
        physics is over: the same frames the loop would have rendered, bit for bit
        (:meth:`Simulator.render_samples`), and the world is left as it was."""
        samples, self._video_samples = self._video_samples, None
        if not samples or self.recorder.video is None:
            return
        t0 = time.monotonic()
        try:
            self.sim.render_samples(RECORD_CAMERA, samples, self.recorder.video.add)
        except Exception as e:  # never lose the attempt because its video failed
            self.recorder.event("video_error", error=repr(e), traceback=traceback.format_exc())
        self._video_render_seconds = time.monotonic() - t0

    def _on_observation(self, obs) -> None:
        self.recorder.save_observation(obs)

    def _snapshot(self, label: str) -> None:
        objs = {}
        for n in self.sim.object_names():
            objs[n] = {"pose": np.round(self.sim.get_object_pose(n), 6).tolist()}
            q = self.sim.get_object_qpos(n)
            if len(q):
                objs[n]["qpos"] = np.round(q, 6).tolist()
                objs[n]["links"] = {l: np.round(self.sim.get_object_link_pose(n, l), 6).tolist()
                                    for l in self.sim.get_object_link_names(n)}
        contacts = [[c.a, c.b, round(float(c.impulse), 7)] for c in self.sim.get_contacts() if c.impulse > 1e-6]
        arms = {a: {"tcp_pose": np.round(self.ctx.tcp_pose(a), 6).tolist(), "gripper_cmd": self.ctx.gripper_cmd[a],
                    "finger_gap_m": round(self.ctx.finger_gap(a), 5)} for a in sorted(self.emb.arms)}
        self.recorder.snapshot(label, {"physics_step": self.clock.steps, "tick": self.ctx.tick, "calls": self._calls,
                                       "objects": objs, "arms": arms, "contacts": contacts,
                                       "latched": bool(self.verdict.latched) if hasattr(self, "verdict") else False})

    # -- the session API ----------------------------------------------------------------------
    @property
    def instruction(self) -> str:
        return self.task.info.instruction

    def tool_specs(self) -> list[dict]:
        return [t.spec() for t in self.registry.values()]

    def image(self, obs_id: str) -> np.ndarray:
        return self.obs.get(obs_id).image

    def call(self, name: str, args: dict | None = None) -> ToolResponse:
        """One direct tool call by the agent (charged, except ``done``)."""
        if self.ended:
            raise AttemptEnded(f"the attempt has ended ({self.termination['reason']})")
        args = {} if args is None else (dict(args) if isinstance(args, dict) else args)  # a non-object is refused below
        t0 = time.monotonic()
        steps0 = self.clock.steps
        if name == "done":
            return self._done(args, t0)
        try:
            self.ledger.check_before_call()
        except BudgetExhausted as e:
            self._end(e.reason, str(e))
            payload = {"error": "budget exhausted", "reason": e.reason, "message": str(e), "attempt_ended": True}
            self.recorder.event("call_refused", tool=name, arguments=args, result=payload)
            return ToolResponse(name, payload, [], ended=True)
        self.ledger.charge_call()
        self._calls += 1
        out_obs: list[str] = []
        status = None
        try:
            payload, out_obs, status = self._invoke(name, args, direct=True)
        except Exception as e:  # only an infrastructure fault gets here (cab_core.faults)
            self.recorder.event("host_fault", tool=name, arguments=args, error=repr(e), traceback=traceback.format_exc())
            self._end("host_fault", f"{name}: {e!r}")
            payload = {"error": "the host failed (not your doing); the attempt has ended", "attempt_ended": True}
            return ToolResponse(name, payload, [], ended=True)
        payload["budget"] = self.ledger.remaining()
        reason = self.ledger.exhausted_reason()
        if reason == "sim_budget" or reason == "wall_budget":
            payload["budget"]["note"] = f"{reason.replace('_', ' ')} spent: the attempt has ended"
        self.recorder.event("call", tool=name, arguments=args, result=payload, obs_ids=out_obs, status=status,
                            physics_steps=self.clock.steps - steps0, physics_step_end=self.clock.steps,
                            sim_seconds=round((self.clock.steps - steps0) * self.sim.timestep, 4),
                            wall_seconds=round(time.monotonic() - t0, 4), tick=self.ctx.tick)
        if self.clock.steps != steps0:
            self._snapshot(f"after_call_{self._calls}")
        ended = False
        if reason in ("sim_budget", "wall_budget"):
            self._end(reason, payload["budget"]["note"])
            ended = True
        return ToolResponse(name, payload, out_obs, ended=ended, status=status)

    def _invoke(self, name: str, args: Any, direct: bool) -> tuple[dict, list[str], str | None]:
        """Validate and run one tool; the fault rule of :mod:`cab_core.faults` applies. Argument
        errors and any other exception raised while serving the call become the typed error payload
        the agent sees (recorded, the attempt goes on); only an infrastructure fault propagates.
        Inside programs, run_code and done do not exist."""
        try:
            return self._serve(name, args, direct)
        except Exception as e:
            if is_infrastructure_fault(e):
                raise
            self.tool_errors += 1
            self.recorder.event("tool_error", tool=name, direct=direct, error=repr(e), traceback=traceback.format_exc())
            return tool_error_payload(name, e), [], None

    def _serve(self, name: str, args: Any, direct: bool) -> tuple[dict, list[str], str | None]:
        from .tools import validate_args

        try:
            if name not in self.registry or (not direct and name in ("run_code", "done")):
                raise ToolArgumentError(f"unknown tool {name!r}")
            model = validate_args(name, args)
            if name == "run_code":
                return self._run_code(model.code)
            out = self.registry[name].resolve()(self.ctx, model)
            return dict(out.payload), list(out.obs_ids), out.status
        except ToolArgumentError as e:
            msg = str(e)
            return ({"error": msg if msg.startswith(("bad arguments", "unknown tool")) else f"bad arguments: {msg}",
                     "code": "invalid_tool_arguments"}, [], None)
        except ObservationUnavailable as e:
            return ({"error": f"observation unavailable: {e}", "code": "observation_unavailable", "available": False},
                    [], None)

    def _done(self, args: Any, t0: float) -> ToolResponse:
        from .tools import validate_args

        try:
            model = validate_args("done", args)
        except ToolArgumentError as e:
            payload = {"error": str(e), "code": "invalid_tool_arguments"}
            self.recorder.event("call", tool="done", arguments=args, result=payload, charged=False)
            return ToolResponse("done", payload, [])
        self.claim = {"success_claim": model.success_claim, "report": model.report}
        payload = {"ok": True, "note": "episode ended; attempt recorded."}
        self.recorder.event("call", tool="done", arguments=args, result=payload, charged=False,
                            wall_seconds=round(time.monotonic() - t0, 4))
        self._end("done", "the agent called done")
        return ToolResponse("done", payload, [], ended=True)

    # -- run_code -----------------------------------------------------------------------------
    def _ensure_sandbox(self):
        if self.sandbox is None:
            from .sandbox import Sandbox, SandboxConfig

            cfg = SandboxConfig(**{k: v for k, v in (self.spec.sandbox or {}).items()})
            cfg.max_internal_calls = self.spec.run_code_max_internal_calls
            names = [n for n in self.registry if n not in ("run_code", "done")]
            self.sandbox = Sandbox(names, self._dispatch_internal, self.image, cfg)
        return self.sandbox

    def _dispatch_internal(self, name: str, kwargs: dict):
        from .sandbox import DispatchResult

        steps0 = self.clock.steps
        reason = self.ledger.exhausted_reason()
        if reason in ("sim_budget", "wall_budget"):
            return DispatchResult({"error": "budget exhausted", "reason": reason}, [], ended=True)
        payload, obs_ids, status = self._invoke(name, kwargs, direct=False)
        self.recorder.event("internal_call", tool=name, arguments=kwargs, result=payload, obs_ids=obs_ids, status=status,
                            physics_steps=self.clock.steps - steps0, physics_step_end=self.clock.steps, tick=self.ctx.tick)
        if self.clock.steps != steps0:
            self._snapshot(f"internal_{name}")
        return DispatchResult(payload, obs_ids, aborted=(status == "ABORTED"),
                              ended=self.ledger.exhausted_reason() in ("sim_budget", "wall_budget"))

    def _run_code(self, code: str):
        rel = self.recorder.save_program(code)
        sb = self._ensure_sandbox()
        res = sb.run(code)
        res["program"] = rel.split("/")[-1]
        images = list(res.get("images") or [])
        status = res.get("status")
        return res, images, status

    # -- the end ------------------------------------------------------------------------------
    def _end(self, reason: str, detail: str = "") -> None:
        if not self.ended:
            self.ended = True
            self.termination = {"reason": reason, "detail": detail}

    def end(self, reason: str, detail: str = "") -> None:
        """Harness-side ending (agent stopped, provider failure...)."""
        self._end(reason, detail)

    def finish(self) -> dict:
        """Score and write ``result.json`` (atomically). Idempotent."""
        if self.result is not None:
            return self.result
        if not self.ended:
            self._end("no_done", "the agent stopped without calling done")
        try:
            verdict = self.verdict.final()
        except Exception as e:  # never lose the attempt because scoring failed
            verdict = {"success": False, "error": repr(e)}
        self._snapshot("end")
        self._render_video()
        checkpoints = self._checkpoints(verdict)
        if self.sandbox is not None:
            self.sandbox.close()
        s = self.spec
        self.result = {
            "record_version": RECORD_VERSION,
            "task": s.task, "seed": s.seed, "attempt": s.attempt, "sim": s.sim, "embodiment": s.embodiment,
            "planner": s.planner, "model": s.model, "harness": s.harness,
            **({"agent": self.agent} if self.agent is not None else {}),
            "instruction": self.task.info.instruction,
            "scoring": self.verifier.scoring,
            **({"perturbation": self.perturbation} if self.perturbation is not None else {}),
            "verdict": verdict,
            "termination": self.termination,
            "claim": self.claim,
            "budget": self.ledger.summary(),
            "timing": {"wall_seconds": round(time.monotonic() - self._t_start, 3),
                       "setup_seconds": round(self.setup_seconds, 3)},
            "counts": {"charged_calls": self._calls, "observations": len(self.obs._obs),
                       "tool_errors": self.tool_errors},
            "sandbox": {"confinement": getattr(self.sandbox, "confinement", None),
                        "layers": getattr(self.sandbox, "confinement_layers", None),
                        "note": getattr(self.sandbox, "confinement_note", None)},
            "versions": self.versions(),
            "checkpoints": checkpoints,
            "video": {"file": "video.mp4", "frames": self.recorder.video.frames, "every_steps": self._video_every,
                      "rendered": "in the loop" if self._video_render_seconds is None else "after the attempt",
                      **({} if self._video_render_seconds is None
                         else {"render_seconds": round(self._video_render_seconds, 3)})}
            if self.recorder.video else None,
        }
        self.recorder.event("attempt_end", termination=self.termination, claim=self.claim)
        self.recorder.finish(self.result)
        return self.result

    def _checkpoints(self, verdict: dict) -> dict | None:
        """Subgoal and spatial checkpoints of this attempt, from its own records."""
        if not hasattr(self.task, "subgoals"):
            return None
        from .analysis.checkpoints import evaluate, load_snapshots

        try:
            latched = bool((verdict.get("latch") or {}).get("latched"))
            return evaluate(self.task, self.emb, self.instance.info, load_snapshots(self.out), latched).as_dict()
        except Exception as e:  # analysis must never lose the attempt
            return {"error": repr(e)}

    def versions(self) -> dict:
        from .plugins import distribution_versions

        pk = distribution_versions()  # the core's own and the installed plugins' distributions
        for d in ("numpy", "pydantic", "hydra-core", "pluggy"):
            try:
                pk[d] = metadata.version(d)
            except metadata.PackageNotFoundError:
                pass
        return {"cab": __version__, "python": platform.python_version(), "platform": platform.platform(),
                "simulator": self.sim.versions(), "planner": self.planner.versions(), "packages": pk,
                "numerics": numerics.describe()}

    def close(self) -> None:
        try:
            if self.result is None:
                self.finish()
        finally:
            try:
                self.sim.close()
            except Exception:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def run_code(ctx, args):  # pragma: no cover - dispatched by the Episode itself
    raise CabError("run_code is executed by the episode host, not through the registry")


def done(ctx, args):  # pragma: no cover - dispatched by the Episode itself
    raise CabError("done is executed by the episode host, not through the registry")
