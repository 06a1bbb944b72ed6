"""``cab-suite-check``: run every task's reference solution (and the idle agent) in parallel over
the cores and print, per task: success, calls and simulated seconds used against the budgets, the
paper's reference-solution figures beside them, and the checkpoints attained. The idle agent must
fail every task, with no subgoal satisfied at the start. ``--sim a,b`` runs the same attempts on
several simulators and adds a cross-simulator table (per task and simulator: success, calls,
simulated seconds, wall seconds of the oracle)."""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path


def sim_config(sim: str) -> dict:
    """The simulator's options as ``cab +sim=<sim>`` gets them: its file in the ``sim`` config
    group (physical parameters declared per simulator live there), else just the name."""
    from importlib.resources import files

    from omegaconf import OmegaConf

    path = files("cab_core") / "conf" / "sim" / f"{sim}.yaml"
    if not path.is_file():
        return {"name": sim}
    return {**OmegaConf.to_container(OmegaConf.load(str(path)), resolve=True), "name": sim}


def run_one(task: str, seed: int, agent: str, out: str, sim: str = "sapien") -> dict:
    """One attempt in this (worker) process; returns a compact summary."""
    from .catalog import task_info
    from .episode import AttemptSpec
    from .runner import run_attempt

    info = task_info(task)
    spec = AttemptSpec(task=task, seed=seed, attempt=1, sim=sim, embodiment="aloha_agilex", planner="mplib",
                       harness="direct", model=agent, output_dir=Path(out), budget_tool_calls=info.budget_tool_calls,
                       budget_sim_seconds=info.budget_sim_s, budget_wall_seconds=info.budget_wall_s,
                       sim_cfg=sim_config(sim), model_cfg={"name": agent, "agent": agent})
    t0 = time.monotonic()
    try:
        r = run_attempt(spec)
    except Exception as e:  # report, never stop the whole check
        return {"task": task, "seed": seed, "agent": agent, "error": repr(e), "wall_s": time.monotonic() - t0}
    ck = r.get("checkpoints") or {}
    return {
        "task": task, "seed": seed, "agent": agent, "sim": sim, "dir": out,
        "success": bool(r["verdict"].get("success")), "termination": r["termination"]["reason"],
        "calls": r["budget"]["tool_calls_used"], "calls_limit": r["budget"]["tool_calls_limit"],
        "sim_s": r["budget"]["sim_seconds_used"], "sim_s_limit": r["budget"]["sim_seconds_limit"],
        "ref_calls": info.reference_solution_api_calls, "ref_sim_s": info.reference_solution_sim_s,
        "subgoals": [s["attained"] for s in ck.get("subgoals", [])],
        "spatial": [s["attained"] for s in ck.get("spatial", [])],
        "subgoals_at_start": ck.get("subgoals_at_start", []),
        "checkpoint_error": ck.get("error"),
        "wall_s": round(time.monotonic() - t0, 1),
    }


def check(tasks: list[str], seeds: list[int] | None, jobs: int, out: Path, agents=("oracle", "idle"),
          sims: tuple[str, ...] = ("sapien",)) -> list[dict]:
    from .catalog import task_info

    jobs_list = []
    for t in tasks:
        for s in (seeds if seeds is not None else [task_info(t).seed]):
            for sim in sims:
                for a in agents:
                    jobs_list.append((t, s, a, str(out / sim / t / f"seed-{s}" / a), sim))
    rows: list[dict] = []
    ctx = mp.get_context("spawn")  # a fresh interpreter per worker: no simulator state is forked
    with cf.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as ex:
        futs = {ex.submit(run_one, *j): j for j in jobs_list}
        for f in cf.as_completed(futs):
            row = f.result()
            rows.append(row)
            print(f"  done {row['task']} seed={row['seed']} {row['agent']} on {row['sim']}: "
                  f"{'error ' + row['error'] if 'error' in row else ('success' if row['success'] else 'fail')}",
                  file=sys.stderr, flush=True)
    order = {(t, s, a, sim): i for i, (t, s, a, _, sim) in enumerate(jobs_list)}
    rows.sort(key=lambda r: order[(r["task"], r["seed"], r["agent"], r["sim"])])
    return rows


def verdict(rows: list[dict]) -> dict:
    o = [r for r in rows if r["agent"] == "oracle"]
    i = [r for r in rows if r["agent"] == "idle"]
    within = lambda r: "error" not in r and r["success"] and r["calls"] <= r["calls_limit"] and r["sim_s"] <= r["sim_s_limit"]
    sub = [x for r in o if "error" not in r for x in r["subgoals"]]
    spa = [x for r in o if "error" not in r for x in r["spatial"]]
    return {
        "oracle_success_within_budget": sum(map(within, o)), "oracle_attempts": len(o),
        "idle_success": sum(1 for r in i if r.get("success")), "idle_attempts": len(i),
        "idle_subgoal_at_start": sum(1 for r in i if any(r.get("subgoals_at_start") or [])),
        "subgoals_attained": sum(sub), "subgoals_total": len(sub),
        "spatial_attained": sum(spa), "spatial_total": len(spa),
    }


def print_table(rows: list[dict]) -> None:
    hdr = f"{'task':<26}{'seed':>5} {'sim':<9}{'agent':<7}{'result':<9}{'calls':>10}{'ref':>5}{'sim s':>15}{'ref':>7}{'subgoals':>10}{'spatial':>9}{'wall s':>8}"
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
              f"{sum(sg):>6}/{len(sg):<3}{sum(sp):>5}/{len(sp):<3}{r['wall_s']:>8.1f}")


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


def main() -> None:
    from .plugins import all_tasks

    ap = argparse.ArgumentParser(prog="cab-suite-check", description=__doc__)
    ap.add_argument("--tasks", default="all", help="comma-separated task names (default: every installed task)")
    ap.add_argument("--seeds", default=None, help="comma-separated seeds (default: each task's catalog seed)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel attempts (default: cores)")
    ap.add_argument("--out", default=None, help="records folder (default: outputs/suite-check/<time>)")
    ap.add_argument("--no-idle", action="store_true", help="run only the oracles")
    ap.add_argument("--sim", default="sapien",
                    help="comma-separated simulators (default: sapien); several add a cross-simulator table")
    a = ap.parse_args()
    sims = [s.strip() for s in a.sim.split(",") if s.strip()]
    from .plugins import registry

    known = registry("simulators")
    missing = [s for s in sims if s not in known]
    if not sims or missing:
        print(f"cab-suite-check: unknown simulator(s) {missing or sims}; installed: {', '.join(known)}", file=sys.stderr)
        sys.exit(2)
    installed = list(all_tasks())
    tasks = installed if a.tasks == "all" else [t.strip() for t in a.tasks.split(",") if t.strip()]
    unknown = [t for t in tasks if t not in installed]
    if unknown:
        print(f"cab-suite-check: unknown task(s) {unknown}; installed: {', '.join(installed)}", file=sys.stderr)
        sys.exit(2)
    seeds = None if a.seeds is None else [int(s) for s in a.seeds.split(",")]
    out = Path(a.out) if a.out else Path("outputs") / "suite-check" / time.strftime("%Y-%m-%d_%H-%M-%S")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    rows = check(tasks, seeds, max(1, a.jobs), out, ("oracle",) if a.no_idle else ("oracle", "idle"), tuple(sims))
    print_table(rows)
    table = cross_sim(rows)
    if len(sims) > 1:
        print()
        print_cross_sim(table, sims)
    v = verdict(rows)
    print(f"\noracle: {v['oracle_success_within_budget']}/{v['oracle_attempts']} successes within budgets; "
          f"idle: {v['idle_success']}/{v['idle_attempts']} successes, {v['idle_subgoal_at_start']} with a subgoal "
          f"satisfied at the start; checkpoints attained by the oracles: subgoals {v['subgoals_attained']}/"
          f"{v['subgoals_total']}, spatial {v['spatial_attained']}/{v['spatial_total']}; "
          f"{time.monotonic() - t0:.0f} s with {a.jobs} worker(s)")
    (out / "summary.json").write_text(json.dumps({"sims": sims, "rows": rows, "verdict": v, "cross_sim": table,
                                                  "verdict_by_sim": {s: verdict([r for r in rows if r["sim"] == s])
                                                                     for s in sims}}, indent=2))
    print(f"records and summary.json in {out}")
    ok = (v["oracle_success_within_budget"] == v["oracle_attempts"] and v["idle_success"] == 0
          and v["idle_subgoal_at_start"] == 0)
    sys.exit(0 if ok else 1)
