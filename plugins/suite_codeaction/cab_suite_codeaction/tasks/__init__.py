"""The suite's tasks, one module each, registered explicitly (no import-time side effects).

Each module defines ``TASK``, a :class:`~cab_suite_codeaction.common.CodeActionTask` subclass; the
module is named after the task's catalog entry, which is the task's ``name``.
"""
from __future__ import annotations

import importlib

from cab_core.contracts.task import Task
from cab_core.errors import PluginError

#: modules under ``cab_suite_codeaction.tasks`` whose ``TASK`` is registered, in catalog order
TASK_MODULES: tuple[str, ...] = (
    "beat_block_hammer",
    "stack_blocks_three",
    "open_microwave",
    "handover_block",
    "handover_mic",
    "place_mouse_pad",
    "rotate_qrcode",
    "open_laptop_setup_arm",
    "place_dual_shoes",
    "lift_pot",
    "grab_roller_dual_contact",
    "move_can_pot",
    "click_bell",
    "press_stapler",
    "scan_object",
    "pick_diverse_bottles",
    "put_bottles_dustbin",
    "dump_bin_bigbin",
    "place_bread_basket",
    "place_bread_skillet",
    "place_cans_plasticbox",
    "place_object_basket",
    "blocks_ranking_size",
    "stack_bowls_three",
    "hanging_mug",
)


def load_tasks(modules: tuple[str, ...] = TASK_MODULES) -> dict[str, Task]:
    """``{name: Task}`` for the registered modules; a task id defined twice is an error."""
    tasks: dict[str, Task] = {}
    for mod in modules:
        task = importlib.import_module(f"{__name__}.{mod}").TASK()
        if task.name in tasks:
            raise PluginError(f"task {task.name!r} is registered twice (module {mod})")
        tasks[task.name] = task
    return tasks
