"""``cab-report <dir> --against paper|<earlier sweep>|<leaderboard.jsonl>``: each configuration of a
sweep beside the same configuration elsewhere, with cab's uncertainty and tests.

The other side is a paper's published figures (what a plugin offers through the hook
``cab_published_figures``, e.g. the task suite's ``paper``: :func:`published`), an earlier cab run
(any folder ``cab-report`` reads) or an exported result (``cab-export leaderboard``'s rows:
a ``leaderboard.jsonl`` file, or a folder holding one and no attempt records; :func:`source_kind`,
:func:`exported_rows`). A configuration of the sweep meets:

* a paper's row whose ``cab`` names its model and harness (``opus5`` under ``reference`` meets
  "Claude Opus 5 (Reference)"), or the row a label gives it (``labels``: ``{configuration: paper
  name}``, ``cab-report --as CONFIG=NAME``; a configuration is named as the report names it, or by a
  prefix of exactly one; a paper row by its name or by ``model (harness)``);
* in an earlier run or an exported result, the configuration of the same name, else the one of the
  same model and harness, or the one a label names.

Against an exported result only success and coverage (the counts a row carries) are tested, per-task
success only where a row carries ``per_task`` (``{task: {"successes", "attempts"}}``), and the
contracts are compared through the row's ``contract_digest``/``contract_parts`` against this
sweep's configuration contract combined as the exporter combines it
(:func:`cab_core.analysis.summary.configuration_contract`).

For each pair, success (successes over attempts) and task coverage (tasks solved at least once
over tasks) get cab's Wilson 95 % interval, the other side's value, the exact two-sided binomial
test of the other side's rate under cab's counts, and Fisher's exact test of the two 2x2 counts
(both sides' counts are known for both measures). The verdict reads "consistent with the paper"
(or "with the earlier run") unless one of those tests rejects at ``alpha``: then "differs: ..."
naming each. The other measures (mean calls; median simulated, wall, provider-wait seconds and
cost; total cost; stopping conditions and claims; program share and errors; non-completed actions
and their causes; success among attempts that used each geometric or contact tool) stand side by
side with cab's interval where it has one: Wilson for shares, a percentile bootstrap over attempts
for means and medians; each says whether the other value lies inside it. Per-task success is
compared where both sides have it (an earlier run; the paper gives it only as a figure), with
Fisher's exact test per task.

A cab run is compared to a paper on what the paper fixed (its tasks, instructions, seeds, budgets
and tool interface): cab's simulators, planner and robot models are not the paper's, and the
comparison says so; where the records carry a comparison contract (``result.json`` ``contract``),
its digest is shown. Two cab runs whose contracts differ are compared all the same, marked
exploratory, with the parts that differ listed.

The tests are exact (:func:`binomial_test`, :func:`fisher_exact`: the two-sided p-value sums every
outcome no more likely than the one observed, as scipy's ``binomtest`` and ``fisher_exact`` do) and
use only the standard library; the bootstrap uses numpy. Formulas: docs/comparing.md.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cab_core.analysis import contract, summary
from cab_core.analysis.attempts import read_json
from cab_core.analysis.measures import ACTION_CAUSES, CLAIMS, ESTIMATION_TOOLS, STOPPING, wilson
from cab_core.errors import ConfigError, RecordError

AGAINST_VERSION = "cab-against/1"
FIGURES_FOLDER = "figures"  # beside the report's own figures (cab_core.analysis.report.FIGURES_FOLDER)
ALPHA = 0.05
_REL = 1 + 1e-7  # outcomes this close to the observed one's probability count as no more likely (scipy's rule)
PAPER_FIXED = ("tools", "task", "seeds", "budget")  # contract parts a paper fixes; cab's world is its own
PAPER_NOTE = ("compared on what the paper fixed (its tasks, instructions, seeds, budgets and tool interface); "
              "cab's simulators, planner and robot models are not the paper's")


# ---------------------------------------------------------------------------------------------
# statistics
# ---------------------------------------------------------------------------------------------
def binomial_test(k: int, n: int, p: float) -> float:
    """Exact two-sided p-value of ``k`` successes in ``n`` trials at rate ``p``: the probability of
    every outcome no more likely than ``k``."""
    if not (0 <= k <= n) or not (0.0 <= p <= 1.0):
        raise ValueError(f"need 0 <= k <= n and 0 <= p <= 1 (k={k}, n={n}, p={p})")
    pmf = [math.comb(n, i) * p ** i * (1 - p) ** (n - i) for i in range(n + 1)]
    return min(1.0, sum(x for x in pmf if x <= pmf[k] * _REL))


def fisher_exact(a: int, b: int, c: int, d: int) -> float:
    """Fisher's exact test of the 2x2 table ``[[a, b], [c, d]]`` (rows: the two sides; columns:
    successes, failures), two-sided: the probability, with the margins fixed, of every table no
    more likely than the one observed."""
    if min(a, b, c, d) < 0:
        raise ValueError(f"counts must be >= 0 (got {a}, {b}, {c}, {d})")
    row, col, n = a + b, a + c, a + b + c + d
    weights = {x: math.comb(row, x) * math.comb(n - row, col - x) for x in range(max(0, col - (n - row)), min(row, col) + 1)}
    observed = weights[a]
    more_extreme = sum(w for w in weights.values() if w * 10 ** 7 <= observed * (10 ** 7 + 1))
    return min(1.0, more_extreme / math.comb(n, col))


def bootstrap(xs: list[float], stat: Callable[..., Any], resamples: int = 10_000, confidence: float = 0.95,
              seed: int = 0) -> tuple[float, float] | None:
    """Percentile interval of ``stat`` (``np.median``, ``np.mean``) over ``xs`` resampled with
    replacement (seeded); None for fewer than two values."""
    if len(xs) < 2:
        return None
    rng = np.random.default_rng(seed)
    data = np.asarray(xs, dtype=float)
    values = stat(data[rng.integers(0, len(data), size=(resamples, len(data)))], axis=1)
    lo, hi = np.quantile(values, [(1 - confidence) / 2, (1 + confidence) / 2])
    return float(lo), float(hi)


# ---------------------------------------------------------------------------------------------
# the other side
# ---------------------------------------------------------------------------------------------
def published(name: str = "paper") -> dict:
    """The published figures a plugin offers under ``name`` (hook ``cab_published_figures``); a
    ConfigError listing the installed ones otherwise."""
    from cab_core.plugins import registry

    sources = registry("published_figures")
    if name not in sources:
        raise ConfigError(f"no published figures named {name!r} (installed: {', '.join(sorted(sources)) or 'none'}); "
                          "--against takes their name or an earlier sweep's folder")
    data = sources[name]()
    if not isinstance(data, Mapping) or not isinstance(data.get("configurations"), list):
        raise ConfigError(f"the published figures {name!r} have no 'configurations' list")
    return dict(data)


def _paper_side(row: Mapping, source: Mapping) -> dict:
    """A paper row as the measures this module compares: ``counts`` (k, n), ``values``. A count's
    denominator comes from the row (attempts: the stopping conditions' sum; tasks: the
    ``tasks_by_successes`` sum), else from the figures' ``source`` (``attempts_per_configuration``,
    ``tasks``); a count without one is left out."""
    cons, use = row.get("consistency") or {}, row.get("resource_use") or {}
    term, prog, act = row.get("termination") or {}, row.get("programs") or {}, row.get("actions") or {}
    n = int(sum((term.get("stopping") or {}).values()) or source.get("attempts_per_configuration") or 0)
    tasks = int(sum((cons.get("tasks_by_successes") or {}).values()) or source.get("tasks") or 0)
    counts: dict[str, tuple[int, int]] = {}
    values: dict[str, float | None] = {}
    if "success" in cons and n:
        counts["success"] = (int(cons["success"]), n)
    if "coverage" in cons and tasks:
        counts["coverage"] = (int(cons["coverage"]), tasks)
    for kind, group in (("stop", term.get("stopping") or {}), ("claim", term.get("claims") or {})):
        for k, v in group.items():
            if n:
                counts[f"{kind}_{k}"] = (int(v), n)
    if "program_errors" in prog:
        counts["program_errors"] = (int(prog["program_errors"]), int(prog["programs_returned"]))
    if "program_share_pct" in prog:
        values["program_share"] = float(prog["program_share_pct"]) / 100
    if "not_completed" in act:
        counts["not_completed"] = (int(act["not_completed"]), int(act["actions"]))
        for cause, v in (act.get("by_cause") or {}).items():
            counts[f"cause_{cause}"] = (int(v), int(act["not_completed"]))
    for tool, t in (row.get("tool_use") or {}).items():
        counts[f"tool_{tool}"] = (int(t["successes"]), int(t["attempts"]))
    for key in ("calls_mean", "sim_seconds_median", "wall_seconds_median", "wait_seconds_median", "cost_total_usd",
                "cost_median_usd"):
        if key in use:
            values[key] = None if use[key] is None else float(use[key])
    return {"counts": counts, "values": values, "intervals": {}, "per_task": None}


def source_kind(source: str, export_file: str = "leaderboard.jsonl") -> str:
    """What ``--against SOURCE`` names: ``"export"`` (a file, taken as leaderboard rows, or a folder
    holding ``export_file`` (:data:`cab_core.analysis.leaderboard.FILE`, which the caller passes:
    this module sits below the exporter in the import graph) and no ``result.json`` below it),
    ``"run"`` (any other folder) or ``"paper"`` (published figures by name)."""
    path = Path(source)
    if path.is_file():
        return "export"
    if path.is_dir():
        if (path / export_file).is_file() and next(path.rglob("result.json"), None) is None:
            return "export"
        return "run"
    return "paper"


def exported_rows(rows: list[dict], path: Path) -> list[dict]:
    """Leaderboard rows as :func:`cab_core.analysis.leaderboard.read` read them from ``path``, checked
    for what this comparison needs besides: at least one row, and a ``per_task`` (where a row has
    one) of counts that fit; a RecordError line otherwise."""
    if not rows:
        raise RecordError(f"{path}: no leaderboard row to compare with")
    for i, row in enumerate(rows, 1):
        pt = row.get("per_task")
        if pt is not None and not (isinstance(pt, Mapping) and all(
                isinstance(v, Mapping) and isinstance(v.get("successes"), int) and isinstance(v.get("attempts"), int)
                and 0 <= v["successes"] <= v["attempts"] for v in pt.values())):
            raise RecordError(f"{path}: row {i} ({row['config']}): per_task should map each task to "
                              "{'successes': k, 'attempts': n} with 0 <= k <= n")
    return rows


def _export_side(row: Mapping) -> dict:
    """An exported leaderboard row as the measures this module compares: success and coverage, and
    per-task success where the row carries it."""
    pt = row.get("per_task")
    return {"counts": {"success": (int(row["successes"]), int(row["attempts"])),
                       "coverage": (int(row["tasks_covered"]), int(row["tasks"]))},
            "values": {}, "intervals": {},
            "per_task": {t: (int(v["successes"]), int(v["attempts"])) for t, v in pt.items()} if pt else None}


def _cab_side(c: Mapping, rows: list[Mapping], matrix: Mapping, boot: Mapping) -> dict:
    """A configuration of a cab report as the same measures, with cab's intervals for the values."""
    n = int(c["attempts"])
    counts: dict[str, tuple[int, int]] = {"success": (int(c["successes"]), n), "coverage": (int(c["coverage"]), int(c["tasks"]))}
    for s in STOPPING:
        counts[f"stop_{s}"] = (int(c["stopping"][s]), n)
    for s in CLAIMS:
        counts[f"claim_{s}"] = (int(c["claims"][s]), n)
    counts["program_errors"] = (int(c["program_errors"]), int(c["programs_returned"]))
    counts["program_share"] = (int(c["program_calls"]), int(c["charged_calls"]))
    counts["not_completed"] = (int(c["not_completed_total"]), int(c["actions"]))
    for cause in ACTION_CAUSES:
        if cause != "other" or c["not_completed"].get(cause):
            counts[f"cause_{cause}"] = (int(c["not_completed"].get(cause, 0)), int(c["not_completed_total"]))
    for tool in ESTIMATION_TOOLS:
        t = (c.get("tool_use") or {}).get(tool)
        counts[f"tool_{tool}"] = (int(t["successes"]), int(t["attempts"])) if t else (0, 0)
    per_attempt: dict[str, tuple[str, Callable[..., Any]]] = {"calls_mean": ("charged_calls", np.mean), "sim_seconds_median": ("sim_seconds", np.median),
                   "wall_seconds_median": ("wall_seconds", np.median), "wait_seconds_median": ("wait_seconds", np.median),
                   "cost_median_usd": ("cost_usd", np.median)}
    values: dict[str, float | None] = {"cost_total_usd": c.get("cost_total")}
    intervals: dict[str, tuple[float, float] | None] = {}
    for key, (field, stat) in per_attempt.items():
        xs = [float(m[field]) for m in rows if m.get(field) is not None]
        values[key] = float(stat(np.asarray(xs))) if xs else None
        intervals[key] = bootstrap(xs, stat, **boot) if xs else None
    per_task = {t: tuple(cells[c["config"]]) for t, cells in matrix.items() if c["config"] in cells}
    return {"counts": counts, "values": values, "intervals": intervals, "per_task": per_task}


# ---------------------------------------------------------------------------------------------
# measures and their labels
# ---------------------------------------------------------------------------------------------
TESTED = (("success", "success"), ("coverage", "task coverage"))
SHARES = ([(f"stop_{s}", f"stopping: {s}") for s in STOPPING] + [(f"claim_{s}", f"claim: {s}") for s in CLAIMS]
          + [("program_share", "program share of charged calls"), ("program_errors", "program errors / returned"),
             ("not_completed", "non-completed actions / actions")]
          + [(f"cause_{c}", f"non-completed by {c}") for c in ACTION_CAUSES]
          + [(f"tool_{t}", f"success when {t} used") for t in ESTIMATION_TOOLS])
VALUES = (("calls_mean", "calls (mean)"), ("sim_seconds_median", "simulated s (median)"),
          ("wall_seconds_median", "wall s (median)"), ("wait_seconds_median", "provider wait s (median)"),
          ("cost_median_usd", "cost USD (median)"), ("cost_total_usd", "cost USD (total)"))


def _rate(count: tuple[int, int] | None) -> float | None:
    return None if not count or not count[1] else count[0] / count[1]


def _inside(v: float | None, ci: tuple[float, float] | None) -> bool | None:
    return None if v is None or ci is None else bool(ci[0] - 1e-12 <= v <= ci[1] + 1e-12)


def compare_sides(cab: Mapping, other: Mapping, other_is_cab: bool, alpha: float = ALPHA,
                  whom: str | None = None) -> dict:
    """The comparison of one configuration (``cab``) with its counterpart (``other``), both as
    :func:`_cab_side`/:func:`_paper_side` give them: the tested measures, the others side by side,
    per-task success where both have it, and the verdict."""
    tested, differs = [], []
    for key, label in TESTED:
        a, b = cab["counts"].get(key), other["counts"].get(key)
        if not a or not b or not a[1] or not b[1]:
            continue
        row = {"measure": key, "label": label, "cab": list(a), "cab_rate": a[0] / a[1], "wilson95": list(wilson(*a)),
               "other": list(b), "other_rate": b[0] / b[1],
               "binomial_p": binomial_test(a[0], a[1], b[0] / b[1]),
               "fisher_p": fisher_exact(a[0], a[1] - a[0], b[0], b[1] - b[0])}
        row["other_inside"] = _inside(row["other_rate"], tuple(row["wilson95"]))
        if other_is_cab:
            row["other_wilson95"] = list(wilson(*b))
        tested.append(row)
        failed = [f"{name} p={p:.3g}" for name, p in (("binomial", row["binomial_p"]), ("Fisher", row["fisher_p"]))
                  if p < alpha]
        if failed:
            differs.append(f"{label} {a[0]}/{a[1]} vs {b[0]}/{b[1]} ({', '.join(failed)})")
    side: list[dict] = []
    for key, label in SHARES:
        a, b = cab["counts"].get(key), other["counts"].get(key)
        ov = _rate(b) if b else other["values"].get(key)
        if ov is None or not a or not a[1]:
            continue
        ci = wilson(*a)
        row = {"measure": key, "label": label, "cab": _rate(a), "cab_count": list(a), "interval": list(ci),
               "other": ov, "other_count": list(b) if b else None, "other_inside": _inside(ov, ci)}
        if b and b[1]:
            row["fisher_p"] = fisher_exact(a[0], a[1] - a[0], b[0], b[1] - b[0])
        side.append(row)
    for key, label in VALUES:
        cv, ov = cab["values"].get(key), other["values"].get(key)
        if cv is None or ov is None:
            continue
        ci = cab["intervals"].get(key)
        side.append({"measure": key, "label": label, "cab": cv, "interval": list(ci) if ci else None, "other": ov,
                     "other_inside": _inside(ov, ci)})
    per_task = []
    if cab.get("per_task") and other.get("per_task"):
        for task in sorted(set(cab["per_task"]) & set(other["per_task"])):
            (ka, na), (kb, nb) = cab["per_task"][task], other["per_task"][task]
            per_task.append({"task": task, "cab": [ka, na], "other": [kb, nb],
                             "fisher_p": fisher_exact(ka, na - ka, kb, nb - kb)})
    whom = whom or ("the earlier run" if other_is_cab else "the paper")
    return {"tested": tested, "measures": side, "per_task": per_task,
            "outside": [r["label"] for r in side if r["other_inside"] is False],
            "verdict": ("differs: " + "; ".join(differs)) if differs else
                       (f"consistent with {whom}" if tested else f"not comparable: no shared counts with {whom}")}


# ---------------------------------------------------------------------------------------------
# matching configurations
# ---------------------------------------------------------------------------------------------
def _config_facts(root: Path, r: Mapping) -> dict[str, dict]:
    """Per configuration of report ``r`` (of ``root``): its model, harness and simulator, and the
    comparison contracts its records carry (``result.json`` ``contract``,
    :func:`cab_core.analysis.contract.of_result`), by attempt instance ``(task, seed, attempt)``."""
    out: dict[str, dict] = {}
    for m in r["attempt_rows"]:
        where = f"{m['rel']}/result.json"
        res = read_json(Path(root) / m["rel"] / "result.json")
        f = out.setdefault(m["config"], {"model": res.get("model"), "harness": res.get("harness"),
                                         "sim": res.get("sim"), "contracts": {}, "results": []})
        f["results"].append(res)
        c = contract.of_result(res, where)
        if c is not None:
            f["contracts"][(m["task"], m["seed"], m["attempt"])] = c
    return out


def _named(names: list[str], name: str, what: str) -> str:
    if name in names:
        return name
    hits = [n for n in names if n.startswith(name)]
    if len(hits) == 1:
        return hits[0]
    raise RecordError(f"{'ambiguous' if hits else 'no'} {what} {name!r}; choices: {'; '.join(hits or names)}")


def parse_labels(items: list[str] | None) -> dict[str, str]:
    """``--as CONFIG=NAME`` items as ``{CONFIG: NAME}``; a ConfigError for an item without ``=``."""
    out = {}
    for item in items or []:
        config, sep, name = item.partition("=")
        if not sep or not config.strip() or not name.strip():
            raise ConfigError(f"--as takes CONFIG=NAME (a configuration of the sweep = the other side's), got {item!r}")
        out[config.strip()] = name.strip()
    return out


def differing_parts(a: Mapping[tuple, Mapping], b: Mapping[tuple, Mapping]) -> list[str]:
    """The contract parts two configurations' records differ in (each side: ``{(task, seed,
    attempt): contract}``): on each attempt instance both ran, the parts its two contracts differ in
    (:func:`cab_core.analysis.contract.differing`); and any part that does not follow the instance
    (tools, simulator, planner, harness...) whose digests are not the same on both sides. [] when
    either side has no contract (records written before cab kept one)."""
    if not a or not b:
        return []
    names: set[str] = set()
    for key in set(a) & set(b):
        names |= set(contract.differing(a[key], b[key]))
    per_instance = {"task", "seeds", "budget"}
    for part in {p for c in [*a.values(), *b.values()] for p in c["parts"]} - per_instance:
        if {c["parts"].get(part) for c in a.values()} != {c["parts"].get(part) for c in b.values()}:
            names.add(part)
    order = list(contract.PARTS)
    return sorted(names, key=lambda p: (order.index(p) if p in order else len(order), p))


# ---------------------------------------------------------------------------------------------
# the comparison
# ---------------------------------------------------------------------------------------------
def against(root: Path, r: Mapping, source: str, labels: Mapping[str, str] | None = None, alpha: float = ALPHA,
            bootstrap_cfg: Mapping | None = None, earlier: Mapping | None = None,
            exported: list[dict] | None = None) -> dict:
    """Compare report ``r`` (of the sweep ``root``, :func:`cab_core.analysis.report.build`) with
    ``source``: the name of published figures (``paper``), an earlier run's folder whose report
    (the same function's) is ``earlier``, or exported leaderboard rows ``exported``
    (:func:`exported_rows` of ``source``)."""
    boot = {"resamples": 10_000, "confidence": 0.95, "seed": 0, **(bootstrap_cfg or {})}
    labels = dict(labels or {})
    facts = _config_facts(root, r)
    names = [c["config"] for c in r["configs"]]
    labels = {_named(names, k, "configuration of the sweep"): v for k, v in labels.items()}
    rows_of = {c: [m for m in r["attempt_rows"] if m["config"] == c] for c in names}
    cab_sides = {c["config"]: _cab_side(c, rows_of[c["config"]], r["matrix"], boot) for c in r["configs"]}
    other_dir = Path(source)
    out: dict[str, Any] = {"against_version": AGAINST_VERSION, "alpha": alpha, "rows": [], "unmatched": []}
    if exported is not None:
        out.update(kind="export", source=str(other_dir), note=None)
        onames = [row["config"] for row in exported]
        by_model = {f"{row['model']} ({row['harness']})": row for row in exported}
        for c in names:
            orow: dict | None
            if c in labels:
                want = labels[c]
                orow = by_model.get(want) or next(x for x in exported if x["config"] == _named(
                    onames, want, f"configuration of the exported result {other_dir}"))
            elif c in onames:
                orow = next(x for x in exported if x["config"] == c)
            else:
                alike = [x for x in exported if (x["model"], x["harness"]) == (facts[c]["model"], facts[c]["harness"])]
                orow = alike[0] if len(alike) == 1 else None
            if orow is None:
                out["unmatched"].append(c)
                continue
            row = {"config": c, "other": orow["config"],
                   **compare_sides(cab_sides[c], _export_side(orow), True, alpha, whom="the exported run")}
            mine = summary.configuration_contract(facts[c]["results"])
            theirs = ({"digest": orow["contract_digest"], "parts": dict(orow.get("contract_parts") or {})}
                      if orow.get("contract_digest") else None)
            parts = contract.differing(mine, theirs) if mine and theirs and mine["digest"] != theirs["digest"] else []
            row["contract"] = {"cab": mine["digest"] if mine else None, "other": theirs["digest"] if theirs else None,
                               "differs_in": parts, "exploratory": bool(parts),
                               "per_task_in_row": orow.get("per_task") is not None}
            out["rows"].append(row)
        return out
    if earlier is not None:
        other = earlier
        if not other["attempts"]:
            raise RecordError(f"no finished attempt under {other_dir} to compare with")
        ofacts = _config_facts(other_dir, other)
        onames = [c["config"] for c in other["configs"]]
        out.update(kind="run", source=str(other_dir), note=None)
        for c in names:
            match = None
            if c in labels:
                match = _named(onames, labels[c], "configuration of the earlier run")
            elif c in onames:
                match = c
            else:
                same = [o for o in onames if (ofacts[o]["model"], ofacts[o]["harness"]) ==
                        (facts[c]["model"], facts[c]["harness"])]
                match = same[0] if len(same) == 1 else None
            if match is None:
                out["unmatched"].append(c)
                continue
            oc = next(x for x in other["configs"] if x["config"] == match)
            oside = _cab_side(oc, [m for m in other["attempt_rows"] if m["config"] == match], other["matrix"], boot)
            row = {"config": c, "other": match, **compare_sides(cab_sides[c], oside, True, alpha)}
            parts = differing_parts(facts[c]["contracts"], ofacts[match]["contracts"])
            row["contract"] = {"cab": len(facts[c]["contracts"]), "other": len(ofacts[match]["contracts"]),
                               "differs_in": parts, "exploratory": bool(parts)}
            out["rows"].append(row)
        return out
    figures = published(source)
    papers = figures["configurations"]
    by_name = {p["name"]: p for p in papers}
    by_cab = {f"{p['cab']['model']} ({p['cab']['harness']})": p for p in papers if isinstance(p.get("cab"), Mapping)}
    out.update(kind="paper", source=source, note=PAPER_NOTE, tables=figures.get("tables") or {},
               paper_source=figures.get("source") or {})
    for c in names:
        if c in labels:
            want = labels[c]
            paper = by_name.get(want) or by_cab.get(want)
            if paper is None:
                raise ConfigError(f"--as {c}={want}: no such configuration in the published figures {source!r}; "
                                  f"choices: {'; '.join(by_name)}")
        else:
            paper = by_cab.get(f"{facts[c]['model']} ({facts[c]['harness']})")
        if paper is None:
            out["unmatched"].append(c)
            continue
        row = {"config": c, "other": paper["name"], **compare_sides(cab_sides[c], _paper_side(paper, figures.get("source") or {}), False,
                                                                  alpha)}
        held = len(facts[c]["contracts"])
        row["contract"] = {"cab": held, "on_what_the_paper_fixed": bool(held), "paper_fixed": list(PAPER_FIXED)}
        out["rows"].append(row)
    return out


# ---------------------------------------------------------------------------------------------
# renderings
# ---------------------------------------------------------------------------------------------
def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f}%"


def _p(x: float) -> str:
    return f"{x:.3g}"


def _val(key: str, x: float | None) -> str:
    if x is None:
        return "–"
    return _pct(x) if any(key == k for k, _ in SHARES) else f"{x:,.2f}"


def _whom(a: Mapping) -> str:
    return {"paper": "paper", "run": "earlier run", "export": "exported run"}[a["kind"]]


def tables(a: Mapping) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of the comparison: the side-by-side table with the tests and verdicts,
    then per configuration its other measures and (an earlier run) its per-task success."""
    whom = _whom(a)
    head = ["configuration", whom, "measure", "cab", "cab 95% interval", whom, "binomial p", "Fisher p", "verdict"]
    rows = []
    for row in a["rows"]:
        for i, t in enumerate(row["tested"]):
            rows.append([row["config"] if i == 0 else "", row["other"] if i == 0 else "", t["label"],
                         f"{t['cab'][0]}/{t['cab'][1]} ({_pct(t['cab_rate'])})",
                         f"{_pct(t['wilson95'][0])}–{_pct(t['wilson95'][1])}",
                         f"{t['other'][0]}/{t['other'][1]} ({_pct(t['other_rate'])})",
                         _p(t["binomial_p"]), _p(t["fisher_p"]), row["verdict"] if i == 0 else ""])
    out = [(f"Against the {whom}: success and task coverage", head, rows)]
    for row in a["rows"]:
        if not row["measures"] and a["kind"] == "export":
            if row["per_task"]:
                out.append((f"{row['config']} beside {row['other']}: per-task success", ["task", "cab", whom, "Fisher p"],
                            [[t["task"], f"{t['cab'][0]}/{t['cab'][1]}", f"{t['other'][0]}/{t['other'][1]}",
                              _p(t["fisher_p"])] for t in row["per_task"]]))
            continue
        body = [[m["label"], _val(m["measure"], m["cab"]),
                 "–" if not m.get("interval") else f"{_val(m['measure'], m['interval'][0])}–{_val(m['measure'], m['interval'][1])}",
                 _val(m["measure"], m["other"]), {True: "yes", False: "no", None: "–"}[m["other_inside"]]]
                for m in row["measures"]]
        out.append((f"{row['config']} beside {row['other']}: other measures",
                    ["measure", "cab", "cab 95% interval", whom, "inside"], body))
        if row["per_task"]:
            out.append((f"{row['config']} beside {row['other']}: per-task success",
                        ["task", "cab", whom, "Fisher p"],
                        [[t["task"], f"{t['cab'][0]}/{t['cab'][1]}", f"{t['other'][0]}/{t['other'][1]}", _p(t["fisher_p"])]
                         for t in row["per_task"]]))
    return out


def notes(a: Mapping) -> list[str]:
    """The lines printed under the tables: what the comparison rests on, and what matched nothing."""
    out = []
    if a["kind"] == "paper":
        out.append(a["note"] + ".")
        for row in a["rows"]:
            if row["contract"]["on_what_the_paper_fixed"]:
                out.append(f"{row['config']}: {row['contract']['cab']} attempt(s) hold a comparison contract; the "
                           f"paper fixes only its parts {', '.join(PAPER_FIXED)}: compared on what the paper fixed.")
        out.append("The paper gives per-task success only as a figure: per-task success is not compared.")
    elif a["kind"] == "export":
        for row in a["rows"]:
            c = row["contract"]
            if c["exploratory"]:
                out.append(f"{row['config']}: EXPLORATORY, its contract and the exported row's differ in "
                           f"{', '.join(c['differs_in'])}.")
            elif c["other"] is None:
                out.append(f"{row['config']}: not checked for comparability: the exported row {row['other']} carries "
                           "no comparison contract.")
            elif c["cab"] is None:
                out.append(f"{row['config']}: not checked for comparability: this sweep's records hold no comparison "
                           "contract (written before cab kept one).")
            else:
                out.append(f"{row['config']}: its comparison contract and the exported row's agree ({c['cab'][:12]}).")
            if not c["per_task_in_row"]:
                out.append(f"{row['config']}: the exported row carries no per-task success: per-task success is not "
                           "compared; only success and task coverage are.")
    else:
        for row in a["rows"]:
            if row["contract"]["exploratory"]:
                out.append(f"{row['config']}: EXPLORATORY, the two runs' contracts differ in "
                           f"{', '.join(row['contract']['differs_in'])}.")
            elif row["contract"]["cab"] and row["contract"]["other"]:
                out.append(f"{row['config']}: the two runs' comparison contracts agree ({row['contract']['cab']} and "
                           f"{row['contract']['other']} attempts).")
            else:
                out.append(f"{row['config']}: not checked for comparability: records without a comparison contract "
                           "(written before cab kept one).")
    if a["unmatched"]:
        out.append("Not compared (no counterpart; name one with --as CONFIG=NAME): " + "; ".join(a["unmatched"]) + ".")
    return out


def forest(a: Mapping):
    """The forest plot: per configuration, success and coverage as cab's rate with its Wilson
    interval (dot and whisker) and the other side's rate (a diamond)."""
    from cab_core.analysis import figures as fg

    name = "against_forest"
    title = f"Success and coverage against the {_whom(a)}"
    items = [(f"{row['config']}: {t['label']}", t) for row in a["rows"] for t in row["tested"]]
    with fg.style(name):
        fig = fg.CabFigure(name, title, 1.2 + 0.32 * max(len(items), 1))
        ax = fig.add_subplot()
        ax.set_title(title, loc="left")
        for i, (label, t) in enumerate(items):
            lo, hi = t["wilson95"]
            (dot,) = ax.plot([t["cab_rate"]], [i], "o", color=fg.PALETTE[0])
            ax.errorbar(t["cab_rate"], i, xerr=[[max(0.0, t["cab_rate"] - lo)], [max(0.0, hi - t["cab_rate"])]], fmt="none",
                        ecolor=fg.PALETTE[0], capsize=3, lw=1)
            fig.cab_titles[f"{name}-point-{i}"] = (f"{label}: cab {fg.pct(t['cab_rate'])} ({fg.pct(lo)}–{fg.pct(hi)}), "
                                                   f"other {fg.pct(t['other_rate'])}")
            dot.set_gid(f"{name}-point-{i}")
            ax.plot([t["other_rate"]], [i], "D", color=fg.PALETTE[2], markersize=5)
        ax.set_yticks(range(len(items)), [x[0] for x in items])
        ax.set_ylim(max(len(items), 1) - 0.5, -0.5)
        from matplotlib.ticker import PercentFormatter

        ax.xaxis.set_major_formatter(PercentFormatter(1.0, decimals=0))
        ax.set_xlim(-0.02, 1.02)
        from matplotlib.lines import Line2D

        fig.legend([Line2D([], [], marker="o", color=fg.PALETTE[0], ls="-"),
                    Line2D([], [], marker="D", color=fg.PALETTE[2], ls="")],
                   ["cab (Wilson 95%)", _whom(a)], loc="outside lower left",
                   ncols=2)
    return fig


def md_table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table (as the report writes its own)."""
    cell = lambda s: str(s).replace("|", "\\|")  # noqa: E731
    return "\n".join(["| " + " | ".join(map(cell, header)) + " |", "|" + "---|" * len(header),
                      *("| " + " | ".join(map(cell, row)) + " |" for row in rows)])


def markdown(a: Mapping, figure: str | None) -> str:
    parts = [f"# Against {'the paper' if a['kind'] == 'paper' else a['source']}", ""]
    for title, header, rows in tables(a):
        parts += [f"## {title}", "", md_table(header, rows), ""]
    parts += [f"- {n}" for n in notes(a)]
    if figure:
        parts += ["", f"![forest plot]({figure})"]
    return "\n".join(parts) + "\n"


def write(a: Mapping, out: Path, figure_files: bool = True) -> list[Path]:
    """``against.json``, ``against.md`` and (``figure_files``) ``figures/against_forest.{pdf,svg,png}``
    in ``out``; the paths written."""
    from cab_core.analysis import figures as fg

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    figure = None
    if figure_files and a["rows"]:
        written += fg.write_files([forest(a)], out / FIGURES_FOLDER)
        figure = f"{FIGURES_FOLDER}/against_forest.svg"
    (out / "against.json").write_text(json.dumps(a, indent=1))
    (out / "against.md").write_text(markdown(a, figure))
    return [out / "against.json", out / "against.md", *written]
