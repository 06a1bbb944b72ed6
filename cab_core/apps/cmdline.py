"""Checks of a ``cab`` command line before Hydra composes or launches anything, and their one line.

Hydra reports a misspelled option or key in several lines and exit status 1, and a key added with
``+`` (``+budget.tool_calsl=5``) is composed and then ignored. :func:`check_command_line` refuses
such mistakes with a :class:`~cab_core.errors.ConfigError` of one line naming the closest valid
names, for a single run and for every job of a sweep alike (before a sweep directory or an attempt
directory exists). The config groups and their options come from Hydra's own config search path
(``--config-dir``, ``hydra.searchpath`` and Hydra search-path plugins included), read through
Hydra's compose API.

What is checked:

* the option of every config group (``task=``, ``sim=``, ``model=``..., each value of a sweep);
* cab's own keys and values (``seed``, ``attempt``, ``budget.*``, ``sandbox.*``, ``record.*``,
  ``perturb.*``, ``fork.*``, ``sweep.*``; top-level keys: ``+seeds=3`` is refused, ``seed``
  exists), with or without ``+``/``++``: OmegaConf refuses them against the schema
  (:mod:`cab_core.conf.schema`), every value of a sweep;
* keys under ``sim`` and ``harness``: those the selected option's config declares (each option a
  sweep selects); an empty mapping of an option (``sim.physics: {}``) is open: the names in it
  are the plugin's to check when it is created, before its simulator starts.

* keys under ``model``: cab's own (``name``, ``agent``, ``harness``) and those the plugins reading the
  selected model configuration declare (the ``config_keys`` of its harness's factory and of its
  agent's or provider's, :func:`cab_core.plugins.declared_model_keys`), each model option a sweep
  selects, the keys of its config file included; open where one of those plugins declares none.

Keys under the other groups (``task.*``...) are not checked here: they are open.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import itertools
from collections.abc import Collection
from dataclasses import fields
from typing import Any

from omegaconf import DictConfig, OmegaConf

from cab_core.conf.schema import ModelBasics, check_value, one_line
from cab_core.config import CLOSED_GROUPS, Compositions, default_selection
from cab_core.errors import CabError, ConfigError, closest
from cab_core.plugins import all_tasks, declared_model_keys, select_record_observers, task_conflict


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
    installed = all_tasks()
    name = next(str(o.value()) for o in parsed if o.key_or_group.lstrip("+") == "seed_set")
    task = next((o for o in parsed if o.key_or_group == "task"), None)
    if task is None:
        tasks = [default_selection(("task",))["task"]]
    elif task.value_type == ValueType.GLOB_CHOICE_SWEEP:
        glob: Any = task.value()
        tasks = list(glob.filter(sorted(installed)))
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


def parse_args(argv: list[str]) -> argparse.Namespace | None:
    """The options of Hydra's command line that decide what the check reads (the others are left to
    Hydra), or None where the command line cannot be read (Hydra then says why)."""
    ap = argparse.ArgumentParser(add_help=False)
    ap.add_argument("overrides", nargs="*")
    for flag in ("--help", "-h"), ("--hydra-help",), ("--multirun", "-m"), ("--resolve",), ("--version",):
        ap.add_argument(*flag, action="store_true")
    for flag in (("--cfg", "-c"), ("--package", "-p"), ("--shell-completion", "-sc"), ("--config-path", "-cp"),
                 ("--config-name", "-cn"), ("--config-dir", "-cd"), ("--experimental-rerun",)):
        ap.add_argument(*flag)
    ap.add_argument("--run", "-r", action="store_true")
    ap.add_argument("--info", "-i", nargs="?", const="all")
    with contextlib.redirect_stderr(io.StringIO()):
        try:
            args, _ = ap.parse_known_args(argv)
        except SystemExit:
            return None
    return args


def check_command_line(argv: list[str]):
    """Refuse (ConfigError, one line) an unknown group option, an unknown key or a value the schema
    refuses on this ``cab`` command line. Returns the parsed arguments (None where they cannot be
    parsed, or nothing is run: ``--help``, ``--info``, shell completion)."""
    args = parse_args(argv)
    if args is None or args.help or args.hydra_help or args.info or args.shell_completion:
        return None
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        overrides = OverridesParser.create().parse_overrides(args.overrides)
        with Compositions.of_command(args.config_path, args.config_name, args.config_dir, overrides) as compositions:
            check = Check(compositions)
            choices, keys = check.options(overrides)
            _check_fork(choices, keys)
            check.models(choices, keys)
            if keys:
                check.keys(choices, keys)
    except (HydraException, OmegaConfBaseException) as e:
        raise ConfigError(one_line(e)) from None
    return args


class Check:
    """The checks of one command line over the configurations it composes."""

    def __init__(self, compositions: Compositions) -> None:
        self.compositions = compositions
        self.groups = compositions.groups

    def options(self, overrides: list) -> tuple[dict[str, list[str]], list]:
        """Each group's options the command selects (several in a sweep), each refused in one line
        where the group has no such option; and the key overrides."""
        choices: dict[str, list[str]] = {}
        keys = []
        for o in overrides:
            key = o.key_or_group
            if o.package is not None or key.startswith("hydra") or o.is_delete():
                continue
            if key.split("/")[0] not in self.groups:
                keys.append(o)
            elif values := self.selected(o):
                choices[key] = values
        return choices, keys

    def selected(self, o) -> list[str]:
        from hydra.core.override_parser.types import ValueType

        key = o.key_or_group
        options = self.compositions.options(key)
        if o.value_type == ValueType.GLOB_CHOICE_SWEEP:  # task=glob(*): the options it matches
            glob: Any = o.value()
            return list(glob.filter(options))
        values = [str(v) for v in _values(o) if v is not None and not _interpolated(v)]
        for v in values:
            if v not in options:
                raise unknown_option(key, v, options)
        return values

    def models(self, choices: dict[str, list[str]], keys: list) -> None:
        """The keys under ``model.`` of each model option the command selects (with each ``harness``
        option), those of its config and those the command line gives, with or without ``+``, each
        refused in one line where the plugins reading the model configuration declare the keys they
        read (:func:`cab_core.plugins.declared_model_keys`) and this one is not among them."""
        given = [o for o in keys if o.key_or_group.startswith("model.")]
        if "model" not in self.groups or not (given or choices.get("model")):
            return  # the default model's config: checked by the tests of the config that ships it
        per_option = [[(g, v) for v in choices[g]] for g in CLOSED_GROUPS if g in choices]
        options: list[str | None] = [*choices.get("model", [])] or [None]
        for m in options:
            others = tuple((g, m if g == "model" else vs[0]) for g, vs in choices.items() if g not in CLOSED_GROUPS)
            for combo in itertools.product(*per_option):  # as Check.keys composes them: each view made once
                self._model(self.compositions.view(others + combo), m, given)

    def _model(self, view: Any, option: str | None, given: list) -> None:
        """The model keys of one composed ``view`` (``option``: the model option selected, None for
        the default one) and of the command line (``given``), checked."""
        if not isinstance(view.get("model"), DictConfig):
            return  # no model selected: refused where the attempt is made
        model: Any = OmegaConf.to_container(view.model, resolve=False)
        for o in given:  # a harness, agent or provider the command line names decides the keys
            leaf = o.key_or_group.split(".", 1)[1]
            if leaf in ("harness", "agent", "provider", "model_id") and not o.is_sweep_override():
                model[leaf] = o.value()
            elif leaf == "model_id":
                model[leaf] = "(swept)"
        if model.get("provider") and "model_id" in model and model["model_id"] is None:  # a generic option
            raise ConfigError(f"model={option or model.get('name')} names no model: give model.model_id=<the id "
                              "the provider serves>")
        declared = declared_model_keys(model, OmegaConf.select(view, "harness.name"))
        if declared is None:
            return  # a plugin that declares no keys: the group stays open
        for name in model:
            check_model_key(str(name), declared, option)
        for o in given:
            check_model_key(o.key_or_group.split(".")[1], declared, option, o.key_or_group)

    def keys(self, choices: dict[str, list[str]], keys: list) -> None:
        """Every value of every key override against the view of every selection a sweep makes of
        the ``sim`` and ``harness`` options (the other groups: their first option)."""
        others = tuple((g, vs[0]) for g, vs in choices.items() if g not in CLOSED_GROUPS)
        per_option = [[(g, v) for v in choices[g]] for g in CLOSED_GROUPS if g in choices]
        selections = [others + combo for combo in itertools.product(*per_option)]
        for o in keys:
            key = o.key_or_group
            top = key.split(".")[0]
            if top in self.groups and top not in CLOSED_GROUPS:
                continue  # model.*, task.*...: open, that option's business
            for view in map(self.compositions.view, selections):
                if top in CLOSED_GROUPS and view.get(top) is None:
                    continue  # the group is unset
                option = view[top].get("name") if top in CLOSED_GROUPS else None
                for v in _override_values(o):
                    check_value(view, key, v, option)
            if key == "record.observers" and not o.is_sweep_override():
                select_record_observers({"observers": o.value()})  # an observer no plugin registers: refused here


def model_keys(declared: Collection[str]) -> list[str]:
    """The keys a model configuration may carry: cab's own (:class:`~cab_core.conf.schema.ModelBasics`) and those the
    plugins reading it declare (``declared``: :func:`cab_core.plugins.declared_model_keys`)."""
    basics = [f.name for f in fields(ModelBasics)]
    return basics + sorted(set(declared) - set(basics))


def check_model_key(name: str, declared: Collection[str], option: str | None, given: str | None = None) -> None:
    """Refuse (ConfigError, one line) the key ``name`` under ``model.`` (``given``: the key as the
    command line gave it, ``model.retry.max_attempts``) where neither cab nor the plugins reading
    the model configuration ``option`` declare it, naming the closest valid keys and all of them."""
    valid = model_keys(declared)
    if name in valid:
        return
    near = closest(name, valid)
    hint = f"did you mean {' or '.join(f'model.{n}' for n in near)}? " if near else ""
    of = f" (model={option})" if option else ""
    raise ConfigError(f"unknown key {given or 'model.' + name!r}; {hint}valid keys under model{of}: {', '.join(valid)}")


def unknown_option(group: str, value: str, options: list[str]) -> CabError:
    if group == "task":  # a name two suites define: say so, not "unknown"
        if (conflict := task_conflict(value)) is not None:
            return conflict
    near = closest(value, options)
    hint = f"did you mean {' or '.join(near)}?" if near else f"valid: {', '.join(options)}"
    return ConfigError(f"unknown {group} {value!r}; {hint}")


def _override_values(o) -> list:
    """Every value an override gives, a list value whole (``record.video_size=[320,240]``)."""
    from hydra.core.override_parser.types import ValueType

    if o.is_delete() or o.value_type == ValueType.GLOB_CHOICE_SWEEP:
        return []
    values = list(o.sweep_iterator()) if o.is_sweep_override() else [o.value()]
    return [v for v in values if not _interpolated(v)]


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
    # here, not at the top: the fork module (numpy, the records) adds 0.08 s (python -X importtime) to
    # cab_core.apps.cli's 0.35 s, which every cab command would pay; only fork.from needs it
    from cab_core.attempt.fork import ForkPoint

    at = fork_at.value() if not fork_at.is_sweep_override() else 0
    try:  # the parent must be forkable at K (a sweep of K: at its start)
        parent = ForkPoint.load(fork_from.value(), at).config
    except CabError as e:  # a parent that cannot be forked: a mistake in the command, one line
        raise ConfigError(str(e)) from None
    kept = {g: parent.get(g) for g in _FORK_KEPT_GROUPS}
    kept["randomize"] = (parent.get("randomize") or {}).get("name", "none")
    if any(o.key_or_group == "fork.planner" and o.value() == "own" for o in keys):
        del kept["planner"]  # fork.planner=own: the command's planner makes the prefix again
    for g, theirs in kept.items():
        for v in choices.get(g, []):
            if v != theirs:
                raise ConfigError(f"a fork keeps its parent's {g} ({theirs}); drop {g}={v}"
                                  + (" or add fork.planner=own" if g == "planner" else ""))
    for o in keys:
        top = o.key_or_group.split(".")[0]
        if o.key_or_group == "seed" and not o.is_sweep_override() and o.value() not in (None, parent.get("seed")):
            raise ConfigError(f"a fork keeps its parent's seed ({parent.get('seed')}); drop seed={o.value()}")
        if top in _FORK_KEPT_SECTIONS:
            raise ConfigError(f"a fork keeps its parent's {top} settings; drop {o.key_or_group}=...")
