"""Each configuration's comparison contract before a sweep runs (``contracts`` in ``sweep.json``):
what ``cab -m`` computes from the sweep's jobs and hands to the manifest
(:class:`cab_core.sweep.manifest.SweepManifest`). The contract itself: :mod:`cab_core.attempt.contract`,
how reports compare contracts: :mod:`cab_core.analysis.contract`."""
from __future__ import annotations

from dataclasses import replace
from typing import Any

from omegaconf import OmegaConf

from cab_core.analysis.configurations import configuration_labels
from cab_core.attempt.contract import combined
from cab_core.attempt.engine.contract import attempt_contract
from cab_core.attempt.spec import AttemptSpec, attempt_spec
from cab_core.plugins import task_info, task_names
from cab_core.sweep.layout import _fixed_overrides, _parsed, _strings


def _plain(node: Any) -> Any:
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


#: the keys of a composed config an attempt's spec is made of (:func:`cab_core.attempt.spec.attempt_spec`)
_SPEC_KEYS = ("task", "sim", "embodiment", "planner", "harness", "model", "seed", "attempt", "budget", "sandbox",
              "record", "perturb", "randomize", "fork")


def sweep_contracts(cfg: Any, jobs: list[list[str]]) -> dict[str, dict]:
    """The comparison contract of each configuration of the sweep (:mod:`cab_core.analysis.contract`),
    by the label cab-report gives it: each job's attempt contract from its spec, combined over the
    configuration's jobs. One composition per job without its task, seed and attempt: an installed
    task's option is ``{name: <task>}`` (:func:`cab_core.config.register_task_configs`); a task
    option that is not an installed task's name is composed with the job."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.types import RunMode

    fixed = _fixed_overrides(cfg)
    hydra_overrides = _strings(cfg.hydra.overrides.hydra)
    loader = GlobalHydra.instance().config_loader()
    composed: dict[tuple[str, ...], dict] = {}
    specs = []
    installed = set(task_names())
    checked: dict[tuple[str, ...], AttemptSpec] = {}
    for job in jobs:
        values = dict(o.split("=", 1) for o in job)
        task = values.get("task")
        by_name = task in installed
        key = tuple(o for o in job if o.split("=", 1)[0] not in ("seed", "attempt", *(("task",) if by_name else ())))
        if key not in composed:
            c = loader.load_configuration(config_name=cfg.hydra.job.config_name,
                                          overrides=[*hydra_overrides, *fixed, *key], run_mode=RunMode.RUN)
            composed[key] = {k: _plain(c[k]) for k in _SPEC_KEYS if k in c}
        plain = dict(composed[key])
        if by_name:
            plain["task"] = {"name": task}
        for k in ("seed", "attempt"):
            if k in values:
                plain[k] = _parsed(values[k])
        if key not in checked:  # validated once per composition (0.1 s each), the tasks and seeds as the spec reads them
            checked[key] = attempt_spec(plain, ".")
        specs.append(_with_task(checked[key], plain) if checked[key].fork is None else attempt_spec(plain, "."))
    labels = configuration_labels([{"model": s.model, "harness": s.harness, "sim": s.sim, "model_cfg": s.model_cfg,
                                    "task": s.task} for s in specs])
    by: dict[str, list[dict]] = {}
    for label, s in zip(labels, specs):
        by.setdefault(label, []).append(attempt_contract(s))
    return {label: combined(cs) for label, cs in sorted(by.items())}


def _with_task(spec: AttemptSpec, plain: dict) -> AttemptSpec:
    """``spec`` (validated) for the task, seed and attempt of ``plain``: budgets and seed from the task's
    suite where the config leaves them null, as :func:`attempt_spec` takes them."""
    info = task_info(plain["task"]["name"])
    b = plain.get("budget") or {}
    seed = info.seed if plain.get("seed") is None else plain["seed"]
    return replace(spec, task=info.name, seed=int(seed), attempt=int(plain.get("attempt", 1)),
                   budget_tool_calls=int(info.budget_tool_calls if b.get("tool_calls") is None else b["tool_calls"]),
                   budget_sim_seconds=float(info.budget_sim_s if b.get("sim_seconds") is None else b["sim_seconds"]),
                   budget_wall_seconds=float(info.budget_wall_s if b.get("wall_seconds") is None
                                             else b["wall_seconds"]))
