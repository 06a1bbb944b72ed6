"""Every extension point of cab, in one place (pluggy project name ``"cab"``).

A plugin is a module that implements some of these hooks with ``@cab_core.hookimpl`` and is
declared as an entry point in group ``cab`` of its package::

    [project.entry-points.cab]
    my_sim = "my_package.plugin"

cab's own plugins (SAPIEN, mplib, the CodeActionBench suite...) are loaded the same way.

Registration hooks return a mapping ``name -> factory``; they are called once, when the plugin
manager is first asked for that kind of plugin (never at import). A name registered twice is a
start-up error. Factories are called lazily with the option's config (a plain dict), so a plugin
whose heavy dependency is missing fails only when it is used, with the install command.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

import pluggy

if TYPE_CHECKING:  # pragma: no cover
    from .embodiment import EmbodimentSpec
    from .planner import Planner
    from .simulator import Simulator
    from .task import Task

hookspec = pluggy.HookspecMarker("cab")
hookimpl = pluggy.HookimplMarker("cab")

# --- world ------------------------------------------------------------------------------------


@hookspec
def cab_simulators() -> dict[str, Callable[[dict], "Simulator"]]:
    """Simulator backends: ``{"sapien": factory}``; ``factory(cfg)`` returns an unbuilt
    :class:`cab_core.simulator.Simulator`. Called once per process. All results are merged."""


@hookspec
def cab_planners() -> dict[str, Callable[[dict], "Planner"]]:
    """Motion planners: ``{"mplib": factory}``; ``factory(cfg)`` returns a
    :class:`cab_core.planner.Planner` (not yet set up). Called once per process."""


@hookspec
def cab_embodiments() -> dict[str, Callable[[dict], "EmbodimentSpec"]]:
    """Robots: ``{"aloha_agilex": factory}``; ``factory(cfg)`` generates the robot description if
    needed and returns an :class:`cab_core.embodiment.EmbodimentSpec`. Called once per process."""


# --- tasks ------------------------------------------------------------------------------------


@hookspec
def cab_task_suites() -> dict[str, Callable[[], dict[str, "Task"]]]:
    """Task suites: ``{"codeaction": loader}``; ``loader()`` returns ``{task_name: Task}``.
    Task names are unique across suites. Called once per process."""


# --- agents -----------------------------------------------------------------------------------


@hookspec
def cab_harnesses() -> dict[str, Callable[[dict], Any]]:
    """Harnesses drive an agent through one attempt's tool session: ``direct`` (model-free
    agents), ``reference`` (model providers + context policy), ``mcp`` (an external MCP client).
    ``factory(cfg)`` returns an object with ``run(episode, model_cfg) -> None`` and, optionally,
    ``preflight(model_cfg) -> None``, called before any simulator starts (credentials, endpoints);
    it raises ``ConfigError`` naming what is missing. Also optional: ``before_build(spec)``, called
    with the ``AttemptSpec`` after the preflight and before the world is built (a server can start
    answering its client meanwhile), and ``close()``, called if building the world fails after it."""


@hookspec
def cab_agents() -> dict[str, Callable[[dict], Any]]:
    """Model-free agents for the ``direct`` harness: ``oracle``, ``idle``, ``scripted``...
    ``factory(cfg)`` returns an object with ``run(session) -> None``."""


@hookspec
def cab_model_providers() -> dict[str, Callable[[dict], Any]]:
    """Model providers for the reference harness (``anthropic``, ``openai``, ``google``,
    ``openai_compatible``). ``factory(cfg)`` returns a provider client with capability flags.
    Implemented by a later issue; declared here so the contract is complete."""


@hookspec
def cab_context_policies() -> dict[str, Callable[[dict], Any]]:
    """Context policies for the reference harness (``reference``: two image rounds, 8 verbatim
    units, 128-record ledger). Implemented by a later issue."""


# --- records ----------------------------------------------------------------------------------


@hookspec
def cab_record_observers() -> list[Callable[[dict], Any]]:
    """Observers of an attempt's record: each factory(cfg) returns an object whose
    ``on_event(event: Mapping)`` receives every frozen event as it is appended, and whose
    ``on_result(result: Mapping)`` receives the final result. Results are concatenated."""


# --- configuration ----------------------------------------------------------------------------


@hookspec
def cab_config_dirs() -> list[str]:
    """Extra Hydra config search paths (``pkg://my_plugin.conf``) holding option files for the
    groups sim/, model/, harness/, task/, planner/, embodiment/. Results are concatenated and
    appended to the search path of ``cab`` (after the primary config) by the ``cab`` distribution's
    Hydra search path plugin (cab_core.config). Tasks need no file: every installed task is an
    option of ``task``; a ``task/<name>.yaml`` shipped here replaces that generated option."""
