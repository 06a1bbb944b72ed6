"""Finishing one attempt: the hidden verdict (final state, or an event latched while the attempt
ran), the checkpoints attained, and the content of ``result.json``."""
from __future__ import annotations

import platform
from importlib import metadata
from typing import TYPE_CHECKING

from cab_core import __version__, numerics
from cab_core.attempt.engine.checkpoint_scoring import evaluate, load_snapshots
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, deciding_margin
from cab_core.plugins import distribution_versions

if TYPE_CHECKING:  # pragma: no cover
    from pathlib import Path

    from cab_core.attempt.engine.world import BuiltWorld


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
            assert self.latched_at_step is not None  # set with latched
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


def attempt_checkpoints(world: BuiltWorld, out: Path, verdict: dict) -> dict | None:
    """Subgoal and spatial checkpoints of this attempt, from its own records (None: the task
    declares none)."""
    if not hasattr(world.task, "subgoals"):
        return None
    try:
        latched = bool((verdict.get("latch") or {}).get("latched"))
        return evaluate(world.task, world.emb, world.instance.info, load_snapshots(out), latched).as_dict()
    except Exception as e:  # analysis must never lose the attempt
        return {"error": repr(e)}


def versions(sim, planner) -> dict:
    """What ran this attempt: cab, Python, the platform, the simulator's and planner's own report,
    the installed distributions, the pinned numerics."""
    pk = distribution_versions()  # the core's own and the installed plugins' distributions
    for d in ("numpy", "pydantic", "hydra-core", "pluggy"):
        try:
            pk[d] = metadata.version(d)
        except metadata.PackageNotFoundError:
            pass
    return {"cab": __version__, "python": platform.python_version(), "platform": platform.platform(),
            "simulator": sim.versions(), "planner": planner.versions(), "packages": pk,
            "numerics": numerics.describe()}
