"""Serving the agent's calls during one attempt: validation, budgets, the fault rule, the sandbox
for ``run_code``, and the record of every call. The :class:`StepClock` is the only way physics
advances while an agent plays."""
from __future__ import annotations

import contextlib
import time
import traceback
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cab_core.attempt.budget import BudgetLedger
from cab_core.attempt.engine import cpu_slots
from cab_core.attempt.engine.faults import is_infrastructure_fault, tool_error_payload
from cab_core.contracts.harness import ToolResponse
from cab_core.errors import AttemptEnded, BudgetExhausted, ObservationUnavailable, ToolArgumentError
from cab_core.sandbox import DispatchResult, Sandbox, SandboxConfig
from cab_core.sandbox.truncate import strict_payload
from cab_core.tools import DoneArgs, RunCodeArgs, validate_args

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.attempt.records.writer import Recorder
    from cab_core.attempt.spec import AttemptSpec
    from cab_core.tools.context import RobotContext


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


class CallServer:
    """Serves one attempt's calls: the agent's direct calls (charged, except ``done``) and the
    internal calls of its programs. ``on_end(reason, detail)`` ends the attempt;
    ``on_physics(label)`` is called after a call that advanced physics (a snapshot)."""

    def __init__(self, spec: AttemptSpec, registry: dict, ctx: RobotContext, ledger: BudgetLedger,
                 clock: StepClock, recorder: Recorder, image: Callable[[str], Any],
                 on_end: Callable[[str, str], None], on_physics: Callable[[str], None], ended: Callable[[], bool]):
        self.spec, self.registry, self.ctx, self.ledger, self.clock = spec, registry, ctx, ledger, clock
        self.recorder, self._image, self._end, self._on_physics, self._ended = recorder, image, on_end, on_physics, ended
        self.calls = 0  # charged direct calls
        self.tool_errors = 0  # exceptions raised while serving the agent's calls (cab_core.attempt.engine.faults)
        self.claim: dict = {"success_claim": None, "report": None}
        self.sandbox: Sandbox | None = None  # started at the first run_code

    def call(self, name: str, args: dict | None, termination: Callable[[], dict | None]) -> ToolResponse:
        """One direct tool call by the agent (charged, except ``done``)."""
        if self._ended():
            ended_by = termination()
            assert ended_by is not None  # an attempt that has ended holds its termination
            raise AttemptEnded(f"the attempt has ended ({ended_by['reason']})")
        args = {} if args is None else (dict(args) if isinstance(args, dict) else args)  # a non-object is refused below
        t0 = time.monotonic()
        steps0 = self.clock.steps
        if name == "done":
            return self._done(args, t0)
        try:
            self.ledger.check_before_call()
        except BudgetExhausted as e:
            self._end(e.reason, str(e))
            payload: dict[str, Any] = {"error": "budget exhausted", "reason": e.reason, "message": str(e), "attempt_ended": True}
            self.recorder.event("call_refused", tool=name, arguments=args, result=payload)
            return ToolResponse(name, payload, [], ended=True)
        self.ledger.charge_call()
        self.calls += 1
        out_obs: list[str] = []
        status = None
        try:
            # a CPU slot while the call computes, none while the agent thinks (sweeps); a program holds one
            # per robot call it makes (_dispatch_internal), so a long program does not keep the others waiting
            with cpu_slots.held() if name != "run_code" else contextlib.nullcontext():
                payload, out_obs, status = self._invoke(name, args, direct=True)
            payload = strict_payload(payload)  # what the agent sees is strict JSON (NaN: null, noted)
        except Exception as e:  # only an infrastructure fault gets here (cab_core.attempt.engine.faults)
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
                            sim_seconds=round((self.clock.steps - steps0) * self.ctx.sim.timestep, 4),
                            wall_seconds=round(time.monotonic() - t0, 4), tick=self.ctx.tick)
        if self.clock.steps != steps0:
            self._on_physics(f"after_call_{self.calls}")
        ended = False
        if reason in ("sim_budget", "wall_budget"):
            self._end(reason, payload["budget"]["note"])
            ended = True
        return ToolResponse(name, payload, out_obs, ended=ended, status=status)

    def _invoke(self, name: str, args: Any, direct: bool) -> tuple[dict, list[str], str | None]:
        """Validate and run one tool; the fault rule of :mod:`cab_core.attempt.engine.faults` applies. Argument
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
        try:
            tool = self.registry.get(name)
            if tool is None or (not direct and tool.handler is None):  # no run_code or done inside programs
                raise ToolArgumentError(f"unknown tool {name!r}")
            model = validate_args(name, args)
            if name == "run_code":  # served here; done never reaches _serve (see call)
                assert isinstance(model, RunCodeArgs)  # the registry's run_code takes RunCodeArgs
                return self._run_code(model.code)
            out = tool.handler(self.ctx, model)
            return dict(out.payload), list(out.obs_ids), out.status
        except ToolArgumentError as e:
            msg = str(e)
            return ({"error": msg if msg.startswith(("bad arguments", "unknown tool")) else f"bad arguments: {msg}",
                     "code": "invalid_tool_arguments"}, [], None)
        except ObservationUnavailable as e:
            return ({"error": f"observation unavailable: {e}", "code": "observation_unavailable", "available": False},
                    [], None)

    def _done(self, args: Any, t0: float) -> ToolResponse:
        try:
            model = validate_args("done", args)
            assert isinstance(model, DoneArgs)  # the registry's done takes DoneArgs
        except ToolArgumentError as e:
            payload: dict[str, Any] = {"error": str(e), "code": "invalid_tool_arguments"}
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
            cfg = SandboxConfig(**{k: v for k, v in (self.spec.sandbox or {}).items()})
            cfg.max_internal_calls = self.spec.run_code_max_internal_calls
            names = [n for n, t in self.registry.items() if t.handler is not None]  # the robot tools
            self.sandbox = Sandbox(names, self._dispatch_internal, self._image, cfg)
        return self.sandbox

    def _dispatch_internal(self, name: str, kwargs: dict):
        steps0 = self.clock.steps
        reason = self.ledger.exhausted_reason()
        if reason in ("sim_budget", "wall_budget"):
            return DispatchResult({"error": "budget exhausted", "reason": reason}, [], ended=True)
        with cpu_slots.held():
            payload, obs_ids, status = self._invoke(name, kwargs, direct=False)
        payload = strict_payload(payload)
        self.recorder.event("internal_call", tool=name, arguments=kwargs, result=payload, obs_ids=obs_ids, status=status,
                            physics_steps=self.clock.steps - steps0, physics_step_end=self.clock.steps, tick=self.ctx.tick)
        if self.clock.steps != steps0:
            self._on_physics(f"internal_{name}")
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

    def close(self) -> None:
        if self.sandbox is not None:
            self.sandbox.close()
