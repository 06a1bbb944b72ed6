"""``cab-report <dir>``: the paper's measures for every configuration found below a directory.

Reads only attempt records (any tree: every ``result.json`` below the directory is an attempt),
groups attempts by configuration (model, harness, simulator), and writes

    report.json   every number, machine-readable (what the tests and other tools read)
    report.md     the tables as Markdown (the summary table is also printed)
    report.html   one self-contained page: the tables, inline SVG figures, links to attempt pages
    figures/      each figure as PDF, SVG and PNG, for papers (listed in report.md)

The figures are matplotlib's (:mod:`cab_core.analysis.figures`), the page a Jinja2 template
(:mod:`cab_core.analysis.pages`, ``templates/report.html.j2``).

Unfinished attempts (records without ``result.json``) and unreadable ones are listed, never fatal.

``--compare A B`` adds the paired comparison of two configurations on their shared task instances
(exact McNemar on attempt pairs, paired bootstrap over instances); ``--plan-difference D`` adds how
many attempts detecting a difference D in success rate needs (also without a directory: the plan
alone). The statistics are :mod:`cab_core.analysis.stats`; their formulas: docs/statistics.md.

``--recoverability`` forks every failed attempt at its failure point (the charged call after which
its first never-attained subgoal should have followed: the call at which every subgoal before it had
been attained, 0 when none was) and at its last call, lets the stage-aware reference solution finish
each fork, and adds per configuration the share of failures it recovers from each point (Wilson 95 %
interval), where its recovery fails (stage, reasons by kind), a figure, and the forks of each failed
attempt (linked pages). ``--recoverability-model-repeats N`` also lets the attempt's own model (as its
records hold it) retry N times from each point. The forks go to ``recoverability/`` in the output
folder (``--recoverability-dir``); those already finished are not run again. Definitions:
:mod:`cab_core.analysis.recoverability`.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from cab_core.analysis import contract, instances, recoverability, stats
from cab_core.analysis.attempts import FORKS_FOLDER, Scan, read_json, scan
from cab_core.analysis.failure import LABELS, STAGES, Classifier
from cab_core.analysis.measures import (
    ACTION_CAUSES,
    CLAIMS,
    ESTIMATION_TOOLS,
    STOPPING,
    AttemptMeasures,
    ConfigSummary,
    matrix,
)
from cab_core.analysis.pages import Markup, render
from cab_core.analysis.viewer import write_view
from cab_core.contracts.verifier import BORDERLINE_FRACTION
from cab_core.errors import CabError, RecordError

REPORT_VERSION = "cab-report/1"
MALFORMED = (LookupError, TypeError, ValueError, AttributeError)  # a field of the wrong shape in a record


def measure(s: Scan) -> list[AttemptMeasures]:
    """Per-attempt measures, failure stage included. An attempt whose records cannot be measured
    (an unreadable event log, a malformed field) moves from ``s.attempts`` to ``s.problems``."""
    classify = Classifier()
    out, keep = [], []
    for a in s.attempts:
        try:
            m = AttemptMeasures.of(a)
            m.failure_stage, m.failure_detail = classify(a)
        except CabError as e:
            s.problems.append((a.rel, str(e)))
            continue
        except MALFORMED as e:
            s.problems.append((a.rel, f"malformed record ({type(e).__name__}: {e})"))
            continue
        out.append(m)
        keep.append(a)
    s.attempts = keep
    return out


def build(root: Path, compare: tuple[str, str] | None = None, plan: dict | None = None,
          bootstrap: dict | None = None, mix_contracts: bool = False) -> dict:
    """Everything the report shows, as plain data. ``compare``: two configurations (as the report
    names them, or a unique prefix) to compare on shared instances; ``plan``: the keyword
    arguments of :func:`stats.plan` (``tasks`` defaults to the tasks the sweep holds);
    ``bootstrap``: ``resamples``, ``confidence``, ``seed`` of the paired bootstrap; ``mix_contracts``:
    put attempts whose comparison contracts differ in one table, marked exploratory
    (:func:`contract.table_contracts`; else :class:`contract.ContractsDiffer`)."""
    s = scan(Path(root))
    ms = measure(s)
    crows = _contract_rows(s, ms)
    ms = [m for m in ms if m.rel in crows]
    contracts = contract.table_contracts(list(crows.values()), mix_contracts, str(root))
    max_calls = max([int(a.result["budget"].get("tool_calls_limit") or 0) for a in s.attempts] + [0])
    configs = sorted({m.config for m in ms})
    summaries = [ConfigSummary.of(c, [m for m in ms if m.config == c], max_calls) for c in configs]
    summaries.sort(key=lambda c: (-c.success_rate, c.config))
    sweep = sweep_manifest(Path(root))
    if sweep and isinstance(sweep["jobs"], int):  # planned attempts with no records at all yet
        seen = len(ms) + len(s.in_flight) + len(s.excluded) + len(s.problems)
        sweep["not_started"] = max(0, sweep["jobs"] - seen)
    r: dict[str, Any] = {"report_version": REPORT_VERSION, "attempts": len(ms), "in_flight": s.in_flight,
         "problems": [{"dir": d, "problem": p} for d, p in s.problems],
         "excluded": [{"dir": d, "why": w} for d, w in s.excluded], "sweep": sweep,
         "configs": [c.as_dict() for c in summaries], "matrix": matrix(ms),
         "attempt_rows": [vars(m) for m in sorted(ms, key=lambda m: (m.config, m.task, m.attempt, m.rel))],
         "comparison": None, "plan": None, "recoverability": None, "contracts": contracts}
    rows = r["attempt_rows"]
    r["instances"] = instances.by_instance_kind(rows, instances.seed_kinds({m["task"] for m in rows}))
    r["randomization"] = instances.by_randomization(rows)
    if compare:
        r["comparison"] = comparison(r, *compare, **(bootstrap or {}))
        pair = (r["comparison"]["a"], r["comparison"]["b"])
        r["comparison"]["contracts_differ"] = contract.report_check([c for c in crows.values() if c["config"] in pair])
    if plan:
        r["plan"] = stats.plan(**{"tasks": len(r["matrix"]) or 25, **plan})
    return r


def _contract_rows(s: Scan, ms: list[AttemptMeasures]) -> dict[str, dict]:
    """Per measured attempt (by folder), what :func:`contract.report_check` reads; an attempt whose
    contract is malformed moves to ``s.problems``."""
    by_rel = {a.rel: a for a in s.attempts}
    out = {}
    for m in ms:
        a = by_rel[m.rel]
        try:
            c = contract.of_result(a.result)
        except RecordError as e:
            s.problems.append((a.rel, str(e)))
            continue
        out[m.rel] = {"config": m.config, "task": m.task, "sim": a.result.get("sim"),
                      "harness": a.result.get("harness"), "contract": c}
    s.attempts = [a for a in s.attempts if a.rel in out]
    return out


def config_named(r: dict, name: str) -> str:
    """The configuration a name means: its full name as the report writes it, or a prefix of
    exactly one (``oracle`` for ``oracle (direct, <simulator>)``); a RecordError naming them otherwise."""
    names = [c["config"] for c in r["configs"]]
    if name in names:
        return name
    hits = [n for n in names if n.startswith(name)]
    if len(hits) == 1:
        return hits[0]
    raise RecordError(f"{'ambiguous' if hits else 'no'} configuration {name!r}; the report's configurations: "
                      + "; ".join(hits or names))


def comparison(r: dict, a: str, b: str, resamples: int = 10_000, confidence: float = 0.95, seed: int = 0) -> dict:
    """The paired comparison of configurations ``a`` and ``b`` on the task instances (task, seed)
    both ran: attempt i of A with attempt i of B (exact McNemar), and the difference in success
    rate over instances with its bootstrap percentile interval."""
    a, b = config_named(r, a), config_named(r, b)
    by: dict[str, dict] = {a: {}, b: {}}
    for m in r["attempt_rows"]:
        if m["config"] in by:
            by[m["config"]].setdefault((m["task"], m["seed"]), {})[m["attempt"]] = m["success"]
    shared = set(by[a]) & set(by[b])
    return {"a": a, "b": b, "instances": {"shared": len(shared), "only_a": len(set(by[a]) - shared),
                                          "only_b": len(set(by[b]) - shared)},
            **stats.compare(by[a], by[b], resamples, confidence, seed)}


def sweep_manifest(root: Path) -> dict | None:
    """The sweep's fingerprint and size from its manifest (``sweep.json``), when there is one."""
    try:
        m = read_json(root / "sweep.json")
    except CabError:
        return None
    return {"fingerprint": m.get("fingerprint"), "jobs": m.get("n_jobs")}


# ---------------------------------------------------------------------------------------------
# formatting helpers shared by the Markdown and HTML renderings
# ---------------------------------------------------------------------------------------------
def pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f}%"


def num(x: float | None) -> str:
    return "–" if x is None else f"{x:.1f}"


def usd(x: float | None) -> str:
    """Dollars: cents at paper scale, four decimals for the cheap attempts of small models."""
    return "–" if x is None else (f"${x:.2f}" if abs(x) >= 1 else f"${x:.4f}")


def tables(r: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of every table, in page order."""
    cs = r["configs"]
    ns = sorted({int(k.split("/")[1]) for c in cs for k in c["consistency"]})
    ks = [f"{k}/{n}" for n in ns for k in range(n + 1)]  # every consistency bucket, 0/n..n/n
    # the MCP clients that played each configuration, when any attempt was served over MCP
    with_clients = any(c.get("clients") for c in cs)
    client_col = (lambda c: [", ".join(c.get("clients") or []) or "–"]) if with_clients else (lambda c: [])  # noqa: E731
    out = [("Success and task coverage" + _marked(r.get("contracts")),
            ["Configuration", *(["MCP client"] if with_clients else []), "Success", "Rate", "Wilson 95%", "Coverage", *ks],
            [[c["config"], *client_col(c), f"{c['successes']}/{c['attempts']}", pct(c["success_rate"]),
              f"{pct(c['wilson95'][0])}–{pct(c['wilson95'][1])}", f"{c['coverage']}/{c['tasks']}",
              *[str(c["consistency"].get(k, 0)) for k in ks]] for c in cs]),
           *instances.tables(r),
           *uncertainty_tables(r),
           ("Stopping conditions and completion claims",
            ["Configuration", "Done", "Tool", "Phys.", "Other", "Correct", "Over", "Under", "Absent"],
            [[c["config"], *[str(c["stopping"][s]) for s in STOPPING], *[str(c["claims"][k]) for k in CLAIMS]]
             for c in cs]),
           ("Programs",
            ["Configuration", "Program share", "Programs", "Program errors"],
            [[c["config"], pct(c["program_share"]), f"{c['program_calls']}/{c['charged_calls']} calls",
              f"{c['program_errors']}/{c['programs_returned']}"
              + (f" ({pct(c['program_errors'] / c['programs_returned'])})" if c["programs_returned"] else "")]
             for c in cs]),
           ("Non-completed robot actions (direct and inside programs)",
            ["Configuration", "Non-completion", "Sim. advanced", *[a.capitalize() for a in ACTION_CAUSES]],
            [[c["config"], f"{c['not_completed_total']}/{c['actions']}"
              + (f" ({pct(c['not_completed_total'] / c['actions'])})" if c["actions"] else ""),
              str(c["not_completed_moved"]), *[str(c["not_completed"][a]) for a in ACTION_CAUSES]] for c in cs]),
           ("Resources",
            ["Configuration", "Calls (mean)", "Sim. s (median)", "Wall s (median)", "Wait s (median)",
             "Cost total", "Cost median", "Cost IQR", "Infra. retries"],
            [[c["config"], num(c["calls_mean"]), num(c["sim_seconds_median"]), num(c["wall_seconds_median"]),
              num(c["wait_seconds_median"]), usd(c["cost_total"]), usd(c["cost_median"]),
              "–" if c["cost_iqr"] is None else f"{usd(c['cost_iqr'][0])}–{usd(c['cost_iqr'][1])}",
              str(c["infra_retries"])] for c in cs]),
           ("Checkpoints (task-weighted coverage) and confirmed progress",
            ["Configuration", "Subgoal coverage", "Spatial coverage", "Success", "Failed: subgoal attained",
             "Failed: spatial only", "Failed: none"],
            [[c["config"], pct(c["subgoal_coverage"]), pct(c["spatial_coverage"]),
              *[str(c["progress"][k]) for k in ("success", "subgoal", "spatial_only", "none")]] for c in cs]),
           ("Failure stages (earliest supported stage per failed attempt)",
            ["Configuration", "Success", *[LABELS[s] for s in STAGES]],
            [[c["config"], str(c["successes"]), *[str(c["failure_stages"].get(s, 0)) for s in STAGES]] for c in cs]),
           (f"Borderline verdicts (decided by less than {BORDERLINE_FRACTION:.0%} of a tolerance: could flip on "
            "another machine)",
            ["Configuration", "Borderline successes", "Borderline failures", "Smallest success margin",
             "No margin on record"],
            [[c["config"], f"{c['borderline']['successes']}/{c['successes']}",
              f"{c['borderline']['failures']}/{c['attempts'] - c['successes']}",
              pct(c["borderline"]["min_success_margin"]), str(c["borderline"]["unrecorded"])] for c in cs])]
    tools = list(ESTIMATION_TOOLS) + sorted({t for c in cs for t in c["tool_use"]} - set(ESTIMATION_TOOLS))
    tools = [t for t in tools if any(t in c["tool_use"] for c in cs)]

    def use(c, t):
        u = c["tool_use"].get(t)
        return f"{pct(u['successes'] / u['attempts'])} ({u['successes']}/{u['attempts']})" if u else "–"

    out.append(("Tool use and success (success rate among attempts using each tool)",
                ["Configuration", *tools], [[c["config"], *[use(c, t) for t in tools]] for c in cs]))
    names = [c["config"] for c in cs]
    out.append(("Task x configuration (successful/attempts)", ["Task", *names],
                [[t, *["{}/{}".format(*row[n]) if n in row else "–" for n in names]] for t, row in r["matrix"].items()]))
    if r.get("recoverability"):
        out += recoverability.tables(r["recoverability"])
    return out


def uncertainty_tables(r: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """pass@k and pass^k per configuration; the paired comparison and the plan when asked for."""
    cs = r["configs"]
    ks = sorted({k for c in cs for k in c["pass_k"].get("k", [])})

    def at(c, key, k):
        curve = c["pass_k"]
        return pct(curve[key][curve["k"].index(k)]) if k in curve.get("k", []) else "–"

    out = [("pass@k and pass^k (unbiased over each task's attempts, averaged over tasks; pass^1 = pass@1)",
            ["Configuration", *[f"pass@{k}" for k in ks], *[f"pass^{k}" for k in ks if k > 1]],
            [[c["config"], *[at(c, "pass_at_k", k) for k in ks], *[at(c, "pass_hat_k", k) for k in ks if k > 1]]
             for c in cs])]
    cmp = r.get("comparison")
    if cmp:
        boot = cmp["bootstrap"]
        ci = "–" if boot["ci"] is None else f"{100 * boot['ci'][0]:+.1f} to {100 * boot['ci'][1]:+.1f} points"
        diff = "–" if boot["difference"] is None else f"{100 * boot['difference']:+.1f} points"
        ins = cmp["instances"]
        out.append((f"Paired comparison: A = {cmp['a']}, B = {cmp['b']}"
                    + _marked({"differing": cmp.get("contracts_differ") or []}), ["Measure", "Value"],
                    [["Shared task instances (task, seed)", f"{ins['shared']} (only A: {ins['only_a']}, only B: {ins['only_b']})"],
                     ["Attempt pairs (attempt i of A with attempt i of B)", str(cmp["pairs"])],
                     ["Both succeeded / only A / only B / neither",
                      f"{cmp['both']} / {cmp['only_a']} / {cmp['only_b']} / {cmp['neither']}"],
                     ["Exact McNemar p-value (two-sided)", f"{cmp['mcnemar_p']:.4g}"],
                     ["Success rate difference A - B (mean over instances)", diff],
                     [f"Paired bootstrap {boot['confidence']:.0%} interval ({boot['resamples']} resamples of "
                      f"instances, seed {boot['seed']})", ci]]))
    pl = r.get("plan")
    if pl:
        out.append((f"Attempts needed to detect a difference of {100 * pl['difference']:.1f} points "
                    f"(power {pl['power']:.0%}, two-sided alpha {pl['alpha']:g})", ["Measure", "Value"],
                    [["Success rates", f"{pct(pl['rates'][0])} vs {pct(pl['rates'][1])}"],
                     ["Attempts per configuration", str(pl["attempts_per_config"])],
                     [f"Attempts per task over {pl['tasks']} tasks",
                      f"{pl['attempts_per_task']} ({pl['attempts_per_config_rounded']} per configuration)"],
                     ["Approximation", pl["method"]],
                     *([["Attempt pairs for a paired comparison (McNemar), discordant share "
                         f"{pct(pl['paired']['discordant'])}",
                         f"{pl['paired']['pairs']} ({pl['paired']['pairs_per_task']} per task; the normal "
                         f"approximation says {pl['paired']['pairs_approximation']})"]] if pl.get("paired") else [])]))
    return out


def _marked(contracts: dict | None) -> str:
    """`` (EXPLORATORY: ...)`` after the title of a table whose attempts' contracts differ, else ``""``."""
    parts = (contracts or {}).get("differing") or []
    return f" ({contract.exploratory_note(parts)})" if parts else ""


def md_table(header: list[str], rows: list[list[str]]) -> str:
    esc = lambda s: str(s).replace("|", "\\|")  # noqa: E731
    lines = ["| " + " | ".join(map(esc, header)) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(map(esc, row)) + " |" for row in rows])


def notes(r: dict) -> list[str]:
    """Plain-text lines on what the report does not count, and on the sweep."""
    out = [f"{r['attempts']} attempts, {len(r['configs'])} configurations."]
    ct = r.get("contracts") or {}
    if ct.get("differing"):
        out.append(f"{contract.exploratory_note(ct['differing'])}: these attempts did not all run the same "
                   "benchmark (cab-report --mix-contracts put them in one table); their differences are not "
                   "only the configurations'.")
    if ct.get("without"):
        out.append(f"Records without a comparison contract (written before cab kept one): {ct['without']}; "
                   "not checked.")
    if r["sweep"]:
        sw = r["sweep"]
        out.append(f"Sweep manifest: {sw['jobs']} jobs ({sw.get('not_started', '?')} not started), "
                   f"configuration fingerprint {sw['fingerprint']}.")
    if r["in_flight"]:
        out.append(f"Unfinished attempts (no result.json): {len(r['in_flight'])}: " + ", ".join(r["in_flight"]))
    if r["excluded"]:
        out.append(f"Excluded, not scored (infrastructure failures, interrupted attempts; not the model's): "
                   f"{len(r['excluded'])}: "
                   + "; ".join(f"{e['dir']} {e['why']}" for e in r["excluded"]))
    for c in r["configs"]:  # the serving endpoint's faults, apart from the model's (measures._server_side)
        ss = c.get("server_side") or {}
        counts = [(ss.get("salvaged_calls", 0), "tool calls salvaged from the server's output"),
                  (ss.get("unparseable_calls", 0), "tool calls unparseable"),
                  (ss.get("attempts_ended_by_server_error", 0), "attempts ended by a server error")]
        said = [f"{n} {what}" for n, what in counts if n]
        if said or ss.get("probe_problems"):
            out.append(f"Server-side, not the model's: {c['config']}: " + ", ".join(said or ["no faults counted"])
                       + "".join(f"; probe: {p}" for p in ss.get("probe_problems", [])))
    out += [f"Skipped record {p['dir']}: {p['problem']}" for p in r["problems"]]
    if r.get("recoverability"):
        out += recoverability.notes(r["recoverability"])
    flagged = [(c["config"], a) for c in r["configs"] for a in c["borderline"]["attempts"]]
    if flagged:
        out.append(f"Borderline verdicts (deciding margin under {BORDERLINE_FRACTION:.0%} of its tolerance): "
                   + "; ".join(f"{a} ({cfg})" for cfg, a in flagged))
    return out


def markdown(r: dict, figs: list[tuple[str, str]] | None = None) -> str:
    """The tables as Markdown; ``figs``: (name, title) of the figures written to ``figures/``, listed
    (the SVG shown, the PDF and PNG linked)."""
    tabs = [f"## {title}\n\n{md_table(header, rows)}" for title, header, rows in tables(r)]
    parts = ["# cab report", *tabs[:1], "\n\n".join(notes(r))]  # the summary table first, as on the page
    if figs:
        from cab_core.analysis.figures import PNG_DPI  # matplotlib: imported only when a report is drawn

        parts.append("## Figures\n\n" + f"PDF, SVG and PNG ({PNG_DPI} dpi) of each figure in `{FIGURES_FOLDER}/`.\n\n"
                     + "\n\n".join(f"![{t}]({FIGURES_FOLDER}/{n}.svg)\n\n{t}: [PDF]({FIGURES_FOLDER}/{n}.pdf) · "
                                     f"[SVG]({FIGURES_FOLDER}/{n}.svg) · [PNG]({FIGURES_FOLDER}/{n}.png)" for n, t in figs))
    return "\n\n".join(parts + tabs[1:]) + "\n"


# ---------------------------------------------------------------------------------------------
# HTML
# ---------------------------------------------------------------------------------------------
FIGURES_FOLDER = "figures"  # beside report.md: <name>.pdf, .svg, .png of each figure


def figures(r: dict) -> list:
    """The report's figures (matplotlib Figures, :mod:`cab_core.analysis.figures`): success,
    outcomes and failure stages, claims, coverage, coverage over charged calls, success against cost
    and against wall time (where known), recoverability (when run)."""
    from cab_core.analysis import figures as fg  # matplotlib: imported only when a report is drawn

    cs = r["configs"]
    outcomes = [(c["config"], [c["successes"]] + [c["failure_stages"].get(s, 0) for s in STAGES]) for c in cs]
    figs = [fg.hbars("success", "Success rate (Wilson 95% interval)",
                     [(c["config"], c["success_rate"], tuple(c["wilson95"])) for c in cs]),
            fg.stacked("outcomes", "Outcome and failure stage per attempt", outcomes,
                       ["Success"] + [LABELS[s] for s in STAGES]),
            fg.stacked("claims", "Completion claims", [(c["config"], [c["claims"][k] for k in CLAIMS]) for c in cs],
                       list(CLAIMS)),
            fg.grouped_hbars("coverage", "Checkpoint coverage (task-weighted)",
                             [(c["config"], [(c["subgoal_coverage"] or 0.0, None), (c["spatial_coverage"] or 0.0, None)])
                              for c in cs], ["subgoal checkpoints", "spatial checkpoints"]),
            fg.lines("coverage_curve", "Spatial checkpoint coverage over charged calls",
                     [(c["config"], c["spatial_curve"]) for c in cs], "charged calls", "coverage")]
    with_cost = [(c["config"], c["cost_total"], c["success_rate"]) for c in cs if c["cost_total"] is not None]
    if with_cost:
        figs.append(fg.scatter("success_cost", "Success rate against total cost", with_cost, "total cost (USD)",
                               "success rate", xfmt=usd))
    with_wall = [(c["config"], c["wall_seconds_median"], c["success_rate"]) for c in cs if c["wall_seconds_median"] is not None]
    if with_wall:
        figs.append(fg.scatter("success_wall", "Success rate against median wall time", with_wall,
                               "median wall time (s)", "success rate", xfmt=lambda x: f"{x:.1f} s"))
    if r.get("recoverability"):
        figs.append(recoverability.figure(r["recoverability"]))
    return figs


def _matrix_class(v: str) -> str | None:
    if "/" not in v:
        return None
    k, n = (int(x) for x in v.split("/"))
    return "ok" if k == n else ("part" if k else "bad")


def margin_text(m: dict) -> str:
    """An attempt's deciding margin: "borderline 4% (green_on_red)", "95% (green_on_red)", "–"."""
    if m.get("margin") is None:
        return "–"
    return f"{'borderline ' if m['borderline'] else ''}{pct(m['margin'])} ({m['margin_predicate']})"


def html(r: dict, view_links: dict[str, str], figs: list | None = None) -> str:
    """The report page (``templates/report.html.j2``): the notes, the figures as inline SVG (``figs``,
    default :func:`figures`), the tables, every attempt linked to its page (``view_links``)."""
    from cab_core.analysis import figures as fg  # matplotlib: imported only when figures are drawn

    tabs = []
    for title, header, rows in tables(r):
        cc = _matrix_class if title.startswith("Task x") else None
        tabs.append({"title": title, "header": header,
                     "rows": [[(str(v), cc(str(v)) if cc and j else None) for j, v in enumerate(row)] for row in rows]})
    attempts = [{"rel": m["rel"], "link": view_links.get(m["rel"]), "config": m["config"],
                 "success": "yes" if m["success"] else "no", "termination": m["termination"], "claim": m["claim"],
                 "calls": m["charged_calls"], "stage": LABELS.get(m["failure_stage"], "") if m["failure_stage"] else "",
                 "why": m["failure_detail"], "borderline": m["borderline"], "margin": margin_text(m)}
                for m in r["attempt_rows"]]
    figs = figures(r) if figs is None else figs
    return render("report.html.j2", notes=notes(r), tables=tabs, attempts=attempts,
                  unfinished=[(d, view_links[d]) for d in r["in_flight"] if d in view_links],
                  figures=[Markup(fg.inline_svg(f)) for f in figs],
                  cases=recoverability.page_cases(r["recoverability"], view_links) if r.get("recoverability") else None)


def write(root: Path, out: Path | None = None, views: bool = True, recover: dict | None = None,
          figure_files: bool = True, **extra) -> dict:
    """Build the report for ``root`` and write report.json, report.md and report.html into ``out``
    (default: ``root``); with ``views``, also each attempt's view.html, linked from the page.
    ``recover``: fork the failed attempts (:func:`recoverability.run`'s ``repeats``, ``jobs`` and
    ``folder``, default ``<out>/recoverability``). ``extra``: what :func:`build` adds (``compare``,
    ``plan``, ``bootstrap``). ``figure_files``: also write each figure as PDF, SVG and PNG into
    ``<out>/figures/`` (listed in report.md); the page has them inline either way."""
    root = Path(root)
    out = Path(out) if out is not None else root
    r = build(root, **extra)
    if not (r["attempts"] or r["problems"] or r["excluded"] or r["in_flight"]):
        raise RecordError(f"no attempt found under {root} (no result.json or events.jsonl below it); nothing written")
    out.mkdir(parents=True, exist_ok=True)
    if recover is not None:
        folder = recover.get("folder") or out / FORKS_FOLDER
        r["recoverability"] = recoverability.run(root, r, Path(folder), out, recover.get("repeats", 0),
                                                 recover.get("jobs", 1))
    links = {}
    if views:
        for d in recoverability.fork_folders(r["recoverability"], out):  # the forks' pages, linked from the page
            write_view(d)
        for rel in [m["rel"] for m in r["attempt_rows"]] + r["in_flight"]:
            page = write_view(root / rel)
            links[rel] = os.path.relpath(page, out).replace(os.sep, "/")
    from cab_core.analysis import figures as fg  # matplotlib: imported only when figures are drawn

    figs = figures(r)
    if figure_files:
        fg.write_files(figs, out / FIGURES_FOLDER)
    (out / "report.json").write_text(json.dumps(r, indent=1))
    (out / "report.md").write_text(markdown(r, [(f.cab_name, f.cab_title) for f in figs] if figure_files else None))
    (out / "report.html").write_text(html(r, links, figs))
    return r
