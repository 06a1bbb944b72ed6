"""The hidden verifier: privileged read-only world view, named sub-predicates, final-state and
latched-event scoring. Nothing here ever reaches a tool result."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .embodiment import EmbodimentSpec
    from .simulator import Contact, Simulator

Scoring = Literal["final", "latch"]


class WorldView:
    """Privileged, read-only access to the world for verifiers, checkpoints and oracles.

    ``gripper_command(arm)`` is the last *commanded* normalised gripper value (1 open, 0 closed),
    which is what the paper's gripper predicates read (FACTS B.3).
    """

    def __init__(self, sim: "Simulator", embodiment: "EmbodimentSpec", gripper_commands: dict[str, float],
                 info: dict | None = None):
        self._sim = sim
        self._emb = embodiment
        self._grip = gripper_commands
        self.info = info or {}  # task-specific privileged facts (functional points, table z, ...)

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

    def contacts(self) -> list["Contact"]:
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
        links = {f"robot/{l}" for l in self._emb.arms[arm].gripper.finger_links}
        for c in self._sim.get_contacts():
            if c.impulse <= 0:
                continue
            if (c.a in links and _match(c.b, obj)) or (c.b in links and _match(c.a, obj)):
                return True
        return False


def _match(name: str, pattern: str) -> bool:
    return name == pattern or (pattern.endswith("/") and name.startswith(pattern)) or name.startswith(pattern + "/")


@dataclass
class Evaluation:
    success: bool
    predicates: dict[str, bool] = field(default_factory=dict)
    values: dict[str, float] = field(default_factory=dict)  # measured quantities, for records


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

    @abstractmethod
    def evaluate(self, w: WorldView) -> Evaluation: ...

    def holds(self, w: WorldView) -> bool:
        """``evaluate(w).success``: what latch polling asks every ``poll_every`` physics steps.
        A task may answer it more cheaply (its cheapest predicate first, stopping at the first
        that fails), never differently."""
        return bool(self.evaluate(w).success)

    def final_requirements(self, w: WorldView) -> dict[str, bool]:
        return {}

    def guard(self, w: WorldView) -> dict[str, bool]:
        """``<object>_on_table`` for each guarded object."""
        return {f"{o}_on_table": bool(w.pose(o)[2] >= self.guard_min_z) for o in self.guarded_objects}
