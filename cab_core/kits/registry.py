"""Other installed plugins, found by name: what a plugin asks of cab's plugin registry.

A harness chooses its model provider and its context policy by name, an embodiment's measuring
script an installed planner, the MCP harness reads the task's card before any session exists. They
do it here, not through ``cab_core.plugins`` (the engine's registry, which may change):

* :func:`create_plugin`: an instance of the plugin ``kind``/``name`` made by its factory from
  ``cfg`` (``kind`` is a registry: ``"model_providers"``, ``"context_policies"``, ``"planners"``,
  ...; an unknown name is a :class:`~cab_core.errors.PluginError` listing the installed ones);
* :func:`task_info`: a task's :class:`~cab_core.contracts.task.TaskInfo` (its instruction and
  budgets), without building the task;
* :func:`task_instance`: the scene a task builds at a seed (its :class:`~cab_core.contracts.scene.SceneSpec`
  and privileged info), without a simulator: what a reader of a record (an export) draws the scene from.
"""
from __future__ import annotations

from typing import Any

from cab_core import plugins
from cab_core.contracts.task import SceneInstance, TaskInfo
from cab_core.errors import ConfigError


def create_plugin(kind: str, name: str, cfg: dict | None = None) -> Any:
    """The plugin ``name`` of the registry ``kind``, made by its factory from ``cfg``."""
    return plugins.create(kind, name, cfg)


def task_info(name: str) -> TaskInfo:
    """The card of the installed task ``name`` (instruction, budgets, seeds)."""
    return plugins.task_info(name)


def task_instance(name: str, seed: int, embodiment: str, embodiment_cfg: dict | None = None) -> SceneInstance:
    """The scene instance the installed task ``name`` builds at ``seed`` for the embodiment plugin
    ``embodiment`` (made from ``embodiment_cfg``): the instance as sampled, before an attempt's
    perturbation or randomisation. Builds no simulator; generated meshes and URDFs are written to
    the asset cache as an attempt would write them."""
    tasks = plugins.all_tasks()
    if name not in tasks:
        raise ConfigError(f"unknown task {name!r}; choices: {', '.join(sorted(tasks)) or '(none installed)'}")
    return tasks[name].build(int(seed), create_plugin("embodiments", embodiment, embodiment_cfg))
