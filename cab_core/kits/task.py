"""The bases of a table-top task: :class:`SceneTask` (a task laid out on the base scene, with its
own metadata), the final-state verifier that also wants the grippers open, and the latched
verifier. A task written on them declares its :class:`~cab_core.contracts.task.TaskInfo`; nothing
here looks a task up in any suite's catalog."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from cab_core.contracts.scene import SceneSpec
from cab_core.contracts.task import SceneInstance, Task, TaskInfo, ToolCaller, rng_for
from cab_core.contracts.verifier import Evaluation, Margin, Verifier, WorldView
from cab_core.errors import PluginError

from .margins import grippers_open
from .oracle import resume
from .scene import ARMS, base_scene, body_reach, table_top_z


# --- verifiers ---------------------------------------------------------------------------------
class GrippersOpenVerifier(Verifier):
    """A final-state verifier whose success needs the task's own predicates (``measure``) and,
    recorded after them, ``grippers_open``: every one of ``arms`` has its gripper commanded above
    ``open_threshold``."""

    arms: Sequence[str] = ARMS
    open_threshold: float = 0.8

    def measure(self, w: WorldView) -> tuple[dict[str, bool], dict[str, float], dict[str, Margin]]:
        """The task's own predicates, the values measured and the predicates' margins."""
        raise NotImplementedError

    def evaluate(self, w: WorldView) -> Evaluation:
        preds, values, margins = self.measure(w)
        preds["grippers_open"], grips, margins["grippers_open"] = grippers_open(w, self.arms, self.open_threshold)
        values.update(grips)
        return Evaluation(success=all(preds.values()), predicates=preds, values=values, margins=margins)


class LatchVerifier(Verifier):
    """A verifier scored by latch: the attempt succeeds once ``holds`` is true, polled at every
    physics step."""

    scoring = "latch"
    poll_every = 1


def arm_names(embodiment: Any) -> list[str]:
    """The embodiment's arm names (tasks read declarations, never a robot's name)."""
    arms = getattr(embodiment, "arms", None)
    return sorted(arms) if arms else list(ARMS)


# --- task base ---------------------------------------------------------------------------------
class SceneTask(Task):
    """A task laid out on the base scene (table, wall, lighting): it declares its metadata,
    ``info = TaskInfo(...)`` on its class (or ``self.info`` set in its own ``__init__``), and its
    ``name`` is the metadata's unless the class sets one. It lays out its objects on the base scene
    (``lay_out``), names its verifier (``verifier_class``) and its subgoals' predicates
    (``subgoal_predicates``), and writes its reference solution (``solve``), which ``oracle`` runs
    from whatever state the world is in (:func:`cab_core.kits.oracle.resume`)."""

    name: str = ""
    #: the task's verifier class, built from a scene's info (``verifier`` and ``evaluate`` use it)
    verifier_class: Callable[[dict[str, Any]], Verifier]
    #: the subgoals, in the order of ``info.subgoals``: each holds when all of these verifier
    #: predicates do
    subgoal_predicates: tuple[tuple[str, ...], ...] = ()
    #: the table's placement in the base scene (``base_scene``), metres
    table_x: float = 0.0
    table_z_bias: float = 0.0

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        declared = cls.__dict__.get("info")
        if not cls.__dict__.get("name") and isinstance(declared, TaskInfo):
            cls.name = declared.name

    def __init__(self) -> None:
        declared = getattr(type(self), "info", None)
        if not isinstance(declared, TaskInfo):
            cls = type(self)
            raise PluginError(
                f"task {self.name or cls.__qualname__!r} ({cls.__module__}.{cls.__qualname__}, a SceneTask) has no "
                "metadata: declare it on the class as info = TaskInfo(name=..., instruction=..., seed=..., "
                "scoring=..., budget_tool_calls=..., budget_sim_s=...) (cab_core.contracts.task), or set self.info "
                "in __init__")
        self.info: TaskInfo = declared

    def build(self, seed: int, embodiment: Any = None) -> SceneInstance:
        """The base scene (table, wall, lighting) with the objects ``lay_out`` adds; the info starts
        with the task, the seed and the table top's height, followed by what ``lay_out`` returns."""
        top = table_top_z(self.table_z_bias)
        scene = base_scene(self.table_x, self.table_z_bias)
        info = self.lay_out(rng_for(seed, self.name), top, scene, embodiment)
        return SceneInstance(scene=scene, info={"task": self.name, "seed": int(seed), "table_top_z": top, **info})

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        """Add the task's objects to ``scene``, drawing their layout from ``rng`` (the table top is at
        height ``top``); returns what the scene's info records about them."""
        raise NotImplementedError(f"{self.name} lays out no scene")

    def verifier(self, instance: SceneInstance) -> Verifier:
        return self.verifier_class(instance.info)

    def evaluate(self, w: WorldView) -> Evaluation:
        """The verifier's evaluation of the world as ``w`` sees it now."""
        return self.verifier_class(w.info).evaluate(w)

    def subgoals(self, w: WorldView) -> list[bool]:
        """The subgoals as ``w`` sees the world now (``subgoal_predicates``)."""
        p = self.evaluate(w).predicates
        return [all(p[n] for n in names) for names in self.subgoal_predicates]

    def oracle(self, call: ToolCaller, world: WorldView) -> None:
        """The reference solution from any reachable state (:func:`cab_core.kits.oracle.resume`):
        what is already achieved is not done again, hands an earlier agent left busy are cleared
        first, and a state it cannot complete from is reported (``NotRecoverable``) with its reason."""
        resume(self, call, world)

    #: free places for distractor objects (appearance randomisation): the back corners of the part
    #: of the table the head camera sees, far from the robot, (x offset from the table's centre,
    #: y); each kept only where no object of the instance is near
    DISTRACTOR_PLACES = ((-0.36, 0.26), (0.36, 0.26), (-0.30, 0.14), (0.30, 0.14))
    DISTRACTOR_CLEARANCE = 0.12  # m between a distractor's place and the reach of any object of the task

    def distractor_slots(self, instance: SceneInstance) -> list[tuple[float, float, float]]:
        top = float(instance.info["table_top_z"])
        reach = [(np.asarray(b.pose[:2], float), body_reach(b)) for b in instance.scene.bodies
                 if b.name not in ("table", "wall")]
        reach += [(np.asarray(a.pose[:2], float), 0.3) for a in instance.scene.articulations]
        out = []
        for dx, y in self.DISTRACTOR_PLACES:
            p = np.array([self.table_x + dx, y])
            if all(np.linalg.norm(p - c) > r + self.DISTRACTOR_CLEARANCE for c, r in reach):
                out.append((float(p[0]), float(p[1]), top))
        return out

    def keeps_hands(self, world: WorldView) -> bool:
        """Whether ``solve`` goes on from the hands as they are now (holding, closed, away from
        their start); False: :func:`cab_core.kits.oracle.resume` puts down what is held and takes
        the hands back to their start first."""
        return False

    def not_recoverable(self, world: WorldView) -> tuple[str, str] | None:
        """``(kind, reason)`` when ``solve`` cannot start from this state (kinds:
        ``cab_core.contracts.task.NOT_RECOVERABLE_KINDS``), e.g. an object it takes standing lies
        on its side; None: it can."""
        return None

    def solve(self, call: ToolCaller, world: WorldView) -> None:
        """The reference solution from the scene's start (or a state like it: objects where they
        can be taken, hands free), its targets computed from the objects' poses now."""
        raise NotImplementedError(f"the reference solution of {self.name} is not written yet")

    def __repr__(self) -> str:
        return f"<task {self.name}>"
