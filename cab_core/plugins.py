"""The plugin manager: entry points of group ``cab``, built on demand, never at import.

Set ``CAB_DISABLE_PLUGIN_AUTOLOAD=1`` to load no entry points (hermetic tests register plugins
by hand with :func:`plugin_manager`'s ``extra``).
"""
from __future__ import annotations

import os
from functools import lru_cache
from importlib import metadata
from typing import Any, Callable

import pluggy

from . import hookspecs
from .errors import ConfigError, PluginError

GROUP = "cab"
KINDS = ("simulators", "planners", "embodiments", "task_suites", "harnesses", "agents",
         "model_providers", "context_policies")


def build_plugin_manager(extra: list[Any] | None = None, autoload: bool | None = None) -> pluggy.PluginManager:
    pm = pluggy.PluginManager(GROUP)
    pm.add_hookspecs(hookspecs)
    if autoload is None:
        autoload = os.environ.get("CAB_DISABLE_PLUGIN_AUTOLOAD", "") in ("", "0")
    if autoload:
        try:
            pm.load_setuptools_entrypoints(GROUP)
        except Exception as e:  # a broken plugin must not be silent
            raise PluginError(f"loading entry points of group {GROUP!r} failed: {e}") from e
    for p in extra or []:
        pm.register(p)
    pm.check_pending()
    return pm


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


def all_tasks(pm: pluggy.PluginManager | None = None) -> dict[str, Any]:
    tasks: dict[str, Any] = {}
    for suite, loader in registry("task_suites", pm).items():
        for name, task in loader().items():
            if name in tasks:
                raise PluginError(f"task {name!r} is defined by two suites")
            tasks[name] = task
    return tasks


@lru_cache(maxsize=1)
def _installed_tasks() -> dict[str, Any]:
    return all_tasks()


def task_names() -> list[str]:
    """Names of the installed suites' tasks, in the suites' order (loaded once per process)."""
    return list(_installed_tasks())


def task_info(name: str):
    """The :class:`~cab_core.task.TaskInfo` of installed task ``name`` (its suite's ``Task.info``).
    An unknown name raises :class:`ConfigError` listing the choices."""
    tasks = _installed_tasks()
    if name not in tasks:
        raise ConfigError(f"unknown task {name!r}; choices: {', '.join(sorted(tasks)) or '(none installed)'}")
    return tasks[name].info


def config_dirs(pm: pluggy.PluginManager | None = None) -> list[str]:
    """Every Hydra config search path the plugins ship (``cab_config_dirs``), in registration order,
    each once."""
    pm = pm or plugin_manager()
    out: list[str] = []
    for impl in reversed(pm.hook.cab_config_dirs.get_hookimpls()):  # pluggy calls the last registered first
        res = impl.function() or []
        owner = pm.get_name(impl.plugin) or repr(impl.plugin)
        if isinstance(res, str) or not all(isinstance(p, str) and p for p in res):
            raise PluginError(f"cab_config_dirs of {owner} must return a list of search paths "
                              f"('pkg://module.conf'), got {res!r}")
        out += [p for p in res if p not in out]
    return out


def describe(pm: pluggy.PluginManager | None = None) -> list[dict]:
    """Installed plugins, their distribution versions and what each provides."""
    pm = pm or plugin_manager()
    dists = {}
    for ep in metadata.entry_points(group=GROUP):
        try:
            dists[ep.name] = (ep.dist.name, ep.dist.version) if ep.dist else ("?", "?")
        except Exception:
            dists[ep.name] = ("?", "?")
    rows = []
    for name, plugin in pm.list_name_plugin():
        provides: dict[str, list[str]] = {}
        for kind in KINDS:
            hook = getattr(pm.hook, f"cab_{kind}")
            for impl in hook.get_hookimpls():
                if impl.plugin is plugin:
                    provides[kind] = sorted((impl.function() or {}).keys())
        hooks = sorted(h.name for h in pm.get_hookcallers(plugin) or [])
        dist, ver = dists.get(name, ("(registered in code)", ""))
        rows.append({"plugin": name, "distribution": dist, "version": ver, "provides": provides, "hooks": hooks})
    return rows
