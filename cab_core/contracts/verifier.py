"""The hidden verifier: privileged read-only world view, named sub-predicates, final-state and
latched-event scoring. Nothing here ever reaches a tool result."""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.embodiment import EmbodimentSpec
    from cab_core.contracts.simulator import Contact, WorldReads

Scoring = Literal["final", "latch"]


class WorldView:
    """Privileged, read-only access to the world for verifiers, checkpoints and oracles.

    ``gripper_command(arm)`` is the last *commanded* normalised gripper value (1 open, 0 closed),
    which is what the paper's gripper predicates read (FACTS B.3).
    """

    def __init__(self, sim: WorldReads, embodiment: EmbodimentSpec, gripper_commands: dict[str, float],
                 info: dict | None = None):
        self._sim = sim
        self._emb = embodiment
        self._grip = gripper_commands
        self.info = info or {}  # task-specific privileged facts (functional points, table z, ...)
        #: the world at the attempt's start, once settled: ``{"objects": {name: pose}, "tcp": {arm:
        #: pose}}`` (numpy poses); None where unknown (a world rebuilt from a snapshot)
        self.start: dict | None = None

    def remember_start(self) -> None:
        """Keep the world as it is now as :attr:`start`."""
        self.start = {"objects": {n: self.pose(n) for n in self.object_names()},
                      "tcp": {a: self.tcp_pose(a) for a in self._emb.arms}}

    def object_names(self) -> list[str]:
        return list(self._sim.object_names())

    def pose(self, name: str) -> np.ndarray:
        return self._sim.get_object_pose(name)

    def qpos(self, name: str) -> np.ndarray:
        return self._sim.get_object_qpos(name)

    def link_pose(self, name: str, link: str) -> np.ndarray:
        return self._sim.get_object_link_pose(name, link)

    def tcp_pose(self, arm: str) -> np.ndarray:
        return self._sim.get_link_pose(self._emb.arms[arm].tcp_link)

    def gripper_command(self, arm: str) -> float:
        return float(self._grip[arm])

    def contacts(self) -> list[Contact]:
        return self._sim.get_contacts()

    def in_contact(self, a: str, b: str, min_impulse: float = 0.0) -> bool:
        """Whether body ``a`` touches ``b``; either may be a prefix such as ``"robot/"`` or
        ``"microwave/"``."""
        for c in self._sim.get_contacts():
            if c.impulse <= min_impulse:
                continue
            if (_match(c.a, a) and _match(c.b, b)) or (_match(c.a, b) and _match(c.b, a)):
                return True
        return False

    def gripper_touches(self, arm: str, obj: str) -> bool:
        links = {f"robot/{link}" for link in self._emb.arms[arm].gripper.finger_links}
        for c in self._sim.get_contacts():
            if c.impulse <= 0:
                continue
            if (c.a in links and _match(c.b, obj)) or (c.b in links and _match(c.a, obj)):
                return True
        return False


    def gripper_holds(self, arm: str, obj: str) -> bool:
        """Every finger of ``arm``'s gripper touches ``obj`` (one finger touching is a push, not
        a hold)."""
        fingers = {f"robot/{link}" for link in self._emb.arms[arm].gripper.finger_links}
        touching = set()
        for c in self._sim.get_contacts():
            if c.impulse <= 0:
                continue
            if c.a in fingers and _match(c.b, obj):
                touching.add(c.a)
            elif c.b in fingers and _match(c.a, obj):
                touching.add(c.b)
        return bool(fingers) and touching == fingers


def _match(name: str, pattern: str) -> bool:
    return name == pattern or (pattern.endswith("/") and name.startswith(pattern)) or name.startswith(pattern + "/")


#: a verdict whose deciding margin is within this fraction of its tolerance is flagged borderline:
#: a difference of a tenth of a tolerance is what another machine's physics can plausibly make
BORDERLINE_FRACTION = 0.10


@dataclass(frozen=True)
class Margin:
    """How far a predicate's measured quantity is inside (``slack > 0``: the predicate holds) or
    outside (``slack < 0``) its threshold, in the quantity's own ``unit``; ``scale`` is the tolerance
    it is judged against (positive, same unit), so ``fraction = slack / scale`` compares predicates
    of different units. ``slack == 0`` is exactly on the threshold."""
    slack: float
    scale: float
    unit: str
    measured: float | None = None
    threshold: float | None = None

    @property
    def fraction(self) -> float:
        return self.slack / self.scale

    def as_record(self) -> dict:
        return {"slack": float(self.slack), "scale": float(self.scale), "fraction": float(self.fraction),
                "unit": self.unit, "measured": None if self.measured is None else float(self.measured),
                "threshold": None if self.threshold is None else float(self.threshold)}


def _scale(threshold: float, scale: float | None) -> float:
    s = abs(float(threshold)) if scale is None else abs(float(scale))
    return s if s > 0 else 1.0


def margin_below(measured: float, threshold: float, unit: str, scale: float | None = None) -> Margin:
    """The margin of ``measured < threshold`` (``scale``: the tolerance; default ``|threshold|``)."""
    return Margin(float(threshold) - float(measured), _scale(threshold, scale), unit, float(measured), float(threshold))


def margin_above(measured: float, threshold: float, unit: str, scale: float | None = None) -> Margin:
    """The margin of ``measured > threshold`` (``scale``: the tolerance; default ``|threshold|``)."""
    return Margin(float(measured) - float(threshold), _scale(threshold, scale), unit, float(measured), float(threshold))


def margin_within(deviations: Iterable[float], tolerance: float | Sequence[float] | np.ndarray, unit: str) -> Margin:
    """The margin of ``all(|d_i| < tol_i)``: the component closest to its tolerance, relative to
    that tolerance (one tolerance for all components, or one each)."""
    d = np.abs(np.asarray(list(deviations), dtype=float))
    tol = np.broadcast_to(np.asarray(tolerance if np.ndim(tolerance) else [tolerance], dtype=float), d.shape)
    i = int(np.argmin((tol - d) / tol))
    return Margin(float(tol[i] - d[i]), float(tol[i]), unit, float(d[i]), float(tol[i]))


def margin_all(*margins: Margin) -> Margin:
    """The margin of a conjunction: its tightest part (the first to flip)."""
    return min(margins, key=lambda m: m.fraction)


def margin_any(*margins: Margin) -> Margin:
    """The margin of a disjunction: its widest part."""
    return max(margins, key=lambda m: m.fraction)


@dataclass
class Evaluation:
    success: bool
    predicates: dict[str, bool] = field(default_factory=dict)
    values: dict[str, float] = field(default_factory=dict)  # measured quantities, for records
    #: per predicate with a numeric threshold, how far inside or outside it; a predicate that is an
    #: event without a threshold (a contact exists) has none
    margins: dict[str, Margin] = field(default_factory=dict)


def deciding_margin(predicates: dict[str, bool], margins: dict[str, Margin], success: bool) -> dict:
    """What decided a verdict and by how much. A success flips when any one of its predicates does:
    its margin is the smallest. A failure flips only when every failing predicate does: its margin is
    the largest among them, and a failing predicate without a threshold cannot flip by a small
    difference (no margin, never borderline). ``borderline``: ``|fraction| < BORDERLINE_FRACTION``."""
    if success:
        cands = {k: margins[k] for k, ok in predicates.items() if ok and k in margins}
        pick = min(cands, key=lambda k: cands[k].fraction) if cands else None
    else:
        failing = [k for k, ok in predicates.items() if not ok]
        if not failing or any(k not in margins for k in failing):
            pick = None
        else:
            pick = max(failing, key=lambda k: -margins[k].fraction)
    if pick is None:
        return {"predicate": None, "fraction": None, "borderline": False, "threshold": BORDERLINE_FRACTION}
    f = float(margins[pick].fraction)
    return {"predicate": pick, "fraction": f, "borderline": bool(abs(f) < BORDERLINE_FRACTION),
            "threshold": BORDERLINE_FRACTION}


class Verifier(ABC):
    """One task's success check. ``evaluate`` is the task's predicate with its named sub-predicates.

    For ``scoring == "latch"`` the host polls ``holds`` every ``poll_every`` physics steps and
    latches success the first time it holds (an event already true at the start is voided);
    ``final_requirements`` must also hold at the end. For ``"final"`` only the end state counts.
    """

    scoring: Scoring = "final"
    poll_every: int = 1
    #: objects whose fall off the table fails the attempt (guard)
    guarded_objects: tuple[str, ...] = ()
    #: world z below which a guarded object counts as knocked off the table
    guard_min_z: float = 0.66
    #: the tolerance a guard's margin is judged against (how far below the table top is "off")
    guard_scale_m: float = 0.08

    @abstractmethod
    def evaluate(self, w: WorldView) -> Evaluation: ...

    def holds(self, w: WorldView) -> bool:
        """``evaluate(w).success``: what latch polling asks every ``poll_every`` physics steps.
        A task may answer it more cheaply (its cheapest predicate first, stopping at the first
        that fails), never differently."""
        return bool(self.evaluate(w).success)

    def final_requirements(self, w: WorldView) -> dict[str, bool]:
        return {}

    def final_requirement_margins(self, w: WorldView) -> dict[str, Margin]:
        """The margins of ``final_requirements`` that have a threshold."""
        return {}

    def guard(self, w: WorldView) -> dict[str, bool]:
        """``<object>_on_table`` for each guarded object."""
        return {f"{o}_on_table": bool(w.pose(o)[2] >= self.guard_min_z) for o in self.guarded_objects}

    def guard_margins(self, w: WorldView) -> dict[str, Margin]:
        return {f"{o}_on_table": margin_above(float(w.pose(o)[2]), self.guard_min_z, "m", self.guard_scale_m)
                for o in self.guarded_objects}
