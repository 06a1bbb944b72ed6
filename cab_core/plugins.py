"""The plugin manager: entry points of group ``cab``, built on demand, never at import.

Entry points are loaded one at a time: one that fails to import or to register is a
:class:`~cab_core.errors.PluginError` of one line naming its distribution, the entry point, the
error and the fix. ``CAB_DISABLE_PLUGINS=name1,name2`` disables plugins by entry point name or
distribution name (as pytest's ``-p no:NAME``): they are blocked in the plugin manager and never
imported (``cab-plugins`` lists them as disabled). ``CAB_DISABLE_PLUGIN_AUTOLOAD=1`` loads no entry
points at all (hermetic tests register plugins by hand with :func:`build_plugin_manager`'s ``extra``).
"""
from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping
from functools import lru_cache
from importlib import metadata
from typing import Any, NamedTuple

import pluggy

from cab_core.contracts import hookspecs
from cab_core.errors import CabError, ConfigError, PluginError, closest

GROUP = "cab"
KINDS = ("simulators", "planners", "embodiments", "task_suites", "harnesses", "agents",
         "model_providers", "context_policies", "record_observers", "record_exporters", "published_figures",
         "sweep_exporters")


def build_plugin_manager(extra: list[Any] | None = None, autoload: bool | None = None) -> pluggy.PluginManager:
    pm = pluggy.PluginManager(GROUP)
    pm.add_hookspecs(hookspecs)
    if autoload is None:
        autoload = os.environ.get("CAB_DISABLE_PLUGIN_AUTOLOAD", "") in ("", "0")
    loaded = _load_entry_points(pm) if autoload else {}
    for p in extra or []:
        pm.register(p)
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as e:  # a hook no spec declares (a misspelt name)
        if id(e.plugin) in loaded:
            raise _broken(loaded[id(e.plugin)], e) from e
        raise
    return pm


DISABLE_ENV = "CAB_DISABLE_PLUGINS"


def _canonical(name: str) -> str:
    """A distribution name as packaging compares them (PEP 503): ``Cab_Sim.X`` -> ``cab-sim-x``."""
    return re.sub(r"[-_.]+", "-", name).lower()


def disabled_names() -> set[str]:
    """The names in ``CAB_DISABLE_PLUGINS`` (comma-separated; blanks ignored)."""
    return {n.strip() for n in os.environ.get(DISABLE_ENV, "").split(",") if n.strip()}


def _dist_name(ep: metadata.EntryPoint) -> str | None:
    dist = getattr(ep, "dist", None)
    return dist.name if dist is not None else None


def is_disabled(ep: metadata.EntryPoint, disabled: set[str] | None = None) -> bool:
    """Whether ``CAB_DISABLE_PLUGINS`` names this entry point or its distribution."""
    disabled = disabled_names() if disabled is None else disabled
    dist = _dist_name(ep)
    return ep.name in disabled or (dist is not None and _canonical(dist) in {_canonical(n) for n in disabled})


def _broken(ep: metadata.EntryPoint, e: BaseException) -> PluginError:
    """The one line that names a plugin that cannot be loaded, and the fix."""
    dist = _dist_name(ep)
    what = f"distribution {dist}" if dist else "an unnamed distribution"
    error = " ".join(f"{type(e).__name__}: {e}".split())
    fix = f"pip install --force-reinstall {dist}" if dist else "reinstall it"
    return PluginError(f"plugin {ep.name!r} ({what}, entry point {ep.name} = {ep.value} in group {GROUP!r}) "
                       f"failed to load: {error}; fix: {fix}, or disable it with {DISABLE_ENV}={ep.name}")


def _load_entry_points(pm: pluggy.PluginManager) -> dict[int, metadata.EntryPoint]:
    """Pluggy's ``load_setuptools_entrypoints``, one entry point at a time so that a broken one is
    named (pluggy's own loop stops at the first failure, without saying which). Disabled names are
    blocked with pluggy's ``set_blocked``: a later registration under that name is refused too.
    Returns the entry point of each plugin loaded, by the plugin's id."""
    disabled = disabled_names()
    loaded = {}
    for ep in metadata.entry_points(group=GROUP):
        if is_disabled(ep, disabled):
            pm.set_blocked(ep.name)
        if pm.has_plugin(ep.name) or pm.is_blocked(ep.name):
            continue
        try:
            plugin = ep.load()
            pm.register(plugin, name=ep.name)
        except Exception as e:  # a broken plugin is named, in one line
            raise _broken(ep, e) from e
        loaded[id(plugin)] = ep
    return loaded


def distribution_versions() -> dict[str, str]:
    """``{distribution: version}`` of the core's own distribution and of every distribution that
    provides an installed, not disabled, entry point of group ``cab`` (from importlib.metadata)."""
    core, plugins = {}, {}
    disabled = disabled_names()
    for ep in metadata.entry_points(group=GROUP):
        dist = getattr(ep, "dist", None)
        if dist is None:
            continue
        if ep.module.split(".")[0] == __package__:
            core[dist.name] = dist.version
        elif not is_disabled(ep, disabled):
            plugins[dist.name] = dist.version
    return {**core, **dict(sorted(plugins.items()))}


@lru_cache(maxsize=1)
def plugin_manager() -> pluggy.PluginManager:
    return build_plugin_manager()


def _merged(kind: str, pm: pluggy.PluginManager | None = None) -> dict[str, tuple[Callable, str]]:
    pm = pm or plugin_manager()
    hook = getattr(pm.hook, f"cab_{kind}")
    out: dict[str, tuple[Callable, str]] = {}
    for impl in hook.get_hookimpls():
        res = impl.function()
        if not res:
            continue
        owner = pm.get_name(impl.plugin) or repr(impl.plugin)
        for name, factory in res.items():
            if name in out:
                raise PluginError(f"{kind[:-1]} {name!r} is registered twice: by {out[name][1]} and {owner}")
            out[name] = (factory, owner)
    return out


def registry(kind: str, pm: pluggy.PluginManager | None = None) -> dict[str, Callable]:
    if kind not in KINDS:
        raise ValueError(kind)
    return {k: v[0] for k, v in _merged(kind, pm).items()}


def create(kind: str, name: str, cfg: dict | None = None, pm: pluggy.PluginManager | None = None):
    reg = registry(kind, pm)
    if name not in reg:
        choices = ", ".join(sorted(reg)) or "(none installed)"
        raise ConfigError(f"unknown {kind[:-1].replace('_', ' ')} {name!r}; choices: {choices}")
    return reg[name](dict(cfg or {}))


def declared_model_keys(model_cfg: Mapping, harness: str | None = None,
                        pm: pluggy.PluginManager | None = None) -> frozenset[str] | None:
    """The keys a model configuration may carry besides the basic ones (``name``, ``agent``,
    ``harness``), as the plugins that read it declare them: the attribute ``config_keys`` of the
    harness's factory (``harness``, else ``model_cfg["harness"]``) and of the agent's or the
    provider's factory the configuration names (``agent``, ``provider``). None where the harness is
    not installed or one of those factories declares nothing: the keys are then open."""
    name = harness if harness and harness != "auto" else model_cfg.get("harness")
    harnesses = registry("harnesses", pm)
    if not isinstance(name, str) or name not in harnesses:
        return None
    factories: list[Callable | None] = [harnesses[name]]
    for kind, key in (("agents", "agent"), ("model_providers", "provider")):
        if isinstance(model_cfg.get(key), str):
            factories.append(registry(kind, pm).get(model_cfg[key]))
    keys: set[str] = set()
    for f in factories:
        declared = getattr(f, "config_keys", None)
        if declared is None:
            return None
        keys.update(declared)
    return frozenset(keys)


class _Tasks(NamedTuple):
    """The installed suites' tasks: ``tasks`` by name (in the suites' order), ``suites`` the names
    each suite defines (``{suite: [task, ...]}``), ``conflicts`` the one line of each name defined by
    more than one suite (that name is disabled: in neither ``tasks`` nor a command's choices)."""
    tasks: dict[str, Any]
    suites: dict[str, list[str]]
    conflicts: dict[str, str]


def _plugin_label(pm: pluggy.PluginManager, owner: str) -> str:
    """``plugin P, distribution D`` of a registered plugin (its entry point's distribution)."""
    dist = next((_dist_name(ep) for ep in metadata.entry_points(group=GROUP) if ep.name == owner), None)
    return f"plugin {owner}, distribution {dist}" if dist else f"plugin {owner}"


def _load_suite(suite: str, loader: Callable, owner: str, pm: pluggy.PluginManager) -> dict[str, Any]:
    """A suite's ``{task_name: Task}``; a loader that fails is a :class:`PluginError` of one line
    naming the suite, its plugin and distribution, the error and how to leave it out."""
    try:
        tasks = loader()
    except Exception as e:
        error = " ".join((str(e) if isinstance(e, CabError) else f"{type(e).__name__}: {e}").split())
        raise PluginError(f"task suite {suite!r} ({_plugin_label(pm, owner)}) failed to load its tasks: {error}; "
                          f"fix it, or disable the plugin with {DISABLE_ENV}={owner}") from e
    if not isinstance(tasks, Mapping):
        raise PluginError(f"task suite {suite!r} ({_plugin_label(pm, owner)}): its loader must return "
                          f"{{task_name: Task}}, got {type(tasks).__name__}")
    return dict(tasks)


def load_suites(pm: pluggy.PluginManager | None = None) -> _Tasks:
    """Every installed suite's tasks (:class:`_Tasks`). A task name defined by two suites (or more)
    is disabled, and its one line names the name and each suite with its plugin and distribution;
    every other task stays available."""
    pm = pm or plugin_manager()
    tasks: dict[str, Any] = {}
    suites: dict[str, list[str]] = {}
    where: dict[str, list[str]] = {}
    for suite, (loader, owner) in _merged("task_suites", pm).items():
        loaded = _load_suite(suite, loader, owner, pm)
        suites[suite] = list(loaded)
        for name, task in loaded.items():
            where.setdefault(name, []).append(f"{suite!r} ({_plugin_label(pm, owner)})")
            tasks.setdefault(name, task)
    conflicts = {}
    for name, by in where.items():
        if len(by) > 1:
            del tasks[name]
            count = "two" if len(by) == 2 else str(len(by))
            conflicts[name] = (f"task {name!r} is defined by {count} suites, {' and '.join(sorted(by))}: it is disabled "
                               f"until one of them is uninstalled or disabled ({DISABLE_ENV}=<plugin>); "
                               "every other task works")
    return _Tasks(tasks, suites, conflicts)


def all_tasks(pm: pluggy.PluginManager | None = None) -> dict[str, Any]:
    """``{name: Task}`` of every installed suite, in the suites' order; a name two suites define
    is left out (:func:`load_suites`)."""
    return load_suites(pm).tasks


@lru_cache(maxsize=1)
def _installed_tasks() -> _Tasks:
    """The installed suites' tasks, loaded once per process (``cache_clear`` reloads them)."""
    return load_suites()


def task_names() -> list[str]:
    """Names of the installed suites' tasks, in the suites' order (loaded once per process); a name
    two suites define is not among them (:func:`task_conflict`)."""
    return list(_installed_tasks().tasks)


def task_conflict(name: str) -> PluginError | None:
    """The error of task ``name`` when two installed suites define it (it is disabled), else None."""
    line = _installed_tasks().conflicts.get(name)
    return None if line is None else PluginError(line)


def unknown_task(name: str, choices: str) -> CabError:
    """The one line for a task name that is not among the installed tasks: the conflict when two
    suites define it (:func:`task_conflict`), else ``unknown task ...`` followed by ``choices``."""
    return task_conflict(name) or ConfigError(f"unknown task {name!r}; {choices}")


def task_info(name: str):
    """The :class:`~cab_core.contracts.task.TaskInfo` of installed task ``name`` (its suite's ``Task.info``).
    An unknown name raises :class:`ConfigError` listing the choices; a name two suites define, the
    :class:`PluginError` naming both."""
    tasks = _installed_tasks().tasks
    if name not in tasks:
        raise unknown_task(name, f"choices: {', '.join(sorted(tasks)) or '(none installed)'}")
    return tasks[name].info


def config_dirs(pm: pluggy.PluginManager | None = None) -> list[str]:
    """Every Hydra config search path the plugins ship (``cab_config_dirs``), in registration order,
    each once."""
    pm = pm or plugin_manager()
    out: list[str] = []
    for impl in reversed(pm.hook.cab_config_dirs.get_hookimpls()):  # pluggy calls the last registered first
        res: Any = impl.function() or []  # checked below: a plugin may return anything
        owner = pm.get_name(impl.plugin) or repr(impl.plugin)
        if isinstance(res, str) or not all(isinstance(p, str) and p for p in res):
            raise PluginError(f"cab_config_dirs of {owner} must return a list of search paths "
                              f"('pkg://module.conf'), got {res!r}")
        out += [p for p in res if p not in out]
    return out


def describe(pm: pluggy.PluginManager | None = None) -> list[dict]:
    """Installed plugins, their distribution versions and what each provides; a plugin disabled
    with ``CAB_DISABLE_PLUGINS`` is listed with ``disabled: True`` and provides nothing. A plugin
    with task suites lists each suite's tasks (``tasks``: ``{suite: [task, ...]}``) and the one line
    of each of those names another suite defines too (``task_conflicts``: ``{task: line}``)."""
    pm = pm or plugin_manager()
    suites = load_suites(pm)
    dists = {}
    disabled = []
    for ep in metadata.entry_points(group=GROUP):
        dist = getattr(ep, "dist", None)
        dists[ep.name] = (dist.name, dist.version) if dist is not None else ("?", "?")
        if pm.is_blocked(ep.name):
            disabled.append(ep.name)
    rows = []
    for name, plugin in pm.list_name_plugin():
        if plugin is None:  # blocked: listed below
            continue
        provides: dict[str, list[str]] = {}
        for kind in KINDS:
            hook = getattr(pm.hook, f"cab_{kind}")
            for impl in hook.get_hookimpls():
                if impl.plugin is plugin:
                    provides[kind] = sorted((impl.function() or {}).keys())
        hooks = sorted(h.name for h in pm.get_hookcallers(plugin) or [])
        dist, ver = dists.get(name, ("(registered in code)", ""))
        row: dict[str, Any] = {"plugin": name, "distribution": dist, "version": ver, "provides": provides, "hooks": hooks,
               "disabled": False}
        if provides.get("task_suites"):
            row["tasks"] = {s: suites.suites.get(s, []) for s in provides["task_suites"]}
            row["task_conflicts"] = {t: suites.conflicts[t] for ts in row["tasks"].values() for t in ts
                                     if t in suites.conflicts}
        rows.append(row)
    for name in disabled:
        dist, ver = dists[name]
        rows.append({"plugin": name, "distribution": dist, "version": ver, "provides": {}, "hooks": [],
                     "disabled": True})
    return rows


class ObserverSpec(NamedTuple):
    """One selected observer, not yet created."""
    name: str
    factory: Callable[[dict], Any]
    cfg: dict


def select_record_observers(record_cfg: Mapping | None, pm=None) -> list[ObserverSpec]:
    """The record observers ``record.observers`` selects among the installed ones (null or absent:
    every installed one but those whose factory says ``on_by_default = False``; a list of names; a
    mapping of name to its config) (:mod:`cab_core.attempt.observers`)."""
    chosen = (record_cfg or {}).get("observers")
    installed = registry("record_observers", pm)
    if chosen is None:
        return [ObserverSpec(n, f, {}) for n, f in sorted(installed.items()) if getattr(f, "on_by_default", True)]
    if isinstance(chosen, (list, tuple)):
        wanted: dict[str, Any] = {}
        for n in chosen:
            if not isinstance(n, str):
                raise ConfigError(f"record.observers: a name must be a string, got {n!r}")
            wanted[n] = {}
    elif isinstance(chosen, Mapping):
        wanted = {}
        for n, c in chosen.items():
            if c is not None and not isinstance(c, Mapping):
                raise ConfigError(f"record.observers.{n}: an observer's config must be a mapping or null, got {c!r}")
            wanted[str(n)] = dict(c or {})
    else:
        raise ConfigError("record.observers must be null (every installed observer), a list of names or a "
                          f"mapping of name to config, got {chosen!r}")
    for n in wanted:
        if n not in installed:
            near = closest(n, installed)
            hint = f"did you mean {' or '.join(near)}? " if near else ""
            raise ConfigError(f"unknown record observer {n!r}; {hint}installed: {', '.join(sorted(installed)) or '(none)'}")
    return [ObserverSpec(n, installed[n], c) for n, c in wanted.items()]
