"""What the CodeActionBench tasks share beyond the task kit (:mod:`cab_core.kits`): the task base
that takes its metadata from the suite's catalog, and the suite's lift checkpoints.

The scene vocabulary, the verifier bases, the margins and the oracle helpers are the kit's
(``cab_core.kits.scene``, ``.assets``, ``.task``, ``.margins``, ``.oracle``, ``.stages``); the
suite's tasks import them from there.
"""
from __future__ import annotations

from typing import Any

from cab_core.contracts.checkpoints import SpatialRule
from cab_core.contracts.task import TaskInfo
from cab_core.errors import PluginError
from cab_core.kits.task import SceneTask

from .catalog import has_catalog_entry, task_info


def lift_rules(info: dict, initial_z: float) -> list[SpatialRule]:
    """"Lift left" and "Lift right" (after rules 0 and 1, the two arms' approaches): each arm's TCP
    rises by the lift the task asks for, from ``initial_z`` to ``info["raised_z"]`` (in cm)."""
    lift = max(0.0, 100.0 * (float(info["raised_z"]) - float(initial_z)))
    return [SpatialRule("Lift left", "left", None, None, prerequisites=(0,), lift_above_cm=lift),
            SpatialRule("Lift right", "right", None, None, prerequisites=(1,), lift_above_cm=lift)]


class CodeActionTask(SceneTask):
    """A catalog task of this suite: ``name`` selects the catalog entry (instruction, seed,
    scoring, budgets); unless a subclass sets it, it is the name of the subclass's module (the
    suite's task modules are named after their catalog entries). A task of another package that
    reuses this class declares its own metadata, ``info = TaskInfo(...)`` on its class (or
    ``self.info`` set in its own ``__init__``); one that does neither, and whose name is not in
    the catalog, is refused in one line saying so. A task outside this suite is better written on
    :class:`cab_core.kits.task.SceneTask`, which has no catalog."""

    #: held out from the seeds the suite was developed on (the catalog's, 0-9): the oracle succeeds
    #: at each within budgets on every simulator, and under small perturbations (cab-suite-check
    #: --seed-set heldout [--perturb N])
    seed_sets = {"heldout": tuple(range(100, 120))}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        if not cls.__dict__.get("name"):
            cls.name = cls.__module__.rsplit(".", 1)[-1]
        super().__init_subclass__(**kwargs)

    def __init__(self) -> None:
        declared = getattr(type(self), "info", None)
        if isinstance(declared, TaskInfo):  # a task outside the catalog declares its own metadata
            self.info = declared
            return
        if not has_catalog_entry(self.name):
            cls = type(self)
            raise PluginError(
                f"task {self.name!r} ({cls.__module__}.{cls.__qualname__}, a CodeActionTask) has no metadata: "
                "the suite's catalog, which gives its own tasks theirs, has no entry of that name; declare it "
                "on the class as info = TaskInfo(name=..., instruction=..., seed=..., scoring=..., "
                "budget_tool_calls=..., budget_sim_s=...) (cab_core.contracts.task; or set self.info in "
                "__init__, as examples/block_on_pad does)")
        self.info: TaskInfo = task_info(self.name)
