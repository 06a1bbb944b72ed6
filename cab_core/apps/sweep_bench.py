"""``cab-bench-sweep``: attempts per hour of a real sweep with 1 worker and with N workers.

Runs the same sweep (``cab -m``, the joblib launcher) once per agent, worker count and mode into
fresh sweep directories under ``--out``, checks that every attempt completed, and prints attempts per
hour and the speed-up over one worker. Modes: ``warm`` (the default: warm workers, renderer
tables from the cache folder) and ``cold`` (a fresh process per attempt, no cache folder: start-up as it was
before both). The machine's load average is printed beside the figures: other processes on the same
cores change them.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from cab_core.config import composed, default_selection
from cab_core.sweep.manifest import completed_results


def run_sweep(out: Path, workers: int, task: str, model: str, attempts: int, video: bool, rnd: int = 1,
              threads: str = "1", sim: str | None = None, mode: str = "warm") -> dict:
    """One timed sweep; returns its figures."""
    if sim is None:
        sim = default_selection(("sim",))["sim"]
    sweep_dir = out / f"round-{rnd}" / f"{model}-{mode}-workers-{workers}"
    cab = os.path.join(os.path.dirname(sys.executable), "cab")
    cmd = [cab, "-m", f"task={task}", f"model={model}", f"sim={sim}",
           f"attempt={','.join(str(a) for a in range(1, attempts + 1))}",
           f"record.video={str(video).lower()}", f"hydra.sweep.dir={sweep_dir}", f"hydra.launcher.n_jobs={workers}",
           f"sweep.threads_per_attempt={threads}"]
    if mode == "cold":
        cmd.append("sweep.warm_workers=false")
        if "brdf_cache" in composed([f"sim={sim}"]).sim:  # a simulator that caches its BRDF table: off
            cmd.append("sim.brdf_cache=false")
    load0 = os.getloadavg()[0]
    t0 = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=out)
    wall = time.monotonic() - t0
    if r.returncode != 0:
        raise RuntimeError(f"sweep with {workers} worker(s) failed ({r.returncode}):\n{r.stderr[-3000:]}")
    results = [json.loads(p.read_text()) for p in completed_results(sweep_dir)]
    if len(results) != attempts:
        raise RuntimeError(f"{len(results)} of {attempts} attempts completed in {sweep_dir}")
    return {"round": rnd, "model": model, "mode": mode, "workers": workers, "attempts": attempts,
            "wall_s": round(wall, 1),
            "attempts_per_hour": round(3600 * attempts / wall, 1),
            "successes": sum(bool(r["verdict"]["success"]) for r in results),
            "mean_attempt_wall_s": round(sum(r["timing"]["wall_seconds"] for r in results) / attempts, 2),
            "load_avg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)]}


def main() -> None:
    ap = argparse.ArgumentParser(prog="cab-bench-sweep",
                                 description="Attempts per hour of a real sweep with 1 worker and with N workers.")
    ap.add_argument("--out", required=True, help="directory for the sweeps (must not exist or be empty)")
    ap.add_argument("--task", default=None, help="task (default: the default configuration's)")
    ap.add_argument("--model", default="idle,oracle", help="comma-separated agents (default: idle,oracle)")
    ap.add_argument("--sim", default=None, help="simulator (default: the default configuration's)")
    ap.add_argument("--modes", default="warm", help="comma-separated: warm (default), cold (see above)")
    ap.add_argument("--attempts", type=int, default=6, help="attempts per sweep (same task, attempt=1..N)")
    ap.add_argument("--workers", default="1,2", help="comma-separated worker counts; the first is the baseline")
    ap.add_argument("--video", action="store_true", help="record the head-view video (off by default)")
    ap.add_argument("--threads", default="1", help="sweep.threads_per_attempt (a number, or null: unlimited)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="repeat, alternating the order of worker counts, so that all see the same background load")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    a = ap.parse_args()
    if a.sim is None or a.task is None:
        chosen = default_selection(("sim", "task"))
        a.sim, a.task = a.sim or chosen["sim"], a.task or chosen["task"]
    out = Path(a.out)
    if out.exists() and any(out.iterdir()):
        print(f"cab-bench-sweep: {out} is not empty", file=sys.stderr)
        sys.exit(2)
    out.mkdir(parents=True, exist_ok=True)
    counts = [int(x) for x in a.workers.split(",")]
    models = [m.strip() for m in a.model.split(",") if m.strip()]
    modes = [m.strip() for m in a.modes.split(",") if m.strip()]
    if not set(modes) <= {"warm", "cold"}:
        print(f"cab-bench-sweep: unknown mode(s) in {a.modes!r}; modes are warm, cold", file=sys.stderr)
        sys.exit(2)
    rows = []
    for rnd in range(1, a.rounds + 1):
        for model in models:
            for mode in modes:
                for w in (counts if rnd % 2 else counts[::-1]):
                    print(f"cab-bench-sweep: round {rnd}: {a.attempts} x {a.task}/{model} on {a.sim} ({mode}) "
                          f"with {w} worker(s)...", file=sys.stderr, flush=True)
                    try:
                        rows.append(run_sweep(out.resolve(), w, a.task, model, a.attempts, a.video, rnd, a.threads,
                                              a.sim, mode))
                    except RuntimeError as e:
                        print(f"cab-bench-sweep: {e}", file=sys.stderr)
                        sys.exit(1)
    groups = [(m, mode) for m in models for mode in modes]
    rate = {(m, mode, w): 3600 * sum(r["attempts"] for r in rows if (r["model"], r["mode"], r["workers"]) == (m, mode, w))
            / sum(r["wall_s"] for r in rows if (r["model"], r["mode"], r["workers"]) == (m, mode, w))
            for m, mode in groups for w in counts}
    print("| round | model | mode | workers | attempts | wall s | attempts/h | successes | mean attempt s | "
          "load avg (start, end) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['round']} | {r['model']} | {r['mode']} | {r['workers']} | {r['attempts']} | {r['wall_s']} | "
              f"{r['attempts_per_hour']} | {r['successes']}/{r['attempts']} | {r['mean_attempt_wall_s']} | "
              f"{r['load_avg_1min']} |")
    for m, mode in groups:
        base = rate[(m, mode, counts[0])]
        for w in counts:
            print(f"{m} ({mode}), {w} worker(s): {rate[(m, mode, w)]:.1f} attempts/h over all rounds, "
                  f"speed-up {rate[(m, mode, w)] / base:.2f}x")
    print(f"cpu cores: {os.cpu_count()}; task {a.task} on {a.sim}, video {'on' if a.video else 'off'}, "
          f"threads per attempt {a.threads}")
    if a.json:
        Path(a.json).write_text(json.dumps({"cpu_count": os.cpu_count(), "task": a.task, "sim": a.sim,
                                            "models": models, "modes": modes,
                                            "video": a.video, "threads_per_attempt": a.threads, "rows": rows,
                                            "attempts_per_hour": {f"{m}/{mode}/{w}": round(v, 1)
                                                                  for (m, mode, w), v in rate.items()}},
                                           indent=2))


if __name__ == "__main__":
    main()
