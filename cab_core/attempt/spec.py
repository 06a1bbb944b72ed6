"""What one attempt is, fully resolved: :class:`AttemptSpec`, validated from a composed Hydra
configuration by :func:`attempt_spec` (budgets and seed from the task's suite where the config
leaves them null). ``result.json`` and the ``attempt_start`` event carry it (:meth:`AttemptSpec.as_record`),
so a replay rebuilds the attempt from its records."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from cab_core.attempt.fork import ForkPoint, fork_config
from cab_core.attempt.variation.perturb import Perturbation
from cab_core.attempt.variation.randomize import Randomization
from cab_core.conf.schema import check_basics, checked_view
from cab_core.errors import ConfigError
from cab_core.plugins import registry, task_info, task_names


@dataclass
class AttemptSpec:
    """One attempt, fully resolved and validated from the Hydra config."""
    task: str
    seed: int
    attempt: int
    sim: str
    embodiment: str
    planner: str
    harness: str
    model: str
    output_dir: Path
    budget_tool_calls: int
    budget_sim_seconds: float
    budget_wall_seconds: float
    run_code_max_internal_calls: int = 500
    #: the spend cap of the attempt (``budget.cost_usd``, USD); None: none
    budget_cost_usd: float | None = None
    sandbox: dict = field(default_factory=dict)
    record: dict = field(default_factory=lambda: {"video": True, "video_every_steps": 25, "video_size": [320, 240]})
    sim_cfg: dict = field(default_factory=dict)
    planner_cfg: dict = field(default_factory=dict)
    embodiment_cfg: dict = field(default_factory=dict)
    model_cfg: dict = field(default_factory=dict)
    harness_cfg: dict = field(default_factory=dict)
    perturb: dict | None = None  # cab_core.attempt.variation.perturb.Perturbation fields; None: the instance as sampled
    #: appearance randomisation (:mod:`cab_core.attempt.variation.randomize`): the option's name and the
    #: parameters of the parts it draws; None: the scene as the task draws it
    randomize: dict | None = None
    #: a fork (:mod:`cab_core.attempt.fork`): ``{"parent": <the parent's folder, relative to
    #: output_dir>, "at": K}``; None: an attempt from the scene's start
    fork: dict | None = None

    def as_record(self) -> dict:
        """Everything but the output directory: what a replay needs to rebuild the attempt."""
        return {k: v for k, v in asdict(self).items() if k != "output_dir"}


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
    names = task_names() if group == "task" else sorted(registry(_GROUP_KINDS[group])) if group in _GROUP_KINDS else []
    return f"installed: {', '.join(names)}" if names else "none installed" if group != "model" else "see cab --help"


def attempt_spec(cfg: Any, output_dir: str | Path) -> AttemptSpec:
    """Validate a composed config into one AttemptSpec (budgets and seed from the task's suite)."""
    c = _plain(cfg)
    for key in ("task", "sim", "embodiment", "planner", "harness", "model"):
        if c.get(key) is None:
            raise ConfigError(f"no {key} selected: add {key}=<option> ({_installed(key)})")
        if not isinstance(c[key], dict) or not c[key].get("name"):
            raise ConfigError(f"config group {key!r} has no name")
    checked_view(c)  # cab's own keys against the schema (cab_core.conf.schema): one line for the first mistake
    check_basics(c)  # the model's and the harness's names (the options' other keys are theirs)
    info = task_info(c["task"]["name"])
    b = c.get("budget") or {}
    seed = c.get("seed")
    seed = info.seed if seed is None else seed
    attempt = c.get("attempt", 1)
    harness = c["harness"]["name"]
    if harness == "auto":  # the harness the model config asks for
        harness = c["model"].get("harness")
        if not harness:
            raise ConfigError(f"model {c['model']['name']!r} names no harness (model.harness); "
                              "give one with harness=<name> (cab-plugins lists the installed harnesses)")
    tool_calls = info.budget_tool_calls if b.get("tool_calls") is None else b["tool_calls"]
    sim_s = info.budget_sim_s if b.get("sim_seconds") is None else b["sim_seconds"]
    wall_s = info.budget_wall_s if b.get("wall_seconds") is None else b["wall_seconds"]
    max_internal = 500 if b.get("run_code_max_internal_calls") is None else b["run_code_max_internal_calls"]
    perturbation = Perturbation.from_cfg(c.get("perturb"))
    randomization = Randomization.from_cfg(c.get("randomize"))
    spec = AttemptSpec(
        task=info.name, seed=int(seed), attempt=int(attempt), sim=c["sim"]["name"], embodiment=c["embodiment"]["name"],
        planner=c["planner"]["name"], harness=harness, model=c["model"]["name"], output_dir=Path(output_dir),
        budget_tool_calls=int(tool_calls), budget_sim_seconds=float(sim_s), budget_wall_seconds=float(wall_s),
        run_code_max_internal_calls=int(max_internal),
        budget_cost_usd=None if b.get("cost_usd") is None else float(b["cost_usd"]),
        sandbox=dict(c.get("sandbox") or {}), record=dict(c.get("record") or {}),
        sim_cfg=c["sim"], planner_cfg=c["planner"], embodiment_cfg=c["embodiment"], model_cfg=c["model"],
        harness_cfg={**(c["harness"] if c["harness"]["name"] == harness else {}), "name": harness},
        perturb=None if perturbation is None else perturbation.as_record(),
        randomize=None if randomization is None else randomization.as_record(),
    )
    return forked(spec, c.get("fork") or {})


def forked(spec: AttemptSpec, fork: dict) -> AttemptSpec:
    """``spec`` as a fork of ``fork["from"]`` after its charged call ``fork["at"]``: the parent's
    world and budgets, this spec's agent, harness, records and output directory."""
    if fork.get("from") is None:
        if fork.get("at") is not None:
            raise ConfigError("fork.at needs fork.from=<the folder of the attempt to fork>")
        return spec
    if fork.get("at") is None:
        raise ConfigError("fork.from needs fork.at=<K>: the charged call of the parent after which the fork starts")
    point = ForkPoint.load(fork["from"], fork["at"])
    which = fork.get("planner") or "parent"
    if which not in ("parent", "own"):
        raise ConfigError(f"fork.planner must be parent (the parent's planner) or own (this command's), got {which!r}")
    out = AttemptSpec(**fork_config(asdict(spec), point))
    if out.task not in task_names():
        raise ConfigError(f"fork.from: the parent's task {out.task!r} is not installed")
    out.fork = point.as_record(out.output_dir)
    if which == "parent" and out.planner not in registry("planners"):
        raise ConfigError(f"fork.from: the parent's planner {out.planner!r} is not installed (installed: "
                          f"{', '.join(sorted(registry('planners')))}); fork.planner=own makes the prefix again "
                          f"with this command's planner ({spec.planner})")
    if which == "own" and spec.planner != out.planner:
        # the prefix is made again by another planner: compared with the parent's snapshots like any
        # prefix (ForkDiverged where the paths differ by more than the tolerance)
        out.fork["planner"] = {"parent": out.planner, "fork": spec.planner}
        out.planner, out.planner_cfg = spec.planner, spec.planner_cfg
    return out
