"""Where each attempt of a sweep writes: ``<task>/<model>/<sim>/[<swept>/]seed-<S>/attempt-<A>``.

The task, the model, the simulator, the seed and the attempt number are folders of their own
(``hydra.sweep.subdir`` in ``cab_core/conf/cab.yaml``). Every other key a sweep varies (``planner=``,
``budget.tool_calls=``, ``sim.physics.impratio=``, ``sandbox.mode=`` ...) is named in one more
folder between the simulator and the seed, ``<key>=<value>[,<key>=<value>...]``, keys sorted, each
key and value made path-safe by percent-encoding every character other than letters, digits and
``._-`` (injective: two different values never give the same folder). A key the sweep lists with
one value only is not named (it is the same for every job).

Which keys vary is a property of the whole sweep, which one job cannot see: the manifest
(``sweep.json``, written before any job starts) records them as ``path_keys``, and the resolver
``cab.swept`` reads them back in each job. Before anything runs, :func:`check_distinct` refuses a
sweep two of whose jobs would write to the same folder.
"""
from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any
from urllib.parse import quote

from omegaconf import OmegaConf

from cab_core.config import scene_seed
from cab_core.errors import ConfigError

# Keys the layout names by folders of their own; a sweep over any other key adds the swept folder.
OWN_FOLDERS = ("task", "model", "sim", "seed", "attempt")
SAFE = "._-"
MAX_COMPONENT = 200  # bytes; file systems allow 255 per path component


class SweepJobsCollide(ConfigError):
    """Two jobs of one sweep would write to the same attempt folder."""


def _key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def path_safe(text: str) -> str:
    """``text`` with every character other than letters, digits and ``._-`` percent-encoded."""
    return quote(str(text), safe=SAFE)


def varying_keys(jobs: Iterable[list[str]]) -> list[str]:
    """The keys that take more than one value across the jobs, minus those with folders of their own."""
    values: dict[str, set[str]] = {}
    for job in jobs:
        for o in job:
            if "=" in o:
                values.setdefault(_key(o), set()).add(o.split("=", 1)[1])
    return sorted(k for k, v in values.items() if len(v) > 1 and k not in OWN_FOLDERS)


def swept_component(overrides: Iterable[str], path_keys: Iterable[str]) -> str:
    """The folder naming this job's values of ``path_keys`` with its trailing ``/``; "" when none."""
    keys = set(path_keys)
    items = sorted((_key(o), o.split("=", 1)[1]) for o in overrides if "=" in o and _key(o) in keys)
    if not items:
        return ""
    name = ",".join(f"{path_safe(k)}={path_safe(v)}" for k, v in items)
    if len(name.encode()) > MAX_COMPONENT:  # keep it readable, and distinct through the digest
        name = f"{name[:MAX_COMPONENT - 20]}...{hashlib.sha256(name.encode()).hexdigest()[:12]}"
    return name + "/"


def manifest_path_keys(sweep_dir: str | Path) -> list[str]:
    """The ``path_keys`` of the manifest in ``sweep_dir`` (written before any job of the sweep runs)."""
    path = Path(str(sweep_dir)) / "sweep.json"
    try:
        return list(json.loads(path.read_text())["path_keys"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"{path}: no readable path_keys ({type(e).__name__}: {e}); cab sweeps write it "
                          "through the hydra.callbacks.sweep_manifest callback before any job starts") from e


def _swept_resolver(sweep_dir: Any, overrides: Any) -> str:
    """Resolver ``cab.swept``: ``${cab.swept:${hydra.sweep.dir},${hydra.overrides.task}}``."""
    return swept_component(_strings(overrides), manifest_path_keys(sweep_dir))


def _strings(overrides: Any) -> list[str]:
    """A list of overrides (a Hydra list node such as ``hydra.overrides.task``, or a plain sequence) as strings."""
    plain = OmegaConf.to_container(overrides) if OmegaConf.is_config(overrides) else list(overrides)
    if not isinstance(plain, list):
        raise ConfigError(f"expected a list of overrides, got {plain!r}")
    return [str(o) for o in plain]


def folder_safe(value: Any) -> str:
    """Resolver ``cab.folder_safe``: ``value`` as one folder name, every run of characters other than
    letters, digits, ``.``, ``_`` and ``-`` made one ``_`` (a model id ``Qwen/Qwen3-VL-8B`` names the
    configuration of a generic model option ``Qwen_Qwen3-VL-8B``; Ollama's ``qwen3-vl:8b``, ``qwen3-vl_8b``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(value)).strip("._") or "_"


# Registered on import (cab_core.apps.cli imports this module): Hydra resolves each job's directory in the
# launcher's worker process, which imports the app's module.
if not OmegaConf.has_resolver("cab.swept"):
    OmegaConf.register_new_resolver("cab.swept", _swept_resolver)
if not OmegaConf.has_resolver("cab.folder_safe"):
    OmegaConf.register_new_resolver("cab.folder_safe", folder_safe)


# -- the guard ------------------------------------------------------------------------------------

def _values(job: list[str]) -> dict[str, str]:
    return {_key(o): o.split("=", 1)[1] for o in job if "=" in o}


def _parsed(value: str) -> Any:
    """An override's value as the job's config will hold it (``1`` -> 1, ``null`` -> None)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return OverridesParser.create().parse_override(f"x={value}").value()


def attempt_folders(cfg: Any, jobs: list[list[str]], path_keys: list[str]) -> list[str]:
    """Each job's attempt folder under the sweep directory, as the default ``hydra.sweep.subdir``
    resolves it: task, model and simulator by the ``name`` their config gives them (one
    composition per swept option), the seed the attempt runs (``seed: null``: the task's catalog
    seed), the attempt number, and the swept folder."""
    base = {g: cfg[g].name for g in ("task", "model", "sim")}
    names: dict[tuple[str, str], str] = {}
    fixed = _fixed_overrides(cfg)
    for job in jobs:
        for g, opt in _values(job).items():
            if g in base and (g, opt) not in names:
                names[(g, opt)] = _option_name(cfg, [o for o in fixed if _key(o) != g], g, opt)
    out = []
    for job in jobs:
        v = _values(job)
        # names holds (g, v[g]) for every swept group g of this job (the loop above)
        name = {g: v.get(f"{g}.name", names[(g, v[g])] if g in v else base[g]) for g in base}
        seed = _parsed(v["seed"]) if "seed" in v else cfg.seed
        attempt = _parsed(v["attempt"]) if "attempt" in v else cfg.attempt
        out.append(f"{name['task']}/{name['model']}/{name['sim']}/{swept_component(job, path_keys)}"
                   f"seed-{scene_seed(seed, name['task'])}/attempt-{attempt}")
    return out


def _fixed_overrides(cfg: Any) -> list[str]:
    """The sweep's overrides that are not sweeps (the same in every job)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    given = _strings(cfg.hydra.overrides.task)
    parsed = OverridesParser.create().parse_overrides(given)
    return [o for o, p in zip(given, parsed) if not p.is_sweep_override()]


def _option_name(cfg: Any, fixed: list[str], group: str, option: str) -> str:
    """``<group>.name`` of the config composed with ``group=option`` and the sweep's fixed overrides."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.types import RunMode

    hydra_overrides = _strings(cfg.hydra.overrides.hydra)  # as Hydra's jobs
    composed = GlobalHydra.instance().config_loader().load_configuration(
        config_name=cfg.hydra.job.config_name, overrides=[*hydra_overrides, *fixed, f"{group}={option}"],
        run_mode=RunMode.RUN)
    return str(composed[group].name)


def check_distinct(folders: list[str], jobs: list[list[str]]) -> None:
    """Raise SweepJobsCollide naming the first folder two jobs would share."""
    seen: dict[str, list[str]] = {}
    for folder, job in zip(folders, jobs):
        if folder in seen:
            raise SweepJobsCollide(
                f"jobs [{' '.join(seen[folder])}] and [{' '.join(job)}] would both write {folder}; nothing ran. "
                "Sweep over values that name different attempts (a seed given twice, e.g. seed=null and the "
                "task's own seed, or two options with the same name, are the same attempt)")
        seen[folder] = job
