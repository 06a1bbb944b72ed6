"""The task contract. One task per module in a suite; tasks read embodiment declarations and never
test a robot's name. Instructions, seeds, scoring and budgets are the suite's (``Task.info``); the
core reads them only through the task-suite hook (cab_core.plugins.task_info)."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from cab_core.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.embodiment import EmbodimentSpec
    from cab_core.contracts.scene import SceneSpec
    from cab_core.contracts.verifier import Verifier, WorldView


@dataclass(frozen=True)
class TaskInfo:
    name: str
    instruction: str
    seed: int
    scoring: str  # "final" | "latch"
    budget_tool_calls: int
    budget_sim_s: float
    category: str = ""
    reference_solution_api_calls: int | None = None
    reference_solution_sim_s: float | None = None
    subgoals: tuple[str, ...] = ()
    spatial_checkpoints: tuple[dict, ...] = ()

    @property
    def budget_wall_s(self) -> float:
        return 60.0 * self.budget_tool_calls


@dataclass
class SceneInstance:
    """A built scene plus the privileged facts the verifier and oracle need (functional points,
    which arm is on which side, the drawn layout...). ``info`` is JSON-serialisable."""
    scene: SceneSpec
    info: dict[str, Any] = field(default_factory=dict)


class NotRecoverable(Exception):
    """Raised by a reference solution that cannot complete the task from the state it was given
    (a fork's, :mod:`cab_core.attempt.fork`): ``kind`` one of :data:`NOT_RECOVERABLE_KINDS`,
    ``reason`` in words, ``stages`` what the solution found already achieved. The oracle agent ends
    the attempt with ``done`` (no success claimed), the reason in its report and the record."""

    def __init__(self, kind: str, reason: str, stages: dict | None = None):
        super().__init__(f"{kind}: {reason}")
        self.kind, self.reason, self.stages = kind, reason, dict(stages or {})


#: why a state is not recoverable: an object fell off the table; a budget is too small for what is
#: left; an object lies where the reference solution cannot take it (tipped over, out of reach);
#: the reference solution failed from this state; it ran to its end but the task does not hold
NOT_RECOVERABLE_KINDS = ("off_table", "budget", "unreachable", "plan_failed", "plan_incomplete")


class ToolCaller(Protocol):
    """How an oracle acts: exactly the public tools, by name, with JSON arguments."""

    def __call__(self, tool: str, **kwargs: Any) -> dict: ...


class Task(ABC):
    """Life cycle: ``build(seed)`` once per attempt; the host builds the world, settles it, then
    the agent acts; the verifier scores."""

    info: TaskInfo
    #: named sets of scene seeds besides the catalog's, e.g. ``{"heldout": (100, ..., 119)}``: seeds
    #: whose instances the task's author checked (oracle success with margin on every simulator)
    seed_sets: dict[str, tuple[int, ...]] = {}

    def seeds(self, seed_set: str) -> tuple[int, ...]:
        """The seeds of ``seed_set``; ``"catalog"`` is the catalog's fixed seed."""
        if seed_set == "catalog":
            return (self.info.seed,)
        if seed_set not in self.seed_sets:
            known = ", ".join(["catalog", *self.seed_sets])
            raise ConfigError(f"task {self.info.name} has no seed set {seed_set!r}; its sets: {known}")
        return tuple(self.seed_sets[seed_set])

    @abstractmethod
    def build(self, seed: int, embodiment: EmbodimentSpec) -> SceneInstance:
        """The scene for ``seed``. Deterministic: the same seed gives the same scene."""

    @abstractmethod
    def verifier(self, instance: SceneInstance) -> Verifier: ...

    @abstractmethod
    def oracle(self, call: ToolCaller, world: WorldView) -> None:
        """The reference solution: reads privileged state from ``world`` only to compute targets,
        acts only through ``call`` (public tools), and ends with ``call("done", ...)``.

        It must work from any state an attempt can reach, not only the scene's start (a fork of
        an attempt, :mod:`cab_core.attempt.fork`, hands it the state after any call): decide which
        of its stages are already achieved (``world.start`` holds the world at the attempt's
        start), complete the rest, or raise :class:`NotRecoverable` with the reason."""

    def distractor_slots(self, instance: SceneInstance) -> list[tuple[float, float, float]]:
        """Free places ``(x, y, z of the supporting surface)`` for distractor objects (appearance
        randomisation, :mod:`cab_core.attempt.variation.randomize`): where no verifier, checkpoint or
        reference solution of this instance looks or moves. None offered: no distractors."""
        return []

    def settle_steps(self) -> int:
        """Physics steps run at reset before the agent starts (not charged)."""
        return 100


def rng_for(seed: int, task: str) -> np.random.Generator:
    """The one RNG a task draws its scene from: seeded by (task, seed), independent of globals."""
    import hashlib

    h = int.from_bytes(hashlib.sha256(f"{task}:{seed}".encode()).digest()[:8], "little")
    return np.random.default_rng(h)
