"""``cab-suite-check``: run every task's reference solution (and the idle agent) in parallel over
the cores and print, per task: success, calls and simulated seconds used against the budgets, the
paper's reference-solution figures beside them, and the checkpoints attained. The idle agent must
fail every task, with no subgoal satisfied at the start. ``--sim a,b`` runs the same attempts on
several simulators and adds a cross-simulator table (per task and simulator: success, calls,
simulated seconds, wall seconds of the oracle). ``--forks`` then forks every oracle attempt (and
every attempt under ``--fork-from``) at each of its charged calls and lets the stage-aware
reference solution finish from there: each fork must succeed or say why it cannot."""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import NoReturn

from cab_core.attempt.fork import charged_calls, read_jsonl
from cab_core.config import composed, default_selection
from cab_core.contracts.verifier import BORDERLINE_FRACTION
from cab_core.errors import ConfigError
from cab_core.plugins import all_tasks, registry
from cab_core.sweep.supervisor import fork_configs, run_batch, run_configs


def verdict(rows: list[dict]) -> dict:
    o = [r for r in rows if r["agent"] == "oracle"]
    i = [r for r in rows if r["agent"] == "idle"]

    def within(r: dict) -> bool:
        return "error" not in r and r["success"] and r["calls"] <= r["calls_limit"] and r["sim_s"] <= r["sim_s_limit"]

    sub = [x for r in o if "error" not in r for x in r["subgoals"]]
    spa = [x for r in o if "error" not in r for x in r["spatial"]]
    return {
        "oracle_success_within_budget": sum(map(within, o)), "oracle_attempts": len(o),
        "idle_success": sum(1 for r in i if r.get("success")), "idle_attempts": len(i),
        "idle_subgoal_at_start": sum(1 for r in i if any(r.get("subgoals_at_start") or [])),
        "subgoals_attained": sum(sub), "subgoals_total": len(sub),
        "spatial_attained": sum(spa), "spatial_total": len(spa),
        # the oracle successes decided by the smallest margin: the verdicts another machine could flip
        "oracle_borderline": sum(1 for r in o if within(r) and r.get("margin") is not None
                                 and r["margin"] < BORDERLINE_FRACTION),
        "oracle_min_margin": min((r["margin"] for r in o if within(r) and r.get("margin") is not None), default=None),
    }


def print_table(rows: list[dict]) -> None:
    hdr = f"{'task':<26}{'seed':>5} {'sim':<9}{'agent':<7}{'result':<9}{'calls':>10}{'ref':>5}{'sim s':>15}{'ref':>7}{'subgoals':>10}{'spatial':>9}{'wall s':>8}{'margin':>8}"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        if "error" in r:
            print(f"{r['task']:<26}{r['seed']:>5} {r['sim']:<9}{r['agent']:<7}ERROR    {r['error'][:80]}")
            continue
        sg, sp = r["subgoals"], r["spatial"]
        print(f"{r['task']:<26}{r['seed']:>5} {r['sim']:<9}{r['agent']:<7}{'success' if r['success'] else 'fail':<9}"
              f"{r['calls']:>4}/{r['calls_limit']:<5}{r['ref_calls'] or '':>5}"
              f"{r['sim_s']:>7.1f}/{r['sim_s_limit']:<7g}{r['ref_sim_s'] or '':>7}"
              f"{sum(sg):>6}/{len(sg):<3}{sum(sp):>5}/{len(sp):<3}{r['wall_s']:>8.1f}"
              f"{'' if r.get('margin') is None else format(r['margin'], '.0%'):>8}")


def cross_sim(rows: list[dict]) -> dict:
    """``{task: {sim: {success, calls, sim_s, wall_s}}}`` over the oracle attempts (the first seed
    of each task), the same attempts side by side on each simulator."""
    out: dict[str, dict[str, dict]] = {}
    for r in rows:
        if r["agent"] != "oracle" or r["sim"] in out.get(r["task"], {}):
            continue
        if "error" in r:
            cell = {"success": False, "calls": None, "sim_s": None, "wall_s": r["wall_s"], "error": r["error"]}
        else:
            cell = {"success": r["success"], "calls": r["calls"], "sim_s": round(r["sim_s"], 2), "wall_s": r["wall_s"]}
        out.setdefault(r["task"], {})[r["sim"]] = cell
    return out


PERTURBED_SUCCESS_MIN = 0.95  # every oracle, on each simulator, over its perturbed runs


def robustness(rows: list[dict]) -> dict:
    """``{task: {sim: {"successes", "runs", "rate"}}}`` over the oracle attempts (all seeds and
    perturbations of the check)."""
    out: dict[str, dict[str, dict]] = {}
    for r in rows:
        if r["agent"] != "oracle":
            continue
        cell = out.setdefault(r["task"], {}).setdefault(r["sim"], {"successes": 0, "runs": 0, "min_margin": None})
        cell["runs"] += 1
        ok = ("error" not in r and bool(r["success"]) and r["calls"] <= r["calls_limit"]
              and r["sim_s"] <= r["sim_s_limit"])
        cell["successes"] += int(ok)
        if ok and r.get("margin") is not None:
            cell["min_margin"] = r["margin"] if cell["min_margin"] is None else min(cell["min_margin"], r["margin"])
    for cells in out.values():
        for c in cells.values():
            c["rate"] = round(c["successes"] / c["runs"], 3)
    return out


def print_robustness(table: dict, sims: list[str]) -> None:
    """Successes/runs and the smallest deciding margin of a success, per task and simulator."""
    print(f"{'task':<26}" + "".join(f"{s:>22}" for s in sims))
    print("-" * (26 + 22 * len(sims)))

    def cell(c: dict) -> str:
        m = "" if c["min_margin"] is None else f"min {c['min_margin']:.0%}"
        return f"{c['successes']:>9}/{c['runs']:<4}{m:>9}"

    for task, cells in table.items():
        print(f"{task:<26}" + "".join(cell(cells[s]) if s in cells else f"{'-':>22}" for s in sims))


def print_cross_sim(table: dict, sims: list[str]) -> None:
    hdr = f"{'task':<26}" + "".join(f"{s:>32}" for s in sims)
    print(hdr)
    print(f"{'':<26}" + "".join(f"{'result  calls   sim s  wall s':>32}" for _ in sims))
    print("-" * len(hdr))
    for task, cells in table.items():
        line = f"{task:<26}"
        for s in sims:
            c = cells.get(s)
            if c is None or c["calls"] is None:
                line += f"{'error' if c else '-':>32}"
            else:
                line += f"{'success' if c['success'] else 'fail':>14}{c['calls']:>7}{c['sim_s']:>8.1f}{c['wall_s']:>8.1f}"
        print(line)


def fork_parents(dirs: list[Path]) -> list[Path]:
    """Every attempt folder under ``dirs`` (a folder holding ``result.json`` and ``events.jsonl``),
    not one nested in another attempt (its replays and forks)."""
    found: list[Path] = []
    for d in dirs:
        for r in sorted(Path(d).rglob("result.json")):
            p = r.parent
            if (p / "events.jsonl").is_file() and not any(q in p.parents for q in found):
                found.append(p)
    return found


def fork_check(rows: list[dict], extra: list[Path], out: Path, jobs: int, planner: str | None = None) -> dict:
    """Fork each oracle attempt of ``rows`` and each attempt under ``extra`` at every charged call;
    the stage-aware oracle finishes each. Prints a table per task and returns the figures. Every
    fork makes its prefix again with ``planner`` (default: the default configuration's), also for a
    recorded parent planned by another one: its prefix must still reproduce the parent's world."""
    own = [Path(r["dir"]) for r in rows if r["agent"] == "oracle" and "dir" in r]
    parents = own + fork_parents(extra)
    points, outs, origin = [], [], []
    for i, p in enumerate(parents):
        n = charged_calls(read_jsonl(p / "events.jsonl"))
        for k in range(n + 1):
            points.append((str(p), k))
            outs.append(str(out / f"{i:03d}-{p.name}" / f"at-{k}"))
            origin.append("oracle" if i < len(own) else "recorded")
    print(f"\nforks: {len(points)} from {len(parents)} attempts", file=sys.stderr, flush=True)
    fork_rows = run_configs(fork_configs(points, planner=planner or default_selection(("planner",))["planner"]), outs, jobs)
    for r, o in zip(fork_rows, origin):
        r["origin"] = o
    fresh_equal = all(r.get("success") for r in fork_rows if r.get("fork_at") == 0 and r["origin"] == "oracle")
    table: dict[tuple, dict] = {}
    for r in fork_rows:
        c = table.setdefault((r["task"], r["origin"]), {"forks": 0, "recovered": 0, "not_recoverable": {},
                                                        "unexplained": [], "errors": 0})
        c["forks"] += 1
        if "error" in r:
            c["errors"] += 1
        elif r.get("outcome") == "recovered":
            c["recovered"] += 1
            if r.get("oracle_said"):  # solved, yet the solution's stage check said it could not be
                c["unexplained"].append(f"at {r['fork_at']}: succeeded though the solution said "
                                        f"not recoverable ({r['oracle_said']['kind']})")
        elif r.get("outcome") == "not_recoverable":
            c["not_recoverable"][r["kind"]] = c["not_recoverable"].get(r["kind"], 0) + 1
        else:
            c["unexplained"].append(f"at {r['fork_at']}: {r.get('kind')} {str(r.get('reason'))[:60]}")
    hdr = f"{'task':<26}{'parent':<10}{'forks':>6}{'recovered':>10}  not recoverable (why)"
    print("\n" + hdr + "\n" + "-" * (len(hdr) + 20))
    for (task, origin), c in table.items():
        why = ", ".join(f"{k} {n}" for k, n in sorted(c["not_recoverable"].items())) or "-"
        print(f"{task:<26}{origin:<10}{c['forks']:>6}{c['recovered']:>10}  {why}"
              + (f"; UNEXPLAINED {len(c['unexplained'])}: {'; '.join(c['unexplained'][:3])}" if c["unexplained"] else "")
              + (f"; ERRORS {c['errors']}" if c["errors"] else ""))
    total = {"forks": len(fork_rows), "recovered": sum(c["recovered"] for c in table.values()),
             "not_recoverable": sum(sum(c["not_recoverable"].values()) for c in table.values()),
             "unexplained": sum(len(c["unexplained"]) for c in table.values()),
             "errors": sum(c["errors"] for c in table.values()), "fresh_equal": fresh_equal,
             "per_task": [{"task": t, "parent": o, **c} for (t, o), c in table.items()], "rows": fork_rows}
    print(f"\nforks: {total['recovered']}/{total['forks']} recovered, {total['not_recoverable']} not recoverable with "
          f"their reason, {total['unexplained']} unexplained, {total['errors']} errors")
    return total


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cab-suite-check", description=__doc__)
    ap.add_argument("--tasks", default="all", help="comma-separated task names (default: every installed task)")
    ap.add_argument("--seeds", default=None, help="comma-separated seeds (default: each task's catalog seed)")
    ap.add_argument("--seed-set", default=None, metavar="NAME",
                    help="each task's own named seed set instead (e.g. heldout: the seeds its suite validated)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel attempts (default: cores)")
    ap.add_argument("--out", default=None, help="records folder (default: outputs/suite-check/<time>)")
    ap.add_argument("--no-idle", action="store_true", help="run only the oracles")
    ap.add_argument("--sim", default=None,
                    help="comma-separated simulators (default: the default configuration's); several add a "
                         "cross-simulator table")
    ap.add_argument("--planner", default=None, metavar="NAME",
                    help="every attempt with this motion planner (default: the default configuration's)")
    ap.add_argument("--cold", action="store_true",
                    help="a fresh process per attempt and no cache folder (start-up as before warm workers)")
    ap.add_argument("--perturb", type=int, default=0, metavar="N",
                    help="run each oracle N times under small perturbations (perturb.seed 1..N: objects moved "
                         "<= 1 mm and turned <= 0.5 deg, physical parameters +-2 %%); success: every oracle "
                         f"succeeds in at least {PERTURBED_SUCCESS_MIN * 100:.0f} %% of its runs on each simulator")
    ap.add_argument("--randomize", default=None, metavar="OPTION",
                    help="every attempt under this appearance randomisation (none, lighting, textures, camera, "
                         "distractors, all: cab_core.attempt.variation.randomize), drawn from each attempt's seed")
    ap.add_argument("--forks", action="store_true",
                    help="then fork each oracle attempt at every charged call (0..N) and let the oracle finish "
                         "from there; success: every fork succeeds or reports why the state is not recoverable")
    ap.add_argument("--fork-from", action="append", default=[], metavar="DIR",
                    help="with --forks: also fork every attempt found under DIR (e.g. recorded agent attempts)")
    ap.add_argument("--compare", action="store_true",
                    help="run the check twice, --cold then warm, and print both wall times and the speed-up")
    return ap


def _usage_error(message: str) -> NoReturn:
    """A mistake on the command line: one line, exit status 2."""
    print(f"cab-suite-check: {message}", file=sys.stderr)
    sys.exit(2)


def _selection(a: argparse.Namespace) -> tuple[list[str], list[str], list[int] | dict[str, tuple[int, ...]] | None]:
    """The simulators, tasks and seeds the command line selects, checked against what is installed."""
    if a.randomize is not None:
        try:
            composed([f"randomize={a.randomize}"])
        except Exception:
            _usage_error(f"unknown --randomize option {a.randomize!r}")
    if a.planner is not None and a.planner not in registry("planners"):
        _usage_error(f"unknown planner {a.planner!r}; installed: {', '.join(registry('planners'))}")
    if a.sim is None:
        a.sim = default_selection(("sim",))["sim"]
    sims = [s.strip() for s in a.sim.split(",") if s.strip()]
    known = registry("simulators")
    missing = [s for s in sims if s not in known]
    if not sims or missing:
        _usage_error(f"unknown simulator(s) {missing or sims}; installed: {', '.join(known)}")
    installed = all_tasks()
    tasks = list(installed) if a.tasks == "all" else [t.strip() for t in a.tasks.split(",") if t.strip()]
    unknown = [t for t in tasks if t not in installed]
    if unknown:
        _usage_error(f"unknown task(s) {unknown}; installed: {', '.join(installed)}")
    if a.seeds is not None and a.seed_set is not None:
        _usage_error("give --seeds or --seed-set, not both")
    seeds: list[int] | dict[str, tuple[int, ...]] | None = None
    if a.seeds is not None:
        seeds = [int(s) for s in a.seeds.split(",")]
    elif a.seed_set is not None:
        try:
            seeds = {t: installed[t].seeds(a.seed_set) for t in tasks}
        except ConfigError as e:
            _usage_error(str(e))
    return sims, tasks, seeds


def _print_verdict(v: dict, elapsed_s: float, a: argparse.Namespace) -> None:
    print(f"\noracle: {v['oracle_success_within_budget']}/{v['oracle_attempts']} successes within budgets; "
          f"idle: {v['idle_success']}/{v['idle_attempts']} successes, {v['idle_subgoal_at_start']} with a subgoal "
          f"satisfied at the start; checkpoints attained by the oracles: subgoals {v['subgoals_attained']}/"
          f"{v['subgoals_total']}, spatial {v['spatial_attained']}/{v['spatial_total']}; borderline oracle "
          f"verdicts {v['oracle_borderline']} (smallest margin "
          f"{'-' if v['oracle_min_margin'] is None else format(v['oracle_min_margin'], '.0%')}); "
          f"{elapsed_s:.0f} s with {a.jobs} worker(s)" + (" (cold)" if a.cold else ""))


def _passed(v: dict, robust: dict | None, forks: dict | None) -> bool:
    """Whether the check passed: every fork explained, or each perturbed oracle's rate, or every oracle
    within its budgets and no idle success."""
    if forks is not None:
        return forks["unexplained"] == 0 and forks["errors"] == 0 and forks["fresh_equal"]
    if robust is not None:  # perturbed: a rate per task and simulator, not every run
        return all(c["rate"] >= PERTURBED_SUCCESS_MIN for cells in robust.values() for c in cells.values())
    return (v["oracle_success_within_budget"] == v["oracle_attempts"] and v["idle_success"] == 0
            and v["idle_subgoal_at_start"] == 0)


def main() -> None:
    a = _parser().parse_args()
    sims, tasks, seeds = _selection(a)
    out = Path(a.out) if a.out else Path("outputs") / "suite-check" / time.strftime("%Y-%m-%d_%H-%M-%S")
    out.mkdir(parents=True, exist_ok=True)
    if a.perturb < 0:
        _usage_error("--perturb must be >= 0")
    agents = ("oracle",) if a.no_idle or a.perturb or a.forks else ("oracle", "idle")
    timings = {}
    if a.compare:
        t0 = time.monotonic()
        cold_rows = run_batch(tasks, seeds, max(1, a.jobs), out / "cold", agents, tuple(sims), cold=True,
                              planner=a.planner)
        timings["cold_s"] = round(time.monotonic() - t0, 1)
        print(f"cold (a fresh process per attempt, no BRDF cache): {timings['cold_s']:.0f} s; "
              f"verdict {verdict(cold_rows)}", file=sys.stderr, flush=True)
    t0 = time.monotonic()
    rows = run_batch(tasks, seeds, max(1, a.jobs), out / "warm" if a.compare else out, agents, tuple(sims),
                     cold=a.cold, perturb=a.perturb, randomize=a.randomize, planner=a.planner)
    timings["cold_s" if a.cold else "warm_s"] = round(time.monotonic() - t0, 1)
    print_table(rows)
    table = cross_sim(rows)
    if len(sims) > 1:
        print()
        print_cross_sim(table, sims)
    v = verdict(rows)
    robust = robustness(rows) if a.perturb else None
    if robust is not None:
        print(f"\noracle successes within budgets under perturbation ({a.perturb} noise seeds per instance):")
        print_robustness(robust, sims)
    _print_verdict(v, time.monotonic() - t0, a)
    if a.compare:
        timings["speedup"] = round(timings["cold_s"] / max(timings["warm_s"], 1e-9), 2)
        print(f"start-up compared on the same {len(rows)} attempts with {a.jobs} worker(s): cold "
              f"{timings['cold_s']:.0f} s, warm {timings['warm_s']:.0f} s: {timings['speedup']:.2f}x")
    (out / "summary.json").write_text(json.dumps({"sims": sims, "rows": rows, "verdict": v, "cross_sim": table,
                                                  "timings": timings, "perturb": a.perturb,
                                                  "robustness": robust,
                                                  "verdict_by_sim": {s: verdict([r for r in rows if r["sim"] == s])
                                                                     for s in sims}}, indent=2))
    forks = None
    if a.forks:
        forks = fork_check(rows, [Path(d) for d in a.fork_from], out / "forks", max(1, a.jobs), a.planner)
        (out / "summary.json").write_text(json.dumps({**json.loads((out / "summary.json").read_text()),
                                                      "forks": forks}, indent=2))
    print(f"records and summary.json in {out}")
    sys.exit(0 if _passed(v, robust, forks) else 1)
