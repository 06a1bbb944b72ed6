"""How cab's Hydra configuration is found: the plugins' config dirs and the installed tasks.

The core's primary config (``cab_core/conf``) names no plugin. What plugins provide reaches Hydra's
config search path through a Hydra SearchPathPlugin (``hydra_plugins/cab_searchpath``), which calls
:func:`extend_search_path` whenever Hydra builds the search path of cab's app (``cab``, the
compose API over ``cab_core.conf``), so ``cab sim=<x>`` works for any installed plugin:

* every path the ``cab_config_dirs`` hook returns (``pkg://<module>.conf``) is appended;
* every installed task gets an option of group ``task`` in Hydra's ConfigStore (``{name: <task>}``),
  unless a config dir ships a ``task/<name>.yaml`` of its own (that file is then the option).

:class:`Compositions` reads a command line's configurations through Hydra's compose API, for the
check of the command line before Hydra's app starts (cab_core.apps.cmdline).

:func:`default_selection` is the composed default configuration's choice of simulator, robot and
planner, for the commands that do not go through Hydra's app (``cab-bench``, ``cab-suite-check``...).
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any

from omegaconf import DictConfig, OmegaConf

from cab_core.conf.schema import OWN_KEYS, checked_view
from cab_core.errors import ConfigError
from cab_core.plugins import config_dirs, task_info, task_names

CORE_CONFIG_MODULE = "cab_core.conf"
GROUPS = ("sim", "model", "harness", "task", "planner", "embodiment", "experiment", "randomize")
PROVIDER = "cab-plugins"  # the search path entries added here


def is_cab_search_path(search_path: Any) -> bool:
    """Whether this Hydra search path is cab's (its primary config dir is the core's): Hydra calls
    search path plugins for every app in the environment; cab's extend only its own."""
    def module(path: str) -> str:
        return path[len("pkg://"):].replace("/", ".") if path.startswith("pkg://") else ""

    return any(e.provider == "main" and module(e.path) == CORE_CONFIG_MODULE for e in search_path.get_path())


def extend_search_path(search_path: Any) -> None:
    """Append the plugins' config dirs and register the installed tasks' options (see above)."""
    if not is_cab_search_path(search_path):
        return
    present = {e.path for e in search_path.get_path()}
    for path in config_dirs():
        if path not in present:
            search_path.append(PROVIDER, path)
    register_task_configs(search_path)


def register_task_configs(search_path: Any) -> list[str]:
    """An option ``task/<name>`` (``{name: <name>}``) in Hydra's ConfigStore for every installed task
    that no config dir on ``search_path`` ships a yaml for; returns the names registered."""
    from hydra.core.config_store import ConfigStore

    shipped = {name for e in search_path.get_path() for name in shipped_options(e.path, "task")}
    store = ConfigStore.instance()
    names = [n for n in task_names() if n not in shipped]
    group = store.repo.get("task", {})
    for key in [k for k, node in group.items() if getattr(node, "provider", None) == "cab" and k[:-len(".yaml")] not in names]:
        del group[key]  # no longer installed, or a config dir now ships its yaml (the yaml is the option)
    for name in names:
        store.store(group="task", name=name, node={"name": name}, provider="cab")
    return names


def shipped_options(path: str, group: str) -> list[str]:
    """The options of ``group`` that the config dir ``path`` of a search path entry ships as yaml
    files (``file://<dir>`` or ``pkg://<module>``; a module that is not installed ships none, as
    Hydra finds none there; ConfigStore's ``structured://`` is not a config dir)."""
    import importlib.resources
    from pathlib import Path

    if path.startswith("file://"):
        folder: Any = Path(path[len("file://"):]) / group
    elif path.startswith("pkg://"):
        try:
            folder = importlib.resources.files(path[len("pkg://"):].replace("/", ".")).joinpath(group)
        except (ImportError, TypeError):  # not installed, or not a package
            return []
    else:
        return []
    if not folder.is_dir():
        return []
    return sorted(p.name[:-len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml") and p.is_file())


class Compositions:
    """The configurations a ``cab`` command line composes, read through Hydra's compose API over
    the search path the app uses (cab_core.apps.cmdline checks a command line with them before
    Hydra's app starts): the config groups, their options, and for a choice of options the typed
    view of the composed config (:func:`cab_core.conf.schema.checked_view`)."""

    def __init__(self, loader: Any, config_name: str, searchpath: list[str]) -> None:
        self.loader, self.config_name, self.searchpath = loader, config_name, searchpath
        self.groups = sorted(g for g in loader.list_groups("") if g != "hydra")
        self.views: dict[tuple, Any] = {}

    @classmethod
    @contextlib.contextmanager
    def of_command(cls, config_path: str | None, config_name: str | None, config_dir: str | None,
                   overrides: list) -> Iterator[Compositions]:
        """Those of a command line (Hydra's ``--config-path``, ``--config-name``, ``--config-dir``
        and its parsed overrides), while Hydra's compose API is initialised."""
        from hydra import initialize_config_dir, initialize_config_module
        from hydra.core.global_hydra import GlobalHydra

        init: Any
        if config_path:  # the app's config_path is relative to cab_core/apps
            here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "apps")
            init = initialize_config_dir(os.path.normpath(os.path.join(here, config_path)), job_name="cab",
                                         version_base=None)
        else:
            init = initialize_config_module(CORE_CONFIG_MODULE, job_name="cab", version_base=None)
        with init:
            yield cls(GlobalHydra.instance().config_loader(), config_name or "config",
                      search_path_overrides(config_dir, overrides))

    def options(self, group: str) -> list[str]:
        from hydra.core.object_type import ObjectType

        return self.loader.get_group_options(group, ObjectType.CONFIG, self.config_name, self.searchpath)

    def view(self, selection: tuple) -> Any:
        """The typed view of the config these ``(group, option)`` choices compose to: cab's own keys
        typed by the schema, the keys of a selected ``sim`` and ``harness`` option closed (an empty
        mapping in them open), the other groups' and a project's keys open."""
        if selection not in self.views:
            from hydra.types import RunMode
            picked = [f"{g}={v}" for g, v in selection]
            cfg = self.loader.load_configuration(self.config_name, picked + self.searchpath, RunMode.RUN)
            plain: Any = OmegaConf.to_container(cfg, resolve=False)
            plain.pop("hydra", None)
            extra = {k: v for k, v in plain.items() if k not in OWN_KEYS and k not in self.groups}
            view = checked_view(plain, {**extra, **{g: plain.get(g) for g in self.groups}})
            for key in [*extra, *self.groups]:
                if isinstance(view[key], DictConfig):
                    OmegaConf.set_struct(view[key], key in CLOSED_GROUPS)
            for key in CLOSED_GROUPS:
                for node in _mappings(view.get(key))[1:]:
                    OmegaConf.set_struct(node, bool(node))
            self.views[selection] = view
        return self.views[selection]


CLOSED_GROUPS = ("sim", "harness")  # the keys under these are those the selected option's config declares


def _mappings(node: Any) -> list:
    """``node`` and every mapping below it."""
    if not isinstance(node, DictConfig):
        return []
    return [node] + [m for k in node for m in _mappings(node[k])]


def search_path_overrides(config_dir: str | None, overrides: list) -> list[str]:
    """``hydra.searchpath=[...]`` as the command line gives it, with ``--config-dir`` first (Hydra
    puts both after the app's and the plugins' config dirs)."""
    paths = [p for o in overrides if o.get_key_element() == "hydra.searchpath" for p in (o.value() or [])]
    if config_dir is not None:
        d = os.path.abspath(config_dir)
        if not os.path.isdir(d):
            raise ConfigError(f"config directory {d} (--config-dir) does not exist")
        paths.insert(0, f"file://{d}")
    return ["hydra.searchpath=[" + ",".join(repr(str(p)) for p in paths) + "]"] if paths else []


def _option_yaml(sources: list[str], group: str, name: str) -> dict | None:
    """The yaml of option ``name`` of ``group`` as the first of these config dirs that ships it
    writes it (unresolved), or None."""
    for path in sources:
        if name in shipped_options(path, group):
            import importlib.resources
            from pathlib import Path

            folder: Any = (Path(path[len("file://"):]) if path.startswith("file://") else
                           importlib.resources.files(path[len("pkg://"):].replace("/", ".")))
            node = OmegaConf.create(folder.joinpath(group, f"{name}.yaml").read_text())
            plain = OmegaConf.to_container(node, resolve=False)
            return plain if isinstance(plain, dict) else None
    return None


def _swept_options(root: Any, group: str) -> list[str] | None:
    """The options of ``group`` a sweep (the command line's overrides and ``hydra.sweeper.params``)
    gives more than one of, or None when it sweeps none."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import Glob

    given = [str(o) for o in (OmegaConf.select(root, "hydra.overrides.task", default=None) or [])]
    params = OmegaConf.select(root, "hydra.sweeper.params", default=None) or {}
    given += [f"{k}={v}" for k, v in params.items()]
    names: list[str] | None = None
    for o in OverridesParser.create().parse_overrides([g for g in given if g.split("=", 1)[0].lstrip("+~") == group]):
        if not o.is_sweep_override():
            continue
        value = o.value()
        if isinstance(value, Glob):
            every = {n for src in _config_sources(root) for n in shipped_options(src, group)}
            names = value.filter(sorted(every))
        else:
            names = [str(v) for v in o.sweep_string_iterator()]
    return names


def _config_sources(root: Any) -> list[str]:
    """The config dirs of this run's search path (``hydra.runtime.config_sources``; without it, the
    core's and the plugins')."""
    sources = OmegaConf.select(root, "hydra.runtime.config_sources", default=None) or []
    out = [f"{s['schema']}://{s['path']}" for s in sources if s.get("schema") in ("pkg", "file")]
    return out or [f"pkg://{CORE_CONFIG_MODULE}", *config_dirs()]


def in_flight(max_in_flight: Any, *, _root_: Any) -> int:
    """Resolver ``cab.in_flight``: the attempts a sweep keeps in flight (cab_core.conf.in_flight) for
    ``sweep.max_in_flight`` (null: from the sweep's agents, simulators and this machine's memory)."""
    from cab_core.conf.in_flight import DEFAULT_SLOT_MEMORY_MB
    from cab_core.conf.in_flight import in_flight as decide

    if max_in_flight is not None:
        if isinstance(max_in_flight, bool) or not isinstance(max_in_flight, int) or max_in_flight < 1:
            raise ConfigError(f"sweep.max_in_flight must be a positive integer or null (automatic), got {max_in_flight!r}")
        return max_in_flight

    def configs(group: str) -> list[dict | None]:
        names = _swept_options(_root_, group)
        if names is None:
            node = OmegaConf.select(_root_, group, default=None)
            return [OmegaConf.to_container(node, resolve=False) if isinstance(node, DictConfig) else None]  # type: ignore[list-item]
        return [_option_yaml(_config_sources(_root_), group, n) for n in names]

    # a model whose config cannot be read counts as model-bound: memory, not cores, then bounds the sweep
    model_bound = any(m is None or not m.get("agent") for m in configs("model"))
    slots = [s.get("slot_memory_mb") if s else None for s in configs("sim")]
    slot_mb = max(float(x) if isinstance(x, (int, float)) else DEFAULT_SLOT_MEMORY_MB for x in slots)
    sweep = OmegaConf.select(_root_, "sweep", default=None) or {}
    return decide(None, model_bound, slot_mb, cap=int(sweep.get("in_flight_cap", 128)),
                  reserve_mb=float(sweep.get("memory_reserve_mb", 2048))).n


DEFAULT_GROUPS = ("sim", "embodiment", "planner")


def composed(overrides: list[str] | None = None):
    """The configuration plain ``cab`` composes with these overrides (Hydra's compose API; not
    inside a running Hydra app)."""
    from hydra import compose, initialize_config_module

    with initialize_config_module(version_base=None, config_module=CORE_CONFIG_MODULE):
        return compose(config_name="config", overrides=list(overrides or []))


def default_selection(groups: tuple[str, ...] = DEFAULT_GROUPS) -> dict[str, str]:
    """The option of each of ``groups`` that plain ``cab`` composes (the project's default
    composition where installed). A group the default leaves unset is a :class:`ConfigError`."""
    cfg = composed()
    out = {}
    for g in groups:
        node = cfg.get(g)
        if node is None or not node.get("name"):
            raise ConfigError(f"the default configuration selects no {g} (its primary config leaves {g}: null)")
        out[g] = str(node.name)
    return out


def normalise_overrides(argv: list[str]) -> list[str]:
    """Accept both ``+group=option`` and ``group=option`` for the groups that have a default.

    Hydra refuses ``+sim=x`` when ``sim`` is in the defaults list; every group here has a
    default, so the ``+`` is dropped for them (DESIGN.md, Hydra note)."""
    out = []
    for a in argv:
        if a.startswith("+") and not a.startswith("++"):
            key = a[1:].split("=", 1)[0]
            if key in GROUPS:
                a = a[1:]
        out.append(a)
    return out


def scene_seed(seed, task: str) -> int:
    """Resolver ``cab.seed``: the seed an attempt uses (``seed: null`` means the task's fixed seed,
    from its suite's catalog), so that sweep directories are named ``seed-<S>`` by the seed that ran."""
    return task_info(task).seed if seed is None else seed


def run_dir(task: str, model: str, sim: str, fork_from=None, fork_at=None) -> str:
    """Resolver ``cab.run_dir``: ``<task>/<model>/<sim>`` of a single attempt's output folder; for a
    fork, the parent's task and simulator (which the fork keeps) and a last part ``fork-at-<K>``."""
    if fork_from is None:
        return f"{task}/{model}/{sim}"
    import json
    from pathlib import Path

    try:
        for line in (Path(str(fork_from)).expanduser() / "events.jsonl").read_text().splitlines():
            e = json.loads(line)
            if e.get("kind") == "attempt_start":
                task, sim = e["config"]["task"], e["config"]["sim"]
                break
    except (OSError, ValueError, KeyError, TypeError):
        pass  # the fork itself says what is wrong with its parent (cab_core.attempt.fork)
    return f"{task}/{model}/{sim}/fork-at-{fork_at}"


# Registered when this module is imported: Hydra resolves each job's output directory in the
# launcher's worker process, and every worker imports the app's module, which imports this one.
if not OmegaConf.has_resolver("cab.seed"):
    OmegaConf.register_new_resolver("cab.seed", scene_seed)
if not OmegaConf.has_resolver("cab.run_dir"):
    OmegaConf.register_new_resolver("cab.run_dir", run_dir)
if not OmegaConf.has_resolver("cab.in_flight"):
    OmegaConf.register_new_resolver("cab.in_flight", in_flight)
