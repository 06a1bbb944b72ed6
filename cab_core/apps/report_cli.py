"""``cab-report <dir>``: the command line of the report (:mod:`cab_core.analysis.report`, which
builds and writes it); its exit status and options are in ``cab-report --help``."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from cab_core.analysis import contract, recoverability, stats
from cab_core.analysis.report import FIGURES_FOLDER, build, md_table, tables, uncertainty_tables, write
from cab_core.errors import CabError


def _parser() -> argparse.ArgumentParser:
    """cab-report's options."""
    ap = argparse.ArgumentParser(
        prog="cab-report", description="The paper's measures for every attempt below a directory.",
        epilog="Exit status: 0 report written; 1 written, but no finished attempt to measure (only unfinished "
               "or unreadable ones); 2 nothing written: the directory does not exist or holds no attempt, a "
               "configuration given to --compare is not in it, or its attempts' comparison contracts differ "
               "(without --mix-contracts). The statistics: docs/statistics.md.")
    ap.add_argument("dir", nargs="?", help="a sweep directory (or any tree of attempt directories); "
                                           "may be left out with --plan-difference (the plan alone)")
    ap.add_argument("--out", help="where report.md/.html/.json go (default: the directory itself)")
    ap.add_argument("--no-views", action="store_true", help="do not write each attempt's view.html")
    ap.add_argument("--no-figure-files", action="store_true",
                    help=f"do not write {FIGURES_FOLDER}/ (each figure as PDF, SVG and PNG, for papers); the page "
                         "shows the figures either way")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"),
                    help="compare two configurations on their shared task instances (names as the report writes "
                         "them, or a prefix of exactly one: 'oracle')")
    ap.add_argument("--mix-contracts", action="store_true",
                    help="put attempts whose comparison contracts differ (another budget, simulator version, task "
                         "code...) in one table, marked exploratory with the differing parts named; without it "
                         "such a directory is refused, naming them (docs/comparing.md)")
    ap.add_argument("--against", metavar="SOURCE",
                    help="put each configuration beside the same one elsewhere: 'paper' (the published figures a "
                         "plugin offers, e.g. the suite's paper), an earlier sweep's folder or an exported result "
                         "(cab-export leaderboard's leaderboard.jsonl, or a folder holding one); Wilson intervals, "
                         "exact binomial and Fisher tests, a forest plot and a verdict per configuration, written "
                         "to against.md/.json (docs/comparing.md)")
    ap.add_argument("--as", dest="labels", action="append", metavar="CONFIG=NAME",
                    help="with --against: compare configuration CONFIG (or a prefix of exactly one) with NAME of the "
                         "other side (a paper configuration's name, or 'model (harness)'); repeatable")
    ap.add_argument("--resamples", type=int, default=10_000, help="paired bootstrap resamples (default 10000)")
    ap.add_argument("--confidence", type=float, default=0.95, help="bootstrap interval (default 0.95)")
    ap.add_argument("--bootstrap-seed", type=int, default=0, help="seed of the bootstrap's RNG (default 0)")
    ap.add_argument("--plan-difference", type=float, metavar="D",
                    help="attempts needed to detect a difference D in success rate (e.g. 0.1)")
    ap.add_argument("--plan-baseline", type=float, default=0.5,
                    help="the success rate the difference is centred on (default 0.5, the most demanding)")
    ap.add_argument("--plan-tasks", type=int, help="tasks to spread the attempts over (default: the sweep's, else 25)")
    ap.add_argument("--plan-discordant", type=float, metavar="P",
                    help="with --plan-difference: also the attempt pairs a paired comparison (exact McNemar) "
                         "needs when a share P of the pairs are discordant (one success, one failure; from "
                         "a pilot's --compare: (only A + only B) / pairs)")
    ap.add_argument("--alpha", type=float, default=0.05, help="two-sided significance level of the plan (default 0.05)")
    ap.add_argument("--power", type=float, default=0.80, help="power of the plan (default 0.80)")
    ap.add_argument("--recoverability", action="store_true",
                    help="fork every failed attempt at its failure point (the charged call at which every subgoal "
                         "before its first never-attained one had been attained; 0 when none was) and at its last "
                         "call, let the stage-aware reference solution finish each fork, and add the share of "
                         "failures it recovers (Wilson 95%% interval), where recovery fails and why, per "
                         "configuration (table, figure, the forks of each failure); forks already finished are "
                         "not run again")
    ap.add_argument("--recoverability-model-repeats", type=int, default=0, metavar="N",
                    help="with --recoverability: also let each failed attempt's own model (its recorded model and "
                         "harness configuration, e.g. a scripted agent's script) retry N times from each point "
                         "(default 0)")
    ap.add_argument("--recoverability-dir", metavar="DIR",
                    help="where the forks go (default: recoverability/ in the output folder; a folder of that name "
                         "is never counted as part of the sweep)")
    ap.add_argument("--recoverability-jobs", type=int, default=os.cpu_count() or 1, metavar="J",
                    help="forks run at a time, each in its own process (default: the cores)")
    return ap


def _plan(ap: argparse.ArgumentParser, a: argparse.Namespace) -> tuple[dict | None, dict | None]:
    """The study plan asked for (``--plan-*``) and that plan computed for 25 tasks (its table when no
    directory is given), both None without ``--plan-difference``. Bad combinations of options end in
    ``ap.error``."""
    if a.recoverability_model_repeats < 0 or a.recoverability_jobs < 1:
        ap.error("--recoverability-model-repeats must be >= 0 and --recoverability-jobs >= 1")
    if not a.recoverability and (a.recoverability_model_repeats or a.recoverability_dir):
        ap.error("--recoverability-model-repeats and --recoverability-dir need --recoverability")
    if a.plan_discordant is not None and a.plan_difference is None:
        ap.error("--plan-discordant goes with --plan-difference D")
    if a.plan_difference is None:
        return None, None
    plan = {"difference": a.plan_difference, "baseline": a.plan_baseline, "alpha": a.alpha, "power": a.power,
            "discordant": a.plan_discordant}
    if a.plan_tasks is not None:
        plan["tasks"] = a.plan_tasks
    try:
        alone = stats.plan(**{"tasks": 25, **plan})
    except ValueError as e:
        ap.error(str(e))
    return plan, alone


def _print_summary(a: argparse.Namespace, r: dict) -> None:
    """What cab-report prints after writing report ``r``: the summary table, the comparison and the plan
    when asked for, the recoverability table when run; then on stderr what was skipped, what was
    written, and (exit status 1) that no finished attempt was measured."""
    title, header, rows = tables(r)[0]
    if (r.get("contracts") or {}).get("differing"):
        print(f"cab-report: {contract.exploratory_note(r['contracts']['differing'])}", file=sys.stderr)
        print(title)
    print(md_table(header, rows))
    for title, header, rows in uncertainty_tables(r)[1:]:  # the comparison and the plan, when asked for
        print(f"\n{title}\n\n{md_table(header, rows)}")
    if r.get("recoverability"):
        title, header, rows = recoverability.tables(r["recoverability"])[0]
        print(f"\n{title}\n\n{md_table(header, rows)}")
    for p in r["problems"]:
        print(f"cab-report: skipped {p['dir']}: {p['problem']}", file=sys.stderr)
    if r["in_flight"]:
        print(f"cab-report: {len(r['in_flight'])} unfinished attempt(s) not counted", file=sys.stderr)
    files = "" if a.no_figure_files else f" and {FIGURES_FOLDER}/ (PDF, SVG, PNG of each figure)"
    print(f"cab-report: wrote report.md, report.html, report.json{files} to {a.out or a.dir}", file=sys.stderr)
    if not r["attempts"]:  # only unfinished, unreadable or excluded attempts: the tables are empty
        print(f"cab-report: no finished attempt to measure under {a.dir}", file=sys.stderr)
        sys.exit(1)


def main(argv: list[str] | None = None) -> None:
    ap = _parser()
    a = ap.parse_args(argv)
    plan, alone = _plan(ap, a)
    if a.labels and not a.against:
        ap.error("--as CONFIG=NAME goes with --against")
    if a.dir is None and alone is not None:
        title, header, rows = uncertainty_tables({"configs": [], "plan": alone})[-1]
        print(f"{title}\n\n{md_table(header, rows)}")
        return
    if a.dir is None:
        ap.error("a directory is needed (only --plan-difference runs without one)")
    if not Path(a.dir).exists():
        print(f"cab-report: {a.dir} does not exist", file=sys.stderr)
        sys.exit(2)
    extra = {"compare": a.compare, "plan": plan, "mix_contracts": a.mix_contracts,
             "bootstrap": {"resamples": a.resamples, "confidence": a.confidence, "seed": a.bootstrap_seed}}
    recover = None
    if a.recoverability:
        recover = {"repeats": a.recoverability_model_repeats, "jobs": a.recoverability_jobs,
                   "folder": Path(a.recoverability_dir) if a.recoverability_dir else None}
    try:
        r = write(Path(a.dir), Path(a.out) if a.out else None, views=not a.no_views, recover=recover,
                  figure_files=not a.no_figure_files, **extra)
    except CabError as e:
        print(f"cab-report: {e}", file=sys.stderr)
        sys.exit(2)
    _print_summary(a, r)
    if a.against:
        _against(a, r)


def _against(a: argparse.Namespace, r: dict) -> None:
    """``--against``: the comparison printed (tables, notes) and written beside the report; exit 2
    with one line when the source or a label names nothing."""
    from cab_core.analysis import against, leaderboard

    try:
        kind = against.source_kind(a.against, leaderboard.FILE)
        earlier = build(Path(a.against), mix_contracts=a.mix_contracts) if kind == "run" else None
        exported = None
        if kind == "export":
            path = Path(a.against) / leaderboard.FILE if Path(a.against).is_dir() else Path(a.against)
            exported = against.exported_rows(leaderboard.read(path), path)
        cmp = against.against(Path(a.dir), r, a.against, against.parse_labels(a.labels),
                              bootstrap_cfg={"resamples": a.resamples, "confidence": a.confidence,
                                             "seed": a.bootstrap_seed}, earlier=earlier, exported=exported)
        against.write(cmp, Path(a.out or a.dir), figure_files=not a.no_figure_files)
    except CabError as e:
        print(f"cab-report: {e}", file=sys.stderr)
        sys.exit(2)
    for title, header, rows in against.tables(cmp):
        print(f"\n{title}\n\n{md_table(header, rows)}")
    print()
    for line in against.notes(cmp):
        print(line)
    print(f"cab-report: wrote against.md, against.json to {a.out or a.dir}", file=sys.stderr)
