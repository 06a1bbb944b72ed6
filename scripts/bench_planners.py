"""Compare installed motion planners (issue 30): planning speed on the same requests, and every
task's oracle attempt under each planner.

    python scripts/bench_planners.py speed   [--planners mplib,pin] [--n 200]
    python scripts/bench_planners.py oracles [--planners mplib,pin] [--sim mujoco] [--tasks a,b] [--out DIR]

``speed``: on the default embodiment, the same seeded requests for every planner: ``ik`` (targets
0.5-15 cm from random start configurations, as the tools' moves are), a reachability check
(``ik`` from home of a random target in the workspace, reachable or not) and a joint path
(``plan_to_pose`` to a reachable target); p50 and p90 wall milliseconds of each, and how many
succeeded. ``oracles``: ``cab task=T seed=<catalog seed> model=oracle sim=S planner=P`` per task, one
after another; per task and planner: success, tool calls and simulated seconds (from result.json).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _planner(name: str, spec, dt: float):
    from cab_core.plugins import registry

    p = registry("planners")[name]({})
    p.setup(spec, dt)
    return p


def _requests(spec, planner, n: int, seed: int = 0) -> dict[str, list]:
    """Seeded requests built with ``planner``'s FK (all planners share the URDF)."""
    rng = np.random.default_rng(seed)
    out: dict[str, list] = {"ik": [], "reach": [], "path": []}
    arms = sorted(spec.arms)
    for k in range(n):
        arm = arms[k % len(arms)]
        home = np.array(spec.arms[arm].home_qpos, float)
        q = home + rng.normal(0, 0.25, size=len(home))
        tcp = planner.fk(arm, q)
        step = rng.normal(size=3)
        target = tcp.copy()
        target[:3] += step / np.linalg.norm(step) * rng.uniform(0.005, 0.15)
        out["ik"].append((arm, target, q))
        reach = planner.fk(arm, home).copy()
        reach[:3] += rng.uniform([-0.35, -0.35, -0.3], [0.35, 0.35, 0.15])
        out["reach"].append((arm, reach, home))
        out["path"].append((arm, target, home))
    return out


def speed(names: list[str], n: int) -> dict:
    import cab_core  # noqa: F401  (pins the numerics first)
    from cab_core.plugins import registry

    spec = registry("embodiments")["aloha_agilex"]({})
    planners = {name: _planner(name, spec, 1.0 / 250.0) for name in names}
    reqs = _requests(spec, planners[names[0]], n)
    table: dict = {}
    for name, p in planners.items():
        row = {}
        for kind, items in reqs.items():
            ms, ok = [], 0
            for arm, target, q in items:
                t0 = time.perf_counter()
                if kind == "path":
                    r = p.plan_to_pose(arm, q, target)
                    good = r.ok
                else:
                    good = p.ik(arm, target, q).ok
                ms.append((time.perf_counter() - t0) * 1e3)
                ok += bool(good)
            row[kind] = {"p50_ms": round(float(np.percentile(ms, 50)), 2),
                         "p90_ms": round(float(np.percentile(ms, 90)), 2), "ok": ok, "n": len(items)}
        table[name] = {"versions": p.versions(), **row}
    return table


def oracles(names: list[str], sim: str, tasks: list[str] | None, out: Path) -> dict:
    from cab_core.plugins import task_info, task_names

    table: dict = {}
    for task in tasks or task_names():
        seed = task_info(task).seed
        for name in names:
            run = out / name / task
            t0 = time.monotonic()
            subprocess.run(["cab", f"task={task}", f"seed={seed}", "model=oracle", f"sim={sim}",
                            f"planner={name}", "record.video=false", f"hydra.run.dir={run}"],
                           capture_output=True, text=True)
            wall = round(time.monotonic() - t0, 1)
            try:
                res = json.loads((run / "result.json").read_text())
            except (OSError, ValueError):
                table.setdefault(task, {})[name] = {"success": False, "error": "no result.json", "wall_s": wall}
                continue
            b = res["budget"]
            table.setdefault(task, {})[name] = {
                "success": bool(res["verdict"]["success"]), "calls": b["tool_calls_used"],
                "sim_s": round(b["sim_seconds_used"], 2), "wall_s": wall}
            print(task, seed, name, table[task][name], file=sys.stderr, flush=True)
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mode", choices=("speed", "oracles"))
    ap.add_argument("--planners", default="mplib,pin")
    ap.add_argument("--n", type=int, default=200, help="speed: requests of each kind")
    ap.add_argument("--sim", default="mujoco")
    ap.add_argument("--tasks", default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    names = [s for s in a.planners.split(",") if s]
    if a.mode == "speed":
        result = speed(names, a.n)
    else:
        out = Path(a.out or f"outputs/bench-planners/{time.strftime('%Y-%m-%d_%H-%M-%S')}")
        result = oracles(names, a.sim, a.tasks.split(",") if a.tasks else None, out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
