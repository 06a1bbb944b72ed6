"""A command's plan before anything runs (``sweep.dry_run=true``), and the pre-flight of its model
configurations before the first attempt.

Both start from the configuration Hydra composed for the command (a single run's, or a sweep's with
its jobs: :class:`SweepJobs`), compose each distinct choice of model,
harness and simulator once (not once per job: 675 jobs of ``experiment=paper`` are 9 compositions),
and group the jobs into configurations named as reports name them
(:func:`cab_core.analysis.configurations.configuration_labels`). Each configuration's harness is asked
what it can check before an attempt (``check_model``: credentials, the endpoint, its model list, a
local server's capabilities); a harness without ``check_model`` (the built-in agents) has nothing to
check. The plan adds, per configuration, the cost range and the time its jobs will take: tokens per
attempt priced at the configuration's ``pricing`` from earlier records of the same configuration
(below the sweep folder, ``./outputs`` and ``./multirun``), else the paper's published figures
(``model.paper_usage``), each figure with its source; the ETA divides the attempt-time by the
attempts in flight (``hydra.launcher.n_jobs``; -1: one per core)."""
from __future__ import annotations

import json
import math
import os
import statistics
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cab_core.analysis.configurations import configuration_labels, identity
from cab_core.contracts.harness import ModelCheck
from cab_core.errors import CabError
from cab_core.kits.harness.pricing import Usage, cost
from cab_core.plugins import create
from cab_core.sweep.attempt_state import SET_ASIDE, is_infrastructure_failure

RECORD_ROOTS = ("outputs", "multirun")  # below the working directory: where earlier attempts are looked for
_COMPOSED = ("model", "harness", "sim")  # the groups that make a configuration (and what fixes them)


@dataclass
class Configuration:
    """The jobs of one model configuration, and what is known of it before they run."""
    label: str
    model_cfg: dict
    harness: str
    harness_cfg: dict
    jobs: int = 0
    todo: int = 0  # jobs without a complete record yet
    check: ModelCheck = field(default_factory=ModelCheck)
    records: list[dict] = field(default_factory=list)  # earlier attempts: {"usd", "wall_s"}

    @property
    def name(self) -> str:
        return str(self.model_cfg.get("name"))


def _plain(node: Any) -> Any:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


def _key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def _shapes(override: str) -> bool:
    """Whether an override can change a job's model, harness or simulator configuration."""
    k = _key(override)
    return any(k == g or k.startswith(g + ".") or k.startswith(g + "/") for g in _COMPOSED)


def _describe(c: dict) -> tuple[dict, str, dict, str]:
    """(model config, harness name, harness config, simulator name) of a composed plain config, as
    :func:`cab_core.attempt.spec.attempt_spec` reads them."""
    model = dict(c.get("model") or {})
    hcfg = dict(c.get("harness") or {})
    harness = str(hcfg.get("name") or "")
    if harness == "auto":
        harness = str(model.get("harness") or "")
    return model, harness, ({**hcfg, "name": harness} if hcfg.get("name") == harness else {"name": harness}), \
        str((c.get("sim") or {}).get("name"))


@dataclass
class SweepJobs:
    """A sweep's jobs as its manifest sees them (the caller reads them with
    :mod:`cab_core.sweep.manifest`, which this module does not import: it would put the plan a level
    above the manifest, and ``cab`` a level above both): each job's overrides, 1 for a job still to run
    (0: complete in the sweep folder being resumed), and why the sweep folder would refuse this sweep."""
    jobs: list[list[str]]
    todo: list[int]
    folder_problem: str | None = None


def configurations(config: Any, sweep: SweepJobs | None) -> list[Configuration]:
    """The configurations of the command Hydra composed ``config`` for, each with its jobs counted
    (and those still to run, for a sweep being resumed)."""
    if sweep is None:
        model, harness, hcfg, sim = _describe({k: _plain(config[k]) for k in _COMPOSED if k in config})
        labels = configuration_labels([{"model": model.get("name"), "harness": harness, "sim": sim, "model_cfg": model}])
        return [Configuration(labels[0], model, harness, hcfg, jobs=1, todo=1)]
    from hydra.core.global_hydra import GlobalHydra
    from hydra.types import RunMode

    jobs, todo = sweep.jobs, sweep.todo
    given = [str(o) for o in _plain(config.hydra.overrides.task)]
    from hydra.core.override_parser.overrides_parser import OverridesParser

    fixed = [o for o, p in zip(given, OverridesParser.create().parse_overrides(given)) if not p.is_sweep_override()]
    hydra_overrides = [str(o) for o in _plain(config.hydra.overrides.hydra)]
    loader = GlobalHydra.instance().config_loader()
    shapes: dict[tuple[str, ...], tuple[dict, str, dict, str]] = {}
    per_job = []
    for job in jobs:
        key = tuple(o for o in job if _shapes(o))
        if key not in shapes:
            composed = loader.load_configuration(config_name=config.hydra.job.config_name,
                                                 overrides=[*hydra_overrides, *fixed, *key], run_mode=RunMode.RUN)
            shapes[key] = _describe({k: _plain(composed[k]) for k in _COMPOSED if k in composed})
        per_job.append(key)
    keys = list(shapes)
    labels = configuration_labels([{"model": m.get("name"), "harness": h, "sim": s, "model_cfg": m}
                                   for m, h, _, s in (shapes[k] for k in keys)])
    out: dict[str, Configuration] = {}
    for k, label in zip(keys, labels):
        m, h, hcfg, _ = shapes[k]
        out.setdefault(label, Configuration(label, m, h, hcfg))
    label_of = dict(zip(keys, labels))
    for key, left in zip(per_job, todo):
        conf = out[label_of[key]]
        conf.jobs += 1
        conf.todo += left
    return list(out.values())


def check(conf: Configuration, network: bool) -> ModelCheck:
    """What the configuration's harness finds (``check_model``); a harness that cannot be created
    is a problem of the configuration."""
    try:
        harness = create("harnesses", conf.harness, dict(conf.harness_cfg))
    except CabError as e:
        return ModelCheck(problems=[str(e)])
    checker = getattr(harness, "check_model", None)
    if checker is None:  # nothing to check (a built-in agent)
        return ModelCheck()
    return checker(dict(conf.model_cfg), network=network)


def preflight(confs: list[Configuration], network: bool) -> list[str]:
    """Check each configuration with jobs to run; one line per problem, naming the configuration."""
    lines = []
    for conf in confs:
        if conf.todo == 0:
            continue
        conf.check = check(conf, network)
        lines += [f"{conf.label}: {p}" for p in conf.check.problems]
    return lines


# -- the estimate ---------------------------------------------------------------------------------

def record_dirs(config: Any, multirun: bool) -> list[Path]:
    """Where earlier attempts are looked for: the sweep folder, ./outputs and ./multirun."""
    dirs = [Path(str(config.hydra.sweep.dir))] if multirun else []
    return dirs + [Path(r) for r in RECORD_ROOTS]


def _events(folder: Path) -> tuple[dict | None, dict | None]:
    """The attempt's ``attempt_start`` and ``model_usage_total`` events (None where absent)."""
    start = total = None
    try:
        with open(folder / "events.jsonl", encoding="utf-8") as f:
            for line in f:
                if '"attempt_start"' in line or '"model_usage_total"' in line:
                    try:
                        e = json.loads(line)
                    except ValueError:
                        continue
                    if e.get("kind") == "attempt_start":
                        start = e
                    elif e.get("kind") == "model_usage_total":
                        total = e
    except OSError:
        pass
    return start, total


def attach_records(confs: list[Configuration], roots: Iterable[Path]) -> None:
    """Each configuration's earlier attempts (scored ones, of the same model name and identity
    settings): their cost at the configuration's pricing and their wall time."""
    by_name: dict[str, list[Configuration]] = {}
    for c in confs:
        by_name.setdefault(c.name, []).append(c)
    seen: set[Path] = set()
    for root in roots:
        if not root.is_dir():
            continue
        for p in root.rglob("result.json"):
            rp = p.resolve()
            if rp in seen or SET_ASIDE in p.parts:
                continue
            seen.add(rp)
            try:
                res = json.loads(p.read_text())
            except (OSError, ValueError):
                continue
            if not isinstance(res, dict) or res.get("model") not in by_name or is_infrastructure_failure(res):
                continue
            start, total = _events(p.parent)
            if total is None:
                continue
            cfg = ((start or {}).get("config") or {}).get("model_cfg")
            for c in by_name[str(res["model"])]:
                if isinstance(cfg, dict) and identity(cfg) != identity(c.model_cfg):
                    continue
                u = Usage(**{k: int(total.get(k) or 0) for k in ("input_tokens", "output_tokens",
                                                                  "cache_read_tokens", "cache_write_tokens")})
                usd = cost(u, c.model_cfg.get("pricing"))["usd"]
                c.records.append({"usd": total.get("usd") if usd is None else usd,
                                  "wall_s": (res.get("timing") or {}).get("wall_seconds")})


@dataclass
class Estimate:
    """Per attempt: a cost range (USD, 25th to 75th percentile) and a mean time, each with its source."""
    usd: tuple[float, float] | None
    usd_source: str
    wall_s: float | None
    wall_source: str


def estimate(conf: Configuration) -> Estimate:
    costs = [float(r["usd"]) for r in conf.records if r.get("usd") is not None]
    walls = [float(r["wall_s"]) for r in conf.records if r.get("wall_s") is not None]
    paper = conf.model_cfg.get("paper_usage") or {}
    if costs:
        q = statistics.quantiles(costs, n=4, method="inclusive") if len(costs) > 1 else [costs[0]] * 3
        usd: tuple[float, float] | None = (q[0], q[2])
        usd_source = f"{len(costs)} earlier record(s)"
    elif not conf.model_cfg.get("pricing"):
        usd, usd_source = (0.0, 0.0), ("no model API" if conf.harness == "direct" else "model.pricing is null")
    elif paper.get("cost_usd_iqr"):
        lo, hi = (float(x) for x in paper["cost_usd_iqr"])
        usd, usd_source = (lo, hi), "the paper's per-attempt IQR (model.paper_usage)"
    else:
        usd, usd_source = None, "unknown: no earlier record, no paper figure"
    if walls:
        wall: float | None = statistics.fmean(walls)
        wall_source = f"mean of {len(walls)} earlier record(s)"
    elif paper.get("wall_s_median"):
        wall, wall_source = float(paper["wall_s_median"]), "the paper's median"
    else:
        wall, wall_source = None, "unknown"
    return Estimate(usd, usd_source, wall, wall_source)


def in_flight(config: Any, multirun: bool) -> int:
    """The attempts a command runs at once: 1 for a single run, else the launcher's ``n_jobs``
    (-1 or less: cores + 1 + n_jobs, as cab's launcher and joblib count)."""
    if not multirun:
        return 1
    from omegaconf import OmegaConf

    n = OmegaConf.select(config, "hydra.launcher.n_jobs", default=1)
    try:
        n = int(n)
    except (TypeError, ValueError):
        return 1
    cores = os.cpu_count() or 1
    return max(1, n if n > 0 else cores + 1 + n)


def _hm(seconds: float) -> str:
    m = int(math.ceil(seconds / 60))
    return f"{m // 60}h{m % 60:02d}m" if m >= 60 else f"{m} min"


def _usd(x: float) -> str:
    return f"${x:,.2f}" if x < 100 else f"${x:,.0f}"


def plan_lines(confs: list[Configuration], slots: int, network: bool) -> list[str]:
    """The plan as printed: one block per configuration, then the totals."""
    total_jobs = sum(c.jobs for c in confs)
    todo = sum(c.todo for c in confs)
    lines = [f"cab plan: {total_jobs} job(s) in {len(confs)} configuration(s)"
             + (f", {todo} still to run" if todo != total_jobs else "")
             + f"; {slots} attempt(s) in flight (hydra.launcher.n_jobs)"]
    lo = hi = busy = 0.0
    unknown_cost, unknown_time = [], []
    for c in confs:
        k = c.check
        lines.append(f"  {c.label}: {c.jobs} job(s)" + (f", {c.todo} to run" if c.todo != c.jobs else ""))
        if k.provider or k.endpoint or k.key_env:
            key = ("no key needed" if k.key_env is None else
                   f"key {k.key_env} {'present' if k.key_present else 'MISSING'}")
            answers = {True: "answers", False: "DOES NOT ANSWER", None: "not asked" if not network else "not checked"}
            listed = {True: ", lists the model", False: ", does NOT list the model", None: ""}[k.model_listed]
            lines.append(f"    provider {k.provider or '?'}, endpoint {k.endpoint or '(the client default)'}: "
                         f"{answers[k.reachable]}{listed if k.reachable else ''}; {key}")
        elif c.harness == "direct" or not c.model_cfg.get("harness"):
            lines.append("    no model: nothing to check")
        e = estimate(c)
        if e.usd is not None:
            lo, hi = lo + e.usd[0] * c.todo, hi + e.usd[1] * c.todo
            lines.append(f"    cost {_usd(e.usd[0] * c.todo)}-{_usd(e.usd[1] * c.todo)} "
                         f"({_usd(e.usd[0])}-{_usd(e.usd[1])} per attempt: {e.usd_source})")
        else:
            unknown_cost.append(c.label)
            lines.append(f"    cost ? ({e.usd_source})")
        if e.wall_s is not None:
            busy += e.wall_s * c.todo
            lines.append(f"    time per attempt {e.wall_s / 60:.1f} min ({e.wall_source})")
        else:
            unknown_time.append(c.label)
        lines += [f"    PROBLEM: {p}" for p in k.problems]
        lines += [f"    note: {p}" for p in (k.capabilities or {}).get("problems") or [] if p not in k.problems]
    lines.append(f"cab plan: estimated cost {_usd(lo)}-{_usd(hi)}"
                 + (f" (without {', '.join(unknown_cost)}: unknown)" if unknown_cost else ""))
    lines.append(f"cab plan: ETA {_hm(busy / slots)} at {slots} attempt(s) in flight"
                 + (f" (without {', '.join(unknown_time)}: unknown)" if unknown_time else ""))
    return lines


def run_plan(config: Any, sweep: SweepJobs | None) -> tuple[list[str], list[str]]:
    """(the plan's lines, the problems' lines) of the command ``config`` was composed for (``sweep``:
    its jobs, None for a single run)."""
    settings = _plain(config.get("sweep")) or {}
    network = bool(settings.get("preflight_network", True))
    multirun = sweep is not None
    confs = configurations(config, sweep)
    problems = preflight(confs, network)
    folder = sweep.folder_problem if sweep is not None else None
    if folder is not None:
        problems.append(folder)
    attach_records(confs, record_dirs(config, multirun))
    slots = min(in_flight(config, multirun), max(1, sum(c.todo for c in confs)))
    return plan_lines(confs, slots, network) + ([f"  PROBLEM: {folder}"] if folder else []), problems
