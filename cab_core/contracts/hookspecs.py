"""Every extension point of cab, in one place (pluggy project name ``"cab"``).

A plugin is a module that implements some of these hooks with ``@cab_core.hookimpl`` and is
declared as an entry point in group ``cab`` of its package::

    [project.entry-points.cab]
    my_sim = "my_package.plugin"

The plugins that ship with cab are loaded the same way; the core names none of them.

Registration hooks return a mapping ``name -> factory``; they are called once, when the plugin
manager is first asked for that kind of plugin (never at import). A name registered twice is a
start-up error. Factories are called lazily with the option's config (a plain dict), so a plugin
whose heavy dependency is missing fails only when it is used, with the install command.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import pluggy

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.embodiment import EmbodimentSpec
    from cab_core.contracts.planner import Planner
    from cab_core.contracts.simulator import Simulator
    from cab_core.contracts.task import Task

hookspec = pluggy.HookspecMarker("cab")
hookimpl = pluggy.HookimplMarker("cab")

# --- world ------------------------------------------------------------------------------------


@hookspec
def cab_simulators() -> dict[str, Callable[[dict], Simulator]]:
    """Simulator backends: ``{"my_sim": factory}``; ``factory(cfg)`` returns an unbuilt
    :class:`cab_core.contracts.simulator.Simulator`. Called once per process. All results are merged."""


@hookspec
def cab_planners() -> dict[str, Callable[[dict], Planner]]:
    """Motion planners: ``{"my_planner": factory}``; ``factory(cfg)`` returns a
    :class:`cab_core.contracts.planner.Planner` (not yet set up). Called once per process."""


@hookspec
def cab_embodiments() -> dict[str, Callable[[dict], EmbodimentSpec]]:
    """Robots: ``{"my_robot": factory}``; ``factory(cfg)`` generates the robot description if
    needed and returns an :class:`cab_core.contracts.embodiment.EmbodimentSpec`. Called once per process."""


# --- tasks ------------------------------------------------------------------------------------


@hookspec
def cab_task_suites() -> dict[str, Callable[[], dict[str, Task]]]:
    """Task suites: ``{"my_suite": loader}``; ``loader()`` returns ``{task_name: Task}``.
    Task names are unique across suites. Called once per process."""


@hookspec
def cab_published_figures() -> dict[str, Callable[[], dict]]:
    """A paper's published figures, for comparing a cab run with them (``cab-report <dir> --against
    <name>``): ``{"my_paper": loader}``; ``loader()`` returns the figures as plain data, a mapping with
    ``configurations``: a list of rows, each ``{"name": "<the paper's name>", "cab": {"model": ...,
    "harness": ...}, ...}`` and the measures the paper gives it (the keys
    :mod:`cab_core.analysis.against` reads: ``consistency``, ``resource_use``, ``termination``,
    ``programs``, ``actions``, ``tool_use``; any may be absent), and optionally ``tables`` (where each
    block comes from) and ``source`` (``attempts_per_configuration`` and ``tasks``: the denominators
    of the counts where a row does not give them). A task suite ships its paper's figures this way.
    Called once per process."""


# --- agents -----------------------------------------------------------------------------------


@hookspec
def cab_harnesses() -> dict[str, Callable[[dict], Any]]:
    """Harnesses drive an agent through one attempt's tool session: ``{"my_harness": factory}``
    (the core's own is ``direct``, for the model-free agents of :func:`cab_agents`; others drive a
    model through a provider and a context policy, or serve an external agent).
    ``factory(cfg)`` returns an object with ``run(session, model_cfg) -> None`` (``session``: the
    running attempt, :class:`cab_core.contracts.harness.AttemptSession`) and, optionally,
    ``preflight(model_cfg) -> None``, called before any simulator starts (credentials, endpoints);
    it raises ``ConfigError`` naming what is missing. Also optional: ``before_build(spec)``, called
    with the ``AttemptSpec`` after the preflight and before the world is built (a server can start
    answering its client meanwhile), and ``close()``, called if building the world fails after it.
    A factory with the attribute ``speaks_on_stdio = True`` serves its agent a protocol on
    stdin/stdout: ``cab harness=<name>`` then reserves stdout for it before anything else prints
    (unless ``harness.transport=`` names another transport). A factory's optional attribute
    ``config_keys`` (a set of names) declares the keys of a model configuration the harness itself
    reads (its agent's or provider's are declared by their factories): with it, cab refuses any other
    key under ``model.`` in one line before anything runs (:func:`cab_core.plugins.declared_model_keys`);
    without it, the keys stay open. :mod:`cab_core.contracts.harness` states all of this as
    protocols (``Harness``, ``HarnessHooks``, ``HarnessFactory``)."""


@hookspec
def cab_agents() -> dict[str, Callable[[dict], Any]]:
    """Model-free agents for the ``direct`` harness: ``oracle``, ``idle``, ``scripted``...
    ``factory(cfg)`` returns an object with ``run(session) -> None``; the factory's optional
    ``config_keys`` declares the model configuration's keys the agent reads (``scripted``: ``script``)."""


@hookspec
def cab_model_providers() -> dict[str, Callable[[dict], Any]]:
    """Model providers: ``{"my_api": factory}``; a harness that talks to a model API creates the
    one the model config names with ``cab_core.plugins.create("model_providers", name, model_cfg)``.
    ``factory(cfg)`` returns a provider client with capability flags; the contract of the client is
    the harness's that uses it. The factory's optional ``config_keys`` declares the model
    configuration's keys the provider reads (``model_id``, ``base_url``...), as a harness's does."""


@hookspec
def cab_context_policies() -> dict[str, Callable[[dict], Any]]:
    """Context policies: ``{"my_policy": factory}``, what a model-driven harness sends the model
    of an attempt's history; such a harness creates the one the model config names with
    ``cab_core.plugins.create("context_policies", name, cfg)``."""


# --- records ----------------------------------------------------------------------------------


@hookspec
def cab_record_observers() -> dict[str, Callable[[dict], Any]]:
    """Observers of an attempt's record: ``{"my_observer": factory}``. The config key
    ``record.observers`` picks them: null (the default) every installed one, a list of names those,
    a mapping ``name -> config`` those with their config. ``factory(cfg)`` is called once the
    attempt's folder exists, with ``cfg`` = the observer's config plus ``name`` and
    ``attempt_dir`` (the folder, where it may write files of its own); it returns an object whose
    optional ``on_event(event)`` receives every event of the attempt, in order, after the recorder
    has written it, and whose optional ``on_result(result)`` receives the final result after
    ``result.json`` is written; each a read-only deep copy. ``on_event`` runs while the recorder
    holds the record (events stay in order): keep it quick. An observer that raises is logged once
    and detached; the attempt and its verdict are unaffected (:mod:`cab_core.attempt.observers`). Called
    as each attempt starts. All results are merged.

    An observer that costs more than an attempt should pay for it by default sets the attribute
    ``on_by_default = False`` on its factory: null then leaves it out, and only a list or mapping
    that names it selects it."""


@hookspec
def cab_record_exporters() -> dict[str, Callable[[Any, Any], list]]:
    """Formats an attempt's record can be exported to with ``cab-export <name> <attempt or sweep
    folder>``: ``{"my_format": export}``. ``export(attempt_dir, out_dir)`` reads the finished
    attempt in ``attempt_dir`` (a :class:`pathlib.Path`; ``result.json``, ``events.jsonl``,
    ``observations/``, ``privileged/``...) and writes its file(s) into ``out_dir`` (the attempt's own
    folder unless ``--out`` is given; created), returning the paths written. It raises
    ``MissingDependency`` (the install command) when a library it needs is missing. Called once per
    process. All results are merged."""


@hookspec
def cab_sweep_exporters() -> dict[str, Callable[[dict, Any], list]]:
    """Formats a whole sweep can be exported to with ``cab-export <name> <sweep folder>``, for
    records that summarise many attempts (an aggregate with its instances): ``{"my_format": export}``.
    ``export(sweep, out_dir)`` gets the sweep as plain data (``cab_core.analysis.summary.sweep_data``:
    per configuration cab-report's figures with their Wilson intervals, success per task, the
    combined comparison contract and the attempts' records; the installed suites' published figures
    of the paper) and writes its files below ``out_dir`` (a :class:`pathlib.Path`, created by it),
    returning the paths written; called once per export. It raises ``MissingDependency`` when a
    library it needs is missing. A name is either a record exporter's or a sweep exporter's, not
    both. Called once per process. All results are merged."""


# --- configuration ----------------------------------------------------------------------------


@hookspec
def cab_config_dirs() -> list[str]:
    """Extra Hydra config search paths (``pkg://my_plugin.conf``) holding option files for the
    groups sim/, model/, harness/, task/, planner/, embodiment/. Results are concatenated and
    appended to the search path of ``cab`` (after the primary config) by the ``cab`` distribution's
    Hydra search path plugin (cab_core.config). Tasks need no file: every installed task is an
    option of ``task``; a ``task/<name>.yaml`` shipped here replaces that generated option."""
