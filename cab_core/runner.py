"""From a composed config to a finished, recorded attempt."""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from .cmdline import BUDGET_KEYS, check_budget_value
from .episode import AttemptSpec, Episode
from .errors import ConfigError
from .faults import is_infrastructure_fault
from .perturb import Perturbation

log = logging.getLogger("cab")


def _plain(cfg: Any) -> dict:
    try:
        from omegaconf import OmegaConf

        if OmegaConf.is_config(cfg):
            return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    except ImportError:  # pragma: no cover
        pass
    return dict(cfg)


_GROUP_KINDS = {"sim": "simulators", "embodiment": "embodiments", "planner": "planners", "harness": "harnesses"}


def _installed(group: str) -> str:
    """What the installed plugins offer for an unset config group, in words."""
    from .plugins import registry, task_names

    names = task_names() if group == "task" else sorted(registry(_GROUP_KINDS[group])) if group in _GROUP_KINDS else []
    return f"installed: {', '.join(names)}" if names else "none installed" if group != "model" else "see cab --help"


def attempt_spec(cfg: Any, output_dir: Path) -> AttemptSpec:
    """Validate a composed config into one AttemptSpec (budgets and seed from the task's suite)."""
    from .plugins import task_info

    c = _plain(cfg)
    for key in ("task", "sim", "embodiment", "planner", "harness", "model"):
        if c.get(key) is None:
            raise ConfigError(f"no {key} selected: add {key}=<option> ({_installed(key)})")
        if not isinstance(c[key], dict) or not c[key].get("name"):
            raise ConfigError(f"config group {key!r} has no name")
    info = task_info(c["task"]["name"])
    b = c.get("budget") or {}
    seed = c.get("seed")
    seed = info.seed if seed is None else seed
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    attempt = c.get("attempt", 1)
    if not isinstance(attempt, int) or attempt < 1:
        raise ConfigError(f"attempt must be a positive integer, got {attempt!r}")
    harness = c["harness"]["name"]
    if harness == "auto":  # the harness the model config asks for
        harness = c["model"].get("harness")
        if not harness:
            raise ConfigError(f"model {c['model']['name']!r} names no harness (model.harness); "
                              "give one with harness=<name> (cab-plugins lists the installed harnesses)")
    unknown = sorted(set(b) - set(BUDGET_KEYS))
    if unknown:
        raise ConfigError(f"unknown budget key(s) {', '.join(unknown)}; valid: {', '.join(BUDGET_KEYS)}")
    for k in BUDGET_KEYS:  # null: the catalog's (0 is no budget: refused, never the catalog's)
        check_budget_value(k, b.get(k))
    tool_calls = info.budget_tool_calls if b.get("tool_calls") is None else b["tool_calls"]
    sim_s = info.budget_sim_s if b.get("sim_seconds") is None else b["sim_seconds"]
    wall_s = info.budget_wall_s if b.get("wall_seconds") is None else b["wall_seconds"]
    max_internal = 500 if b.get("run_code_max_internal_calls") is None else b["run_code_max_internal_calls"]
    perturbation = Perturbation.from_cfg(c.get("perturb"))
    return AttemptSpec(
        task=info.name, seed=int(seed), attempt=int(attempt), sim=c["sim"]["name"], embodiment=c["embodiment"]["name"],
        planner=c["planner"]["name"], harness=harness, model=c["model"]["name"], output_dir=Path(output_dir),
        budget_tool_calls=int(tool_calls), budget_sim_seconds=float(sim_s), budget_wall_seconds=float(wall_s),
        run_code_max_internal_calls=int(max_internal),
        sandbox=dict(c.get("sandbox") or {}), record=dict(c.get("record") or {}),
        sim_cfg=c["sim"], planner_cfg=c["planner"], embodiment_cfg=c["embodiment"], model_cfg=c["model"],
        harness_cfg={**(c["harness"] if c["harness"]["name"] == harness else {}), "name": harness},
        perturb=None if perturbation is None else perturbation.as_record(),
    )


def run_attempt(spec: AttemptSpec) -> dict:
    """Build everything through the plugin registry, run the harness, score, record."""
    from .observers import select as select_observers
    from .plugins import all_tasks, create

    tasks = all_tasks()
    if spec.task not in tasks:
        raise ConfigError(f"unknown task {spec.task!r}; choices: {', '.join(sorted(tasks)) or '(none installed)'}")
    observers = select_observers(spec.record)  # an unknown name is refused before anything starts
    harness = create("harnesses", spec.harness, {**spec.harness_cfg, "name": spec.harness})
    preflight = getattr(harness, "preflight", None)
    if preflight is not None:  # credentials and endpoints are checked before any simulator starts
        preflight(spec.model_cfg)
    before_build = getattr(harness, "before_build", None)
    if before_build is not None:  # e.g. a server that answers its client while the world is built
        before_build(spec)
    try:
        emb = create("embodiments", spec.embodiment, spec.embodiment_cfg)
        planner = create("planners", spec.planner, spec.planner_cfg)
        sim = create("simulators", spec.sim, spec.sim_cfg)
        episode = Episode(spec, tasks[spec.task], sim, planner, emb, observers)
    except BaseException:
        close = getattr(harness, "close", None)
        if close is not None:
            close()
        raise
    try:
        try:
            harness.run(episode, spec.model_cfg)
        except Exception as e:  # the fault rule (cab_core.faults): only a broken host is not scored
            log.exception("harness failed")
            episode.end("host_fault" if is_infrastructure_fault(e) else "harness_error", f"harness: {e!r}")
        return episode.finish()
    finally:
        episode.close()
