"""Checks of a ``cab`` command line before Hydra composes or launches anything.

Hydra reports a misspelled option or key in several lines and exit status 1, and a key added with
``+`` (``+budget.tool_calsl=5``) is composed and then ignored. :func:`check_command_line` refuses
such mistakes with a :class:`~cab_core.errors.ConfigError` of one line naming the closest valid
names, for a single run and for every job of a sweep alike (before a sweep directory or an attempt
directory exists). It reads the config groups and their options from Hydra's own config search path
(``--config-dir``, ``hydra.searchpath`` and Hydra search-path plugins included).

What is checked:

* the option of every config group (``task=``, ``sim=``, ``model=``..., each value of a sweep);
* keys under ``budget``, ``sandbox``, ``record``, ``perturb``, ``sweep`` (the primary config's), ``sim`` and
  ``harness`` (the selected option's config, for each option a sweep selects), with or without
  ``+``/``++``; an empty mapping of an option (``sim.physics: {}``) is open: the names in it are
  the plugin's to check when it is created, before its simulator starts;
* top-level keys (``+seeds=3`` is refused: ``seed`` exists);
* budget values: a positive number, or null (the catalog's budget; for
  ``run_code_max_internal_calls`` the default, 500).

Keys under the other groups (``model.*``, ``task.*``...) are not checked here.
"""
from __future__ import annotations

import contextlib
import io
import itertools
import os
from typing import Any

from cab_core.attempt.budget import BUDGET_KEYS, check_budget_value
from cab_core.errors import CabError, ConfigError, closest

CHECKED_SECTIONS = ("budget", "sandbox", "record", "perturb", "sweep", "sim", "harness")
OPTION_SECTIONS = ("sim", "harness")  # their keys are the selected option's
MAIN_CONFIG_MODULE = "cab_core.apps.cli"  # the module of the Hydra app (its config_path is relative to it)
MAIN_CONFIG_PATH = "../conf"  # cab_core/conf


def one_line(e: BaseException) -> str:
    lines = [l.strip() for l in str(e).splitlines() if l.strip() and not l.strip().startswith("See https://")]
    return ": ".join(lines) if lines else type(e).__name__


def _values(o) -> list:
    """Every value an override gives (each of a sweep's); none for a deletion or a glob sweep."""
    from hydra.core.override_parser.types import ValueType

    if o.is_delete():
        return []
    if o.is_sweep_override():
        if o.value_type == ValueType.GLOB_CHOICE_SWEEP:
            return []
        return list(o.sweep_iterator())
    v = o.value()
    return list(v) if isinstance(v, list) else [v]


def expand_seed_set(argv: list[str]) -> list[str]:
    """``seed_set=NAME`` in a sweep (``-m``): each selected task's named seed set
    (``Task.seeds(NAME)``, e.g. ``heldout``) becomes the sweep's ``seed=`` values, and
    ``seed_set=NAME`` stays in the configuration (the report tells catalog from other seeds by the
    seed itself). Refused in one line when not a sweep, with ``seed=`` too, or when the tasks' sets
    differ (sweep those tasks separately)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import ValueType
    from hydra.errors import HydraException

    keys = [a.split("=", 1)[0].lstrip("+") for a in argv if "=" in a and not a.startswith("-")]
    if "seed_set" not in keys:
        return argv
    if not ({"-m", "--multirun"} & set(argv)):
        raise ConfigError("seed_set=NAME sweeps a task's named seed set: add -m (or give one seed=S)")
    if "seed" in keys:
        raise ConfigError("give seed_set=NAME or seed=..., not both")
    overrides = [a for a in argv if "=" in a and not a.startswith("-")]
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except HydraException as e:
        raise ConfigError(one_line(e)) from None
    from cab_core.plugins import all_tasks

    installed = all_tasks()
    name = next(str(o.value()) for o in parsed if o.key_or_group.lstrip("+") == "seed_set")
    task = next((o for o in parsed if o.key_or_group == "task"), None)
    if task is None:
        from cab_core.config import default_selection

        tasks = [default_selection(("task",))["task"]]
    elif task.value_type == ValueType.GLOB_CHOICE_SWEEP:
        tasks = list(task.value().filter(sorted(installed)))
    else:
        tasks = [str(v) for v in _values(task)]
    sets = {t: installed[t].seeds(name) for t in tasks if t in installed}  # an unknown task: refused later
    if len(set(sets.values())) > 1:
        raise ConfigError(f"the tasks' {name!r} seed sets differ ({', '.join(f'{t}: {len(s)} seeds' for t, s in sets.items())});"
                          " sweep them separately")
    seeds = next(iter(sets.values()), ())
    return argv + [f"seed={','.join(str(s) for s in seeds)}"] if seeds else argv


def _interpolated(v) -> bool:
    return isinstance(v, str) and "${" in v


def _loader(args):
    """Hydra's config loader over the search path the app uses (as ``hydra._internal.utils._run_hydra``
    builds it)."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_automatic_config_search_path
    from hydra.core.config_search_path import SearchPathQuery

    search_path = create_automatic_config_search_path(None, MAIN_CONFIG_MODULE, args.config_path or MAIN_CONFIG_PATH)
    if args.config_dir is not None:
        d = os.path.abspath(args.config_dir)
        if not os.path.isdir(d):
            raise ConfigError(f"config directory {d} (--config-dir) does not exist")
        search_path.prepend(provider="command-line", path=f"file://{d}", anchor=SearchPathQuery(provider="schema"))
    return ConfigLoaderImpl(config_search_path=search_path)


def parse_args(argv: list[str]):
    """Hydra's own reading of the command line, or None where it cannot read it (Hydra then says why)."""
    from hydra._internal.utils import get_args_parser

    with contextlib.redirect_stderr(io.StringIO()):
        try:
            args, _ = get_args_parser().parse_known_args(argv)
        except SystemExit:
            return None
    return args


def check_command_line(argv: list[str]):
    """Refuse (ConfigError, one line) an unknown group option, an unknown key or a non-positive
    budget on this ``cab`` command line. Returns Hydra's parsed arguments (None where Hydra
    cannot parse them, or nothing is run: ``--help``, ``--info``, shell completion)."""
    args = parse_args(argv)
    if args is None or args.help or args.hydra_help or args.info or args.shell_completion:
        return None
    from hydra.core.object_type import ObjectType
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import ValueType
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        overrides = OverridesParser.create().parse_overrides(args.overrides)
    except (HydraException, OmegaConfBaseException) as e:
        raise ConfigError(one_line(e)) from None
    config_name = args.config_name or "config"
    loader = _loader(args)
    searchpath = [o.input_line for o in overrides if o.get_key_element() == "hydra.searchpath"]
    try:
        top_groups = {g for g in loader.list_groups("") if g != "hydra"}
    except (HydraException, OmegaConfBaseException) as e:
        raise ConfigError(one_line(e)) from None

    def is_group(key: str) -> bool:
        return key in top_groups or ("/" in key and key.split("/")[0] in top_groups)

    choices: dict[str, list[str]] = {}  # group -> the options the command selects (a sweep: several)
    keys = []
    for o in overrides:
        key = o.key_or_group
        if o.package is not None or key.startswith("hydra"):
            continue
        if is_group(key):
            if o.is_delete():
                continue
            try:
                options = loader.get_group_options(key, ObjectType.CONFIG, config_name, searchpath)
            except (HydraException, OmegaConfBaseException) as e:
                raise ConfigError(one_line(e)) from None
            if o.value_type == ValueType.GLOB_CHOICE_SWEEP:  # task=glob(*): the options it matches
                values = list(o.value().filter(options))
            else:
                values = [str(v) for v in _values(o) if v is not None and not _interpolated(v)]
            if not values:
                continue
            for v in values:
                if v not in options:
                    if key == "task":  # a name two suites define: say so, not "unknown"
                        from cab_core.plugins import task_conflict

                        if (conflict := task_conflict(v)) is not None:
                            raise conflict
                    near = closest(v, options)
                    hint = f"did you mean {' or '.join(near)}?" if near else f"valid: {', '.join(options)}"
                    raise ConfigError(f"unknown {key} {v!r}; {hint}")
            choices[key] = values
        elif not o.is_delete():
            keys.append(o)
    _check_fork(choices, keys)
    if not keys:
        return args

    composed: dict[tuple, dict] = {}

    def base(selection: tuple) -> dict:
        """The config these group choices compose to, without the key overrides."""
        if selection not in composed:
            from hydra.types import RunMode
            from omegaconf import OmegaConf

            picked = [f"{g}={v}" for g, v in selection]
            try:
                cfg = loader.load_configuration(config_name, picked + searchpath, RunMode.RUN)
            except (HydraException, OmegaConfBaseException) as e:
                raise ConfigError(one_line(e)) from None
            plain = OmegaConf.to_container(cfg, resolve=False)
            plain.pop("hydra", None)
            composed[selection] = plain
        return composed[selection]

    others = tuple((g, vs[0]) for g, vs in choices.items() if g not in OPTION_SECTIONS)
    per_option = [[(g, v) for v in choices[g]] for g in OPTION_SECTIONS if g in choices]
    selections = [others + combo for combo in itertools.product(*per_option)]
    for o in keys:
        parts = o.key_or_group.split(".")
        top = parts[0]
        if top in top_groups and top not in OPTION_SECTIONS:
            continue  # model.*, task.*...: that option's business
        for sel in selections:
            cfg = base(sel)
            if top not in cfg:
                if top in top_groups:
                    continue  # a group removed from the defaults
                valid = [k for k in cfg if k not in top_groups] + sorted(top_groups)
                near = closest(top, valid)
                hint = f"did you mean {' or '.join(near)}? " if near else ""
                raise ConfigError(f"unknown key {top!r}; {hint}valid top-level keys: {', '.join(valid)}")
            if top in CHECKED_SECTIONS:
                section = cfg[top]
                option = section.get("name") if top in OPTION_SECTIONS and isinstance(section, dict) else None
                _check_path(section, parts, option)
        _check_settings(o, parts)
        if top == "budget" and len(parts) == 2 and parts[1] in BUDGET_KEYS:
            for v in _values(o):
                if not _interpolated(v):
                    check_budget_value(parts[1], v)
        if parts == ["record", "observers"] and not o.is_delete() and not o.is_sweep_override():
            from cab_core.plugins import select_record_observers as select

            select({"observers": o.value()})  # an observer no plugin registers: refused here
    return args


def _override_values(o) -> list:
    """Every value an override gives, a list value whole (``record.video_size=[320,240]``)."""
    from hydra.core.override_parser.types import ValueType

    if o.is_delete() or o.value_type == ValueType.GLOB_CHOICE_SWEEP:
        return []
    values = list(o.sweep_iterator()) if o.is_sweep_override() else [o.value()]
    return [v for v in values if not _interpolated(v)]


def _check_settings(o, parts: list[str]) -> None:
    """``seed``, ``attempt``, ``sandbox.*``, ``record.*``: each value of the override against its
    declared valid values (cab_core.attempt.spec.SETTINGS); one line naming the key and the range."""
    from cab_core.attempt.spec import SETTINGS

    if len(parts) == 1 and parts[0] in SETTINGS[""].model_fields:
        for v in _override_values(o):
            SETTINGS[""].check_value(parts[0], v)
    elif parts[0] in SETTINGS and parts[0]:
        model = SETTINGS[parts[0]]
        for v in _override_values(o):
            if len(parts) == 2:
                model.check_value(parts[1], v)
            elif len(parts) == 1 and isinstance(v, dict):
                model.check(v)


#: what a fork keeps from its parent: groups compared by option name, keys by value
_FORK_KEPT_GROUPS = ("task", "sim", "embodiment", "planner")
_FORK_KEPT_SECTIONS = ("budget", "perturb", "sandbox", "randomize")


def _check_fork(choices: dict[str, list[str]], keys: list) -> None:
    """A fork (``fork.from``) keeps its parent's task, seed, simulator, robot, planner, budgets,
    perturbation and sandbox: a command line that asks for other ones is refused, naming the
    parent's (the same ones are accepted)."""
    fork_from = next((o for o in keys if o.key_or_group == "fork.from"), None)
    fork_at = next((o for o in keys if o.key_or_group == "fork.at"), None)
    if fork_at is not None and fork_at.value() is not None and (fork_from is None or fork_from.value() is None):
        raise ConfigError("fork.at needs fork.from=<the folder of the attempt to fork>")
    if fork_from is None or fork_from.is_sweep_override() or fork_from.value() is None:
        return
    if fork_at is None or fork_at.value() is None:
        raise ConfigError("fork.from needs fork.at=<K>: the charged call of the parent after which the fork starts")
    from cab_core.attempt.fork import ForkPoint

    at = fork_at.value() if not fork_at.is_sweep_override() else 0
    try:  # the parent must be forkable at K (a sweep of K: at its start)
        parent = ForkPoint.load(fork_from.value(), at).config
    except CabError as e:  # a parent that cannot be forked: a mistake in the command, one line
        raise ConfigError(str(e)) from None
    kept = {g: parent.get(g) for g in _FORK_KEPT_GROUPS}
    kept["randomize"] = (parent.get("randomize") or {}).get("name", "none")
    for g, theirs in kept.items():
        for v in choices.get(g, []):
            if v != theirs:
                raise ConfigError(f"a fork keeps its parent's {g} ({theirs}); drop {g}={v}")
    for o in keys:
        top = o.key_or_group.split(".")[0]
        if o.key_or_group == "seed" and not o.is_sweep_override() and o.value() not in (None, parent.get("seed")):
            raise ConfigError(f"a fork keeps its parent's seed ({parent.get('seed')}); drop seed={o.value()}")
        if top in _FORK_KEPT_SECTIONS:
            raise ConfigError(f"a fork keeps its parent's {top} settings; drop {o.key_or_group}=...")


def _check_path(node: Any, parts: list[str], option: str | None) -> None:
    """``parts`` (``["budget", "tool_calls"]``) must name keys that exist below ``node`` (the
    section's config). An empty mapping below the section is open (``sim.physics``: the plugin
    checks its names); a list or a value ends the walk (Hydra refuses what does not fit it)."""
    for depth in range(1, len(parts)):
        if not isinstance(node, dict):
            return
        name = parts[depth]
        if name in node:
            node = node[name]
            continue
        if depth > 1 and not node:
            return
        where = ".".join(parts[:depth])
        valid = list(node)
        near = closest(name, valid)
        hint = f"did you mean {' or '.join(f'{where}.{n}' for n in near)}? " if near else ""
        of = f" ({parts[0]}={option})" if option else ""
        raise ConfigError(f"unknown key {'.'.join(parts)!r}; {hint}valid keys under {where}{of}: "
                          f"{', '.join(map(str, valid)) or '(none)'}")
