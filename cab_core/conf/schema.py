"""The schema of cab's own configuration keys: structured configs (dataclasses) registered in Hydra's
ConfigStore as ``cab_schema`` and checked by OmegaConf.

OmegaConf refuses a key the schema does not declare and a value of the wrong type; each dataclass's
``__post_init__`` refuses what a type cannot say (a positive number, a list of two sides). Every
refusal becomes one line with :func:`one_line_error`: ``<key> must be <what the field says>, got
<value>`` or ``unknown key ...; did you mean ...? valid keys under ...``. The composed configuration
itself stays as the yaml files write it (a typed node would turn ``timeout_s: 180`` into ``180.0``
in the records): :func:`checked_view` is a typed copy, made to be checked and thrown away.

The config groups (``sim``, ``model``, ``task``...) are not in the schema: their options come from
plugins, which declare their own keys. The top-level keys a project's primary config adds are kept
as they are.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import Any, ClassVar

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf, open_dict
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException, ValidationError

from cab_core.errors import ConfigError, closest

MIN_SANDBOX_MEMORY_MB = 256  # below this the run_code process cannot start Python with numpy
VIDEO_SIDE = (8, 4096)  # pixels, each side of the record video
CATALOG = "the catalog's budget for the task"


def setting(default: Any, must_be: str, *, factory: Any = None) -> Any:
    """A field of the schema; ``must_be`` completes "<key> must be ..." in a refusal."""
    if factory is not None:
        return field(default_factory=factory, metadata={"must_be": must_be})
    return field(default=default, metadata={"must_be": must_be})


def shown(value: Any) -> str:
    """A refused value as the user wrote it (OmegaConf turns ``-1`` of a float field into ``-1.0``)."""
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return repr(int(value))
    if isinstance(value, Enum):
        return repr(value.value)
    return repr(value)


def given(value: Any) -> str:
    """A value as the command line or a yaml file gave it."""
    return repr(value.value) if isinstance(value, Enum) else repr(value)


class Section:
    """A dataclass of the schema: ``SECTION`` is its key in the configuration ('' for the top level)."""
    SECTION: ClassVar[str] = ""

    @classmethod
    def key(cls, name: str) -> str:
        return f"{cls.SECTION}.{name}" if cls.SECTION else name

    def refuse(self, name: str) -> None:
        must_be = _must_be(self.SECTION, name)
        raise ConfigError(f"{self.key(name)} must be {must_be}, got {shown(getattr(self, name))}")

    def positive(self, *names: str) -> None:
        for name in names:
            value = getattr(self, name)
            if value is not None and not (value > 0 and math.isfinite(value)):
                self.refuse(name)

    def at_least(self, name: str, low: float) -> None:
        if getattr(self, name) < low:
            self.refuse(name)


@dataclass
class BudgetConfig(Section):
    """``budget.*``: null is the task's budget from its suite's catalog (0 is no budget: refused)."""
    SECTION: ClassVar[str] = "budget"
    tool_calls: int | None = setting(None, f"a positive integer or null ({CATALOG})")
    sim_seconds: float | None = setting(None, f"a positive number or null ({CATALOG})")
    wall_seconds: float | None = setting(None, f"a positive number or null ({CATALOG})")
    run_code_max_internal_calls: int | None = setting(500, "a positive integer or null (the default, 500)")
    cost_usd: float | None = setting(None, "a positive number of USD or null (no spend cap per attempt)")

    def __post_init__(self) -> None:
        self.positive("tool_calls", "sim_seconds", "wall_seconds", "run_code_max_internal_calls", "cost_usd")


class SandboxMode(Enum):
    required = "required"
    auto = "auto"
    off = "off"


@dataclass
class SandboxConfig(Section):
    """``sandbox.*``: how run_code is confined (cab_core.sandbox.SandboxConfig takes these)."""
    SECTION: ClassVar[str] = "sandbox"
    mode: SandboxMode = setting(SandboxMode.auto, "one of required, auto, off")
    timeout_s: float = setting(180.0, "a positive number of seconds (wall clock per run_code program)")
    memory_mb: int = setting(2048, f"an integer of at least {MIN_SANDBOX_MEMORY_MB} (MiB: the address space "
                                   "of the run_code process)")

    def __post_init__(self) -> None:
        self.positive("timeout_s")
        self.at_least("memory_mb", MIN_SANDBOX_MEMORY_MB)


@dataclass
class RecordConfig(Section):
    """``record.*``: what an attempt's record holds besides its events (``observers``: cab_core.plugins)."""
    SECTION: ClassVar[str] = "record"
    video: bool = setting(True, "true or false")
    video_every_steps: int = setting(25, "a positive integer (physics steps per video frame; record.video=false "
                                         "records no video)")
    video_size: list[int] = setting(None, f"[width, height]: two integers from {VIDEO_SIDE[0]} to {VIDEO_SIDE[1]} "
                                          "(pixels)", factory=lambda: [320, 240])
    observers: Any = setting(None, "null, a list of observer names or a mapping of name to config")

    def __post_init__(self) -> None:
        self.positive("video_every_steps")
        size = list(self.video_size)
        if len(size) != 2 or not all(VIDEO_SIDE[0] <= s <= VIDEO_SIDE[1] for s in size):
            self.video_size = size
            self.refuse("video_size")


@dataclass
class PerturbConfig(Section):
    """``perturb.*``: small noise on the instance (cab_core.attempt.variation.perturb checks the ranges)."""
    SECTION: ClassVar[str] = "perturb"
    seed: int | None = setting(None, "an integer, or null (no perturbation)")
    position_m: float = setting(0.001, "a number of metres")
    angle_deg: float = setting(0.5, "a number of degrees")
    physics_fraction: float = setting(0.02, "a number (the fraction physical parameters are scaled by, at most)")


class ForkPlanner(Enum):
    parent = "parent"
    own = "own"


@dataclass
class ForkConfig(Section):
    """``fork.*``: start where an earlier attempt stood after its charged call ``at``."""
    SECTION: ClassVar[str] = "fork"
    # ``from`` is a Python keyword: the dataclass cannot name its field so, and the key stays open
    at: int | None = setting(None, "an integer (the charged call of the parent after which the fork starts), or null")
    planner: ForkPlanner = setting(ForkPlanner.parent, "parent (the parent's planner makes the prefix again) or own "
                                                       "(this command's planner=..., e.g. for a parent whose planner is "
                                                       "not installed)")


@dataclass
class SweepConfig(Section):
    """``sweep.*``: infrastructure settings of sweeps (not part of a sweep's fingerprint)."""
    SECTION: ClassVar[str] = "sweep"
    max_infra_retries: int = setting(2, "a non-negative integer (tries after the first)")
    hang_timeout_s: float = setting(900.0, "a positive number of seconds")
    retry_backoff_s: float = setting(10.0, "a number of seconds")
    threads_per_attempt: int | None = setting(1, "a positive integer, or null (unlimited)")
    warm_workers: bool = setting(True, "true or false")
    fork_workers: bool = setting(True, "true or false")
    worker_max_attempts: int = setting(50, "a positive integer")
    worker_max_rss_mb: int = setting(6144, "a positive integer (MiB)")
    max_in_flight: int | None = setting(None, "a positive integer, or null (automatic: from memory for a model's "
                                              "sweep, one per core for model-free agents)")
    in_flight_cap: int = setting(128, "a positive integer")
    memory_reserve_mb: int = setting(2048, "a non-negative integer (MiB)")
    cpu_slots: bool = setting(True, "true or false")
    dry_run: bool = setting(False, "true or false")
    max_cost_usd: float | None = setting(None, "a positive number of USD or null (no spend cap per sweep)")
    preflight_network: bool = setting(True, "true or false")

    def __post_init__(self) -> None:
        self.positive("hang_timeout_s", "threads_per_attempt", "worker_max_attempts", "worker_max_rss_mb",
                      "max_in_flight", "in_flight_cap", "max_cost_usd")
        self.at_least("memory_reserve_mb", 0)


@dataclass
class CabConfig(Section):
    """cab's own top-level keys of an attempt (or, with -m, a sweep)."""
    seed: int | None = setting(None, "a non-negative integer, or null (the task's fixed seed)")
    seed_set: Any = setting(None, "the name of a seed set (with -m), or null")  # Task.seeds(NAME) refuses an unknown one
    attempt: int = setting(1, "a positive integer (1, 2, ...: the repetition of the attempt)")
    budget: BudgetConfig = field(default_factory=BudgetConfig)
    sandbox: SandboxConfig = field(default_factory=SandboxConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    perturb: PerturbConfig = field(default_factory=PerturbConfig)
    fork: ForkConfig = field(default_factory=ForkConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)

    def __post_init__(self) -> None:
        if self.seed is not None and self.seed < 0:
            self.refuse("seed")
        self.positive("attempt")


@dataclass
class ModelBasics(Section):
    """``model.*``: the keys cab itself reads of a model configuration; each option adds its own
    (a provider's, a vendor's): the group is open."""
    SECTION: ClassVar[str] = "model"
    name: str = setting(MISSING, "the name of the model configuration (a string)")
    agent: str | None = setting(None, "the name of a built-in agent (oracle, idle, scripted, human), or null")
    harness: str | None = setting(None, "the name of the harness the model runs in (harness=auto), or null")


@dataclass
class HarnessBasics(Section):
    """``harness.*``: the key cab itself reads; each harness declares its own (the group is open)."""
    SECTION: ClassVar[str] = "harness"
    name: str = setting(MISSING, "the name of the harness (a string)")


#: the config groups whose basic keys the schema declares (the groups stay open to their options' keys)
BASICS: dict[str, type[Section]] = {"model": ModelBasics, "harness": HarnessBasics}


def check_basics(cfg: dict) -> None:
    """Refuse (ConfigError, one line) a selected model or harness option whose basic keys
    (:data:`BASICS`) are not of their types; their other keys are the options' own."""
    for group, basics in BASICS.items():
        option = cfg.get(group)
        if not isinstance(option, dict):
            continue
        root = OmegaConf.create({group: OmegaConf.structured(basics)})  # refusals name the key from the group
        OmegaConf.set_struct(root[group], False)  # open: the option's own keys are added as they are
        try:
            root[group].merge_with(option)
        except OmegaConfBaseException as e:
            raise ConfigError(one_line_error(e, root, lambda key, o=option, g=group: _part(o, g, key))) from None
        where = _converted(option, OmegaConf.to_container(root[group], resolve=False), group)
        if where is not None:
            raise ConfigError(f"{where} must be {_must_be(group, where.rpartition('.')[2])}, "
                              f"got {given(_part(option, group, where))}")


#: each dataclass of the schema by its key ('' the top level)
_ALL: tuple[type[Section], ...] = (CabConfig, BudgetConfig, SandboxConfig, RecordConfig, PerturbConfig, ForkConfig,
                                    SweepConfig, *BASICS.values())
SECTIONS: dict[str, type[Section]] = {section.SECTION: section for section in _ALL}

SCHEMA_NAME = "cab_schema"  # a config of its own, not a group: `cab --help` lists no group "schema"
ConfigStore.instance().store(name=SCHEMA_NAME, node=CabConfig, provider="cab")
for _group, _basics in BASICS.items():
    ConfigStore.instance().store(name=f"{SCHEMA_NAME}_{_group}", node=_basics, provider="cab")
OWN_KEYS = tuple(f.name for f in fields(CabConfig))


def schema() -> DictConfig:
    """The schema as Hydra's ConfigStore holds it (a fresh typed config)."""
    node = ConfigStore.instance().load(f"{SCHEMA_NAME}.yaml").node
    return copy.deepcopy(node)


def _open_fork(view: DictConfig) -> None:
    with open_dict(view.fork):
        view.fork["from"] = None


def checked_view(cfg: dict, open_keys: dict[str, Any] | None = None) -> DictConfig:
    """A typed copy of ``cfg``'s own keys (a plain mapping, interpolations unresolved), refused in
    one line (ConfigError) where they do not fit the schema; ``open_keys`` (the groups, a project's
    keys) are added as they are. The key ``fork.from`` is open (a folder)."""
    view = schema()
    _open_fork(view)
    own = {k: v for k, v in cfg.items() if k in OWN_KEYS}
    try:
        view.merge_with(own)
        with open_dict(view):
            for key, value in (open_keys or {}).items():
                view[key] = value
        OmegaConf.to_object(view)
    except OmegaConfBaseException as e:
        raise ConfigError(one_line_error(e, view, lambda key: OmegaConf.select(OmegaConf.create(own), key))) from None
    for key, value in own.items():
        refuse_converted(view, key, value)
    return view


def check_value(view: DictConfig, key: str, value: Any, option: str | None = None) -> None:
    """Refuse (ConfigError, one line) ``key=value`` on ``view`` (:func:`checked_view`): an unknown
    key, a value of the wrong type or out of its range. ``option`` names the selected option of a
    config group whose keys are checked (``sim=<name>``)."""
    trial = copy.deepcopy(view)
    try:
        OmegaConf.update(trial, key, value, merge=True)
        OmegaConf.to_object(trial)
    except OmegaConfBaseException as e:
        raise ConfigError(one_line_error(e, view, lambda name: _part(value, key, name), key, option)) from None
    refuse_converted(trial, key, value)


def refuse_converted(view: DictConfig, key: str, value: Any) -> None:
    """Refuse a value OmegaConf accepted by converting it (``record.video=yes`` to true, ``seed='5'``
    to 5): the composed configuration keeps the value as given, so it must be of the field's type."""
    typed = OmegaConf.select(view, key)
    if OmegaConf.is_config(typed):
        typed = OmegaConf.to_container(typed, resolve=False)
    where = _converted(value, typed, key)
    if where is not None:
        section, _, leaf = where.rpartition(".")
        must_be = _must_be(section, leaf) or "of its declared type"
        raise ConfigError(f"{where} must be {must_be}, got {given(_part(value, key, where))}")


def _converted(raw: Any, typed: Any, key: str) -> str | None:
    """The key of the first value in ``raw`` that is not ``typed`` as given, or None."""
    if isinstance(raw, dict) and isinstance(typed, dict):
        return next((w for k, v in raw.items() if k in typed and (w := _converted(v, typed[k], f"{key}.{k}"))), None)
    if isinstance(typed, Enum):
        return None if raw == typed.value else key
    if isinstance(raw, list) and isinstance(typed, list):
        same = len(raw) == len(typed) and all(_converted(r, t, key) is None for r, t in zip(raw, typed))
        return None if same else key
    if isinstance(raw, str) and "${" in raw:
        return None  # an interpolation: its value is checked where it is resolved
    if isinstance(raw, bool) or isinstance(typed, bool) or isinstance(raw, str) or isinstance(typed, str):
        return None if type(raw) is type(typed) and raw == typed else key
    return None if raw == typed else key


def _part(value: Any, key: str, name: str) -> Any:
    """The value of ``name`` in ``key=value`` (``sandbox={mode:bogus}``: ``sandbox.mode`` is 'bogus')."""
    if name == key or not name.startswith(key + "."):
        return value
    return OmegaConf.select(OmegaConf.create({"v": value}), "v." + name[len(key) + 1:], default=value)


def one_line_error(e: OmegaConfBaseException, view: DictConfig, value_of: Any, key: str | None = None,
                   option: str | None = None) -> str:
    """OmegaConf's refusal ``e`` in one line with cab's suggestions; ``key`` is the key the user
    gave (``sim.physic.impratio``, where OmegaConf stops at ``sim.physic``)."""
    full = str(e.full_key or "")
    if isinstance(e, (ConfigKeyError, ConfigAttributeError)):
        return unknown_key(view, full, key or full, option)
    if isinstance(e, ValidationError):
        name = full.split("[")[0]
        section, _, leaf = name.rpartition(".")
        must_be = _must_be(section, leaf)
        if must_be is not None:
            return f"{name} must be {must_be}, got {given(value_of(name))}"
    return one_line(e)


def one_line(e: BaseException) -> str:
    """Hydra's or OmegaConf's message of several lines in one (without its "See https://..." line)."""
    lines = [line.strip() for line in str(e).splitlines() if line.strip() and not line.strip().startswith("See https://")]
    return ": ".join(lines) if lines else type(e).__name__


def _must_be(section: str, leaf: str) -> str | None:
    """What the field ``leaf`` of ``section`` ('' the top level) must be, as its schema says."""
    node: Any = SECTIONS.get(section)
    if node is None:
        return None
    return next((f.metadata.get("must_be") for f in fields(node) if f.name == leaf), None)


def unknown_key(view: DictConfig, failed: str, key: str, option: str | None = None) -> str:
    """``unknown key 'budget.tool_calsl'; did you mean budget.tool_calls? valid keys under budget: ...``"""
    where, _, name = failed.rpartition(".")
    node = OmegaConf.select(view, where) if where else view
    valid = [str(k) for k in node] if isinstance(node, DictConfig) else []
    near = closest(name, valid)
    if not where:
        hint = f"did you mean {' or '.join(near)}? " if near else ""
        return f"unknown key {name!r}; {hint}valid top-level keys: {', '.join(valid)}"
    hint = f"did you mean {' or '.join(f'{where}.{n}' for n in near)}? " if near else ""
    of = f" ({key.split('.')[0]}={option})" if option else ""
    return f"unknown key {key!r}; {hint}valid keys under {where}{of}: {', '.join(valid) or '(none)'}"
