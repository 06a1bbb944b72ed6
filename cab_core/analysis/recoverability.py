"""Recoverability of failures (``cab-report --recoverability``): could the task still have been
completed from where a failed attempt stood, and does the attempt's own model complete it when it
tries again from there?

**Fork points.** Each failed attempt of the report is forked (:mod:`cab_core.attempt.fork`) at two
of its states:

* its **failure point**: the state after which its first failed stage should have followed. The
  task's stages are its subgoals, in the task's order. The first failed stage is the first subgoal
  the attempt never attained (``result.json``: ``checkpoints.subgoals[i].attained`` false); the
  failure point is the charged-call count at which every subgoal before it had been attained, the
  largest ``checkpoints.subgoals[j].first.calls`` over those subgoals j (0 when the first failed
  stage is the first subgoal: the scene's start). An attempt that attained every subgoal at some
  time and failed all the same (a subgoal lost again, a final condition unmet) failed after the last
  of them was first attained: its failure point is the largest ``first.calls`` of all, its first
  failed stage its failure-stage label (:mod:`cab_core.analysis.failure`). An attempt without a
  usable checkpoint record has no failure point (only its last call is forked).
* its **last call**: its charged-call count, the state it ended in (``done`` is not charged and is
  not made again).

When both are the same call, one fork serves both.

**Forks.** Each point is forked once played by the task's stage-aware reference solution (model
``oracle``, deterministic: once is enough) and, with ``repeats`` N > 0, N times played by the
attempt's own model as its records hold it (its model and harness configuration: a model-free
agent such as ``scripted`` with its script, a reference-harness model with its settings; a provider
model needs its key as any attempt does). A fork's outcome is
:func:`cab_core.attempt.records.recovery.recovery`'s (recovered; not recoverable, with the kind and reason the
reference solution gave, or ``budget``; unexplained: it failed and gave no reason), or ``error``
when no fork could be made (the records cannot be forked, the re-executed prefix diverged, every
try failed for infrastructure reasons).

**Figures**, per configuration (the report's grouping): the failures; the share of them the
reference solution recovers from the failure point and from the last call, over the failures whose
fork has an outcome (failures without a failure point and forks that could not be made are counted
apart), with its Wilson 95 % score interval; with ``repeats``, the share of the model's retries that
succeed, over its retries with an outcome (each retry counts once); and, for every reference-solution
fork that did not recover, **where recovery fails**: the first subgoal the fork never attained (its
own checkpoints, the re-executed prefix included), else the fork's failure-stage label, with the
not-recoverable reasons by kind.

**Where the forks are**: ``<folder>/<attempt, relative to the report's directory>/at-<K>/oracle`` and
``.../model-<i>``, ``<folder>`` by default ``recoverability/`` in the report's output folder (a
folder of that name is never scanned as part of the sweep: :data:`cab_core.analysis.attempts.FORKS_FOLDER`).
A fork whose ``result.json`` is there (and is no infrastructure failure) is not run again: a report
that was interrupted, or is run again with more repeats, makes only the forks that are missing.

Pure functions over records (:func:`fork_points`, :func:`fork_fails_at`, :func:`summarize`,
:func:`tables`, :func:`figure`) and :func:`run`, which makes the forks (through
:func:`cab_core.sweep.supervisor.run_configs`, each in its own supervised process).
"""
from __future__ import annotations

import os
import shutil
from collections import Counter
from pathlib import Path

from cab_core.analysis.attempts import Attempt, read_json
from cab_core.analysis.failure import LABELS, Classifier
from cab_core.analysis.measures import wilson
from cab_core.attempt.records.recovery import recovery
from cab_core.errors import CabError
from cab_core.kits.jsonfiles import read_json_object
from cab_core.sweep.attempt_state import is_infrastructure_failure

POINTS = ("failure_point", "last_call")
POINT_LABELS = {"failure_point": "failure point", "last_call": "last call"}
OUTCOMES = ("recovered", "not_recoverable", "unexplained")  # a fork with an outcome; else "error"
ORACLE = "oracle"


# ---------------------------------------------------------------------------------------------
# pure functions over records
# ---------------------------------------------------------------------------------------------
def stage_name(subgoal: dict) -> str:
    """A subgoal as the tables name a stage: ``subgoal 2: <its text>``."""
    return f"subgoal {subgoal.get('index')}: {subgoal.get('text') or ''}".rstrip(": ")


def _subgoals(result: dict) -> list[dict] | None:
    ck = result.get("checkpoints")
    if not isinstance(ck, dict) or "error" in ck or not ck.get("subgoals"):
        return None
    return list(ck["subgoals"])


def _first_calls(s: dict) -> int:
    k = (s.get("first") or {}).get("calls")
    return int(k) if isinstance(k, int) and not isinstance(k, bool) else 0


def fork_points(result: dict, failure_stage: str | None = None) -> dict:
    """The fork points of a failed attempt from its ``result.json``: ``{"failure_point": K or None,
    "last_call": K, "failed_stage": the first failed stage, in words, or None}`` (see the module's
    docstring). ``failure_stage``: the attempt's failure stage (:class:`cab_core.analysis.failure.Classifier`),
    named where every subgoal was attained."""
    last = int((result.get("budget") or {}).get("tool_calls_used") or 0)
    label = LABELS.get(failure_stage) if failure_stage else None
    subs = _subgoals(result)
    if subs is None:
        return {"failure_point": None, "last_call": last, "failed_stage": label}
    j = next((i for i, s in enumerate(subs) if not s.get("attained")), None)
    before = subs if j is None else subs[:j]
    k = max((_first_calls(s) for s in before), default=0)
    stage = stage_name(subs[j]) if j is not None else (label or "every subgoal attained")
    return {"failure_point": min(k, last), "last_call": last, "failed_stage": stage}


def fork_fails_at(result: dict, failure_stage: str | None = None) -> str:
    """Where a fork that did not recover fails: the first subgoal its own checkpoints never
    attained, else its failure-stage label (``Unresolved`` when there is none)."""
    subs = _subgoals(result) or []
    j = next((s for s in subs if not s.get("attained")), None)
    if j is not None:
        return stage_name(j)
    return LABELS.get(failure_stage or "unresolved", LABELS["unresolved"])


def share(recovered: int, n: int) -> dict:
    """``recovered`` of ``n``, its share and Wilson 95 % interval (None for both when n is 0)."""
    return {"recovered": recovered, "n": n, "share": recovered / n if n else None,
            "wilson95": list(wilson(recovered, n)) if n else None}


def point_summary(forks: list[dict | None]) -> dict:
    """The reference solution's forks at one point, one per failure (None: the failure has no such
    point): the share recovered, the errors, the failures without the point, the not-recoverable
    reasons by kind, and where the forks that did not recover fail (stage -> forks, kinds)."""
    made = [f for f in forks if f is not None and f["outcome"] in OUTCOMES]
    kinds = Counter(f["kind"] or "unknown" for f in made if f["outcome"] == "not_recoverable")
    fails: dict[str, dict] = {}
    for f in made:
        if f["outcome"] == "recovered":
            continue
        cell = fails.setdefault(f.get("fails_at") or LABELS["unresolved"], {"forks": 0, "kinds": {}})
        cell["forks"] += 1
        k = (f["kind"] or "unknown") if f["outcome"] == "not_recoverable" else "unexplained"
        cell["kinds"][k] = cell["kinds"].get(k, 0) + 1
    return {**share(sum(f["outcome"] == "recovered" for f in made), len(made)),
            "errors": sum(1 for f in forks if f is not None and f["outcome"] not in OUTCOMES),
            "unavailable": sum(1 for f in forks if f is None),
            "not_recoverable": dict(sorted(kinds.items())),
            "unexplained": sum(f["outcome"] == "unexplained" for f in made),
            "fails_at": dict(sorted(fails.items(), key=lambda kv: (-kv[1]["forks"], kv[0])))}


def model_summary(forks: list[dict]) -> dict:
    """The model's retries at one point (every retry of every failure): the share that succeeded."""
    made = [f for f in forks if f["outcome"] in OUTCOMES]
    return {**share(sum(f["outcome"] == "recovered" for f in made), len(made)),
            "errors": len(forks) - len(made)}


def summarize(cases: list[dict], configs: list[str], repeats: int = 0) -> list[dict]:
    """Per configuration, in the order given (the report's): its failures and, at each point, the
    reference solution's figures (:func:`point_summary`) and, with ``repeats``, the model's
    (:func:`model_summary`). ``cases``: one per failed attempt, as :func:`run` makes them."""
    out = []
    for c in configs:
        mine = [x for x in cases if x["config"] == c]
        row = {"config": c, "failures": len(mine),
               "oracle": {p: point_summary([x["oracle"].get(p) for x in mine]) for p in POINTS}, "model": None}
        if repeats:
            row["model"] = {p: model_summary([f for x in mine for f in (x.get("model") or {}).get(p) or []])
                            for p in POINTS}
        out.append(row)
    return out


# ---------------------------------------------------------------------------------------------
# the tables and the figure
# ---------------------------------------------------------------------------------------------
def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f}%"


def _frac(s: dict) -> str:
    return "–" if not s["n"] else f"{s['recovered']}/{s['n']} ({_pct(s['share'])})"


def _ci(s: dict) -> str:
    return "–" if not s["wilson95"] else f"{_pct(s['wilson95'][0])}–{_pct(s['wilson95'][1])}"


def _kinds(p: dict) -> str:
    parts = [f"{k} {n}" for k, n in p["not_recoverable"].items()]
    if p["unexplained"]:
        parts.append(f"unexplained {p['unexplained']}")
    return ", ".join(parts) or "–"


def _not_forked(c: dict) -> str:
    fp, last = c["oracle"]["failure_point"], c["oracle"]["last_call"]
    parts = []
    if fp["unavailable"]:
        parts.append(f"{fp['unavailable']} without a failure point")
    made = [f"{p['errors']} from the {POINT_LABELS[k]}" for k, p in (("failure_point", fp), ("last_call", last))
            if p["errors"]]
    if made:
        parts.append("fork not made: " + ", ".join(made))
    return "; ".join(parts) or "–"


def tables(rec: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows): the recoverability of each configuration's failures, and where the
    reference solution's recovery fails."""
    with_model = bool(rec.get("repeats"))
    header = ["Configuration", "Failures", "Oracle from failure point", "Wilson 95%", "Oracle from last call",
              "Wilson 95%", *(["Model retry from failure point", "Model retry from last call"] if with_model else []),
              "Not recoverable from failure point", "Not recoverable from last call", "Not forked"]
    rows = []
    for c in rec["configs"]:
        o = c["oracle"]
        model = [_frac(c["model"][p]) for p in POINTS] if with_model and c["model"] else (["–", "–"] if with_model else [])
        rows.append([c["config"], str(c["failures"]), _frac(o["failure_point"]), _ci(o["failure_point"]),
                     _frac(o["last_call"]), _ci(o["last_call"]), *model, _kinds(o["failure_point"]),
                     _kinds(o["last_call"]), _not_forked(c)])
    n = rec.get("repeats") or 0
    title = ("Recoverability of failures (each failed attempt forked at its failure point and its last call; "
             "the stage-aware reference solution finishes each fork"
             + (f"; the attempt's own model retries {n} time(s) from each" if n else "") + ")")
    where = []
    for c in rec["configs"]:
        for p in POINTS:
            for stage, cell in c["oracle"][p]["fails_at"].items():
                where.append([c["config"], POINT_LABELS[p], stage, str(cell["forks"]),
                              ", ".join(f"{k} {v}" for k, v in sorted(cell["kinds"].items()))])
    if not where:
        where.append(["–", "–", "every reference-solution fork recovered (or none was made)", "0", "–"])
    return [(title, header, rows),
            ("Where recovery fails (reference-solution forks that did not recover: the first subgoal the fork never "
             "attained, else its failure stage)", ["Configuration", "From", "Stage", "Forks", "Not recoverable, by kind"],
             where)]


def figure(rec: dict):
    """Grouped bars (a matplotlib Figure named ``recoverability``): per configuration with failures,
    the share recovered by the reference solution from each point (and by the model's retries, when
    run), with Wilson 95 % intervals; each bar's title says whose and from where."""
    from cab_core.analysis import figures  # matplotlib: imported only when a report is drawn

    series = [f"oracle from {POINT_LABELS[p]}" for p in POINTS]
    with_model = bool(rec.get("repeats"))
    if with_model:
        series += [f"model retry from {POINT_LABELS[p]}" for p in POINTS]
    rows = []
    for c in rec["configs"]:
        if not c["failures"]:
            continue
        parts = [c["oracle"][p] for p in POINTS] + ([c["model"][p] for p in POINTS] if with_model else [])
        rows.append((c["config"], [(s["share"], tuple(s["wilson95"]) if s["wilson95"] else None) for s in parts]))
    return figures.grouped_hbars("recoverability", "Failures recoverable (Wilson 95% interval)", rows, series)


def _outcome(f: dict | None) -> str:
    if f is None:
        return "–"
    if f["outcome"] == "recovered":
        said = f.get("oracle_said")
        return f"recovered, though the solution said not recoverable ({said['kind']})" if said else "recovered"
    if f["outcome"] == "not_recoverable":
        return f"not recoverable ({f['kind']}): {f.get('reason') or ''}".rstrip(": ")
    if f["outcome"] == "unexplained":
        return f"failed, no reason given ({f.get('kind') or '?'})"
    return f"no fork: {f.get('reason') or ''}".rstrip(": ")


def page_cases(rec: dict, view_links: dict[str, str] | None = None) -> dict:
    """Every failed attempt with its fork points and each fork's outcome, for the report page's
    table of forks (``templates/report.html.j2``): ``head`` and ``rows`` of cells, each ``{text,
    href}`` (href None: no link) or, for the model's retries, ``{ok, n, marks: [{mark, title, href}]}``.
    The cells link to the attempt's and the forks' pages (``view_links``: attempt dir relative to
    the report's directory -> page; a fork links to ``<its folder>/view.html`` when ``view_links``
    is given)."""
    view_links = view_links if view_links is not None else {}
    with_pages = bool(view_links)

    def fork_cell(f: dict | None) -> dict:
        linked = f is not None and with_pages and f["outcome"] in OUTCOMES
        return {"text": _outcome(f), "href": f"{f['dir']}/view.html" if linked and f is not None else None}

    def models(fs: list[dict]) -> dict:
        if not fs:
            return {"text": "–", "href": None}
        marks = [{"mark": "✓" if f["outcome"] == "recovered" else ("!" if f["outcome"] not in OUTCOMES else "✗"),
                  "title": _outcome(f), "href": f"{f['dir']}/view.html" if with_pages and f["outcome"] in OUTCOMES else None}
                 for f in fs]
        return {"ok": sum(f["outcome"] == "recovered" for f in fs), "n": len(fs), "marks": marks}

    with_model = bool(rec.get("repeats"))
    head = ["Attempt", "Configuration", "First failed stage", "Failure point", "Last call", "Oracle from failure point",
            "Oracle from last call", *(["Model from failure point", "Model from last call"] if with_model else [])]
    rows = []
    for x in rec["cases"]:
        fp = x["points"]["failure_point"]
        cells = [{"text": x["rel"], "href": view_links.get(x["rel"])}, {"text": x["config"], "href": None},
                 {"text": x["failed_stage"] or "–", "href": None}, {"text": "–" if fp is None else str(fp), "href": None},
                 {"text": str(x["points"]["last_call"]), "href": None},
                 fork_cell(x["oracle"].get("failure_point")), fork_cell(x["oracle"].get("last_call"))]
        if with_model:
            cells += [models((x.get("model") or {}).get(p) or []) for p in POINTS]
        rows.append(cells)
    return {"head": head, "rows": rows}


def notes(rec: dict) -> list[str]:
    """Plain-text lines: how many failures were forked, where the forks are, what the points are."""
    return [f"Recoverability: {len(rec['cases'])} failed attempt(s) forked at their failure point and last call, "
            f"{rec['forks']} fork(s) under {rec['dir']}, {rec['ran']} of them run now (the others had finished "
            "earlier). Failure point: the "
            "charged-call count at which every subgoal before the first never-attained one had been attained "
            "(0: the scene's start); last call: the attempt's charged-call count."]


def fork_folders(rec: dict | None, out: Path) -> list[Path]:
    """The folder of every fork that was made (once, though it may serve both points), ``out``
    being the report's folder."""
    found = [Path(out) / f["dir"] for x in (rec or {}).get("cases", [])
             for f in [*x["oracle"].values(), *[g for fs in (x["model"] or {}).values() for g in fs]]
             if f is not None and f["outcome"] in OUTCOMES]
    return list(dict.fromkeys(found))


# ---------------------------------------------------------------------------------------------
# making the forks
# ---------------------------------------------------------------------------------------------
def finished(d: Path) -> bool:
    """Whether a fork folder holds a finished fork (``result.json`` that is no infrastructure failure)."""
    try:
        return not is_infrastructure_failure(read_json_object(d / "result.json"))
    except CabError:
        return False


def read_fork(d: Path, at: int, rel: str, error: str | None = None, classify=None) -> dict:
    """A fork's outcome from its folder: ``{"dir", "at", "outcome", "kind", "reason", "fails_at"}``;
    outcome ``error`` (with the reason) when it did not finish."""
    if not finished(d):
        return {"dir": rel, "at": at, "outcome": "error", "kind": None,
                "reason": error or "the fork left no result.json", "fails_at": None}
    out = {"dir": rel, "at": at, **recovery(d), "fails_at": None}
    if out["outcome"] != "recovered":
        try:
            a = Attempt.load(d)
            stage = classify(a)[0] if classify is not None else None
            out["fails_at"] = fork_fails_at(a.result, stage)
        except Exception as e:  # an unreadable fork record: where it failed stays unknown
            out["fails_at"] = f"{LABELS['unresolved']} ({type(e).__name__})"
    return out


def run(root: Path, r: dict, folder: Path, out: Path, repeats: int = 0, jobs: int = 1) -> dict:
    """Fork every failed attempt of report ``r`` (built from ``root``) at its failure point and
    last call, into ``folder``; run the forks not yet finished, ``jobs`` at a time; return the
    recoverability record (``report.json`` ``recoverability``): ``dir`` (the folder relative to
    ``out``, the report's folder), ``repeats``, ``forks`` (how many in all), ``ran`` (how many were
    run now), ``cases`` (one per failed attempt: its
    points, first failed stage and each fork's outcome) and ``configs`` (:func:`summarize`)."""
    # the supervisor (and through it the attempt's spec, Hydra's config, the plugins): only a fork run needs it,
    # and it doubles the import time of cab-report (1.7 -> 4.5 s measured)
    from cab_core.sweep.supervisor import fork_configs, run_configs

    root, folder, out = Path(root), Path(folder), Path(out)
    if repeats < 0:
        raise ValueError(f"repeats must be >= 0, got {repeats}")
    cases, forks = [], []  # forks: (case, point names, who, parent folder, K, fork folder)
    for m in r["attempt_rows"]:
        if m["success"]:
            continue
        parent = root / m["rel"]
        pts = fork_points(read_json(parent / "result.json"), m.get("failure_stage"))
        case = {"rel": m["rel"], "config": m["config"], "task": m["task"], "seed": m.get("seed"),
                "failed_stage": pts["failed_stage"],
                "points": {p: pts[p] for p in POINTS}, "oracle": {p: None for p in POINTS},
                "model": {p: [] for p in POINTS} if repeats else None}
        cases.append(case)
        at: dict[int, list[str]] = {}
        for p in POINTS:
            if pts[p] is not None:
                at.setdefault(pts[p], []).append(p)
        for k, names in at.items():
            for who in [ORACLE] + [f"model-{i}" for i in range(1, repeats + 1)]:
                forks.append((case, names, who, parent, k, folder / m["rel"] / f"at-{k}" / who))
    todo = [f for f in forks if not finished(f[5])]
    errors: dict[Path, str] = {}
    configs, outs = [], []
    for _, _, who, parent, k, d in todo:
        if d.exists():  # an interrupted fork of an earlier run: made again from the start
            shutil.rmtree(d)
        try:
            configs.append(fork_configs([(str(parent), k)], ORACLE if who == ORACLE else None)[0])
            outs.append(str(d))
        except Exception as e:  # records that cannot be forked: that fork is an error, the rest go on
            errors[d] = f"{type(e).__name__}: {e}"
    if configs:
        for row, d in zip(run_configs(configs, outs, max(1, jobs)), outs):
            if "error" in row:
                errors[Path(d)] = row["error"]
    classify = Classifier()
    for case, names, who, _, k, d in forks:
        f = read_fork(d, k, os.path.relpath(d, out).replace(os.sep, "/"), errors.get(d), classify)
        for p in names:
            if who == ORACLE:
                case["oracle"][p] = f
            else:
                case["model"][p].append(f)
    return {"dir": os.path.relpath(folder, out).replace(os.sep, "/"), "repeats": repeats,
            "forks": len(forks), "ran": len(configs),
            "cases": cases, "configs": summarize(cases, [c["config"] for c in r["configs"]], repeats)}
