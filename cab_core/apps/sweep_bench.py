"""``cab-bench-sweep``: attempts per hour of a real sweep with 1 worker and with N workers.

Runs the same sweep (``cab -m``, the default launcher) once per agent, worker count and mode into
fresh sweep directories under ``--out``, checks that every attempt completed, and prints attempts per
hour, the speed-up over one worker, the CPU the sweep's processes used and their memory (PSS) per
attempt in flight.

``--fake-model-latency S``: the agent is a model (``model=qwen_local``) served by a scripted
OpenAI-compatible server in this process (cab_core.testing.fake_openai: real HTTP, 16 turns, 15
charged calls, each answer after S seconds), so the sweep is model-bound as a real one is; the
worker counts are attempts in flight, and the projected wall time of ``experiment=paper`` (675
attempts) follows for N = 1, 8, 32, 64 and for the default N on this machine, at the paper's mean
attempt length (23.3 min) and Astra's median (477 s), bounded by the CPU the benchmark measured per
attempt. Modes: ``warm`` (the default: warm workers, renderer
tables from the cache folder) and ``cold`` (a fresh process per attempt, no cache folder: start-up as it was
before both). The machine's load average is printed beside the figures: other processes on the same
cores change them.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

from cab_core.config import composed, default_selection
from cab_core.sweep.manifest import completed_results

PAPER_ATTEMPTS = 675
PAPER_MEAN_S = 23.3 * 60  # the paper's mean attempt length
ASTRA_MEDIAN_S = 477.0  # Astra's median attempt length
PROJECTED_N = (1, 8, 32, 64)


def _sample_tree(pid: int, every_s: float, peak: list[float], cpu: dict[int, float], stop: threading.Event) -> None:
    """The largest PSS of the sweep's process tree, and the CPU seconds of each of its processes as
    last seen, sampled every ``every_s`` until ``stop``. The attempt processes a fork server forked
    are not children of ``cab -m`` (whose reaped children the kernel accounts): they are counted
    here, from the tree, a process's last ``every_s`` before it ends excepted."""
    from cab_core.sweep.memory import cpu_seconds, descendants, pss_mb

    while not stop.wait(every_s):
        procs = descendants(pid)
        peak[0] = max(peak[0], sum(pss_mb(p) for p in procs))
        for p in procs:
            cpu[p] = max(cpu.get(p, 0.0), cpu_seconds(p))


def run_sweep(out: Path, workers: int, task: str, model: str, attempts: int, video: bool, rnd: int = 1,
              threads: str = "1", sim: str | None = None, mode: str = "warm", extra: tuple[str, ...] = ()) -> dict:
    """One timed sweep; returns its figures."""
    if sim is None:
        sim = default_selection(("sim",))["sim"]
    sweep_dir = out / f"round-{rnd}" / f"{model}-{mode}-workers-{workers}"
    cab = os.path.join(os.path.dirname(sys.executable), "cab")
    cmd = [cab, "-m", f"task={task}", f"model={model}", f"sim={sim}",
           f"attempt={','.join(str(a) for a in range(1, attempts + 1))}",
           f"record.video={str(video).lower()}", f"hydra.sweep.dir={sweep_dir}", f"hydra.launcher.n_jobs={workers}",
           f"sweep.threads_per_attempt={threads}", *extra]
    if mode == "cold":
        cmd.append("sweep.warm_workers=false")
        if "brdf_cache" in composed([f"sim={sim}"]).sim:  # a simulator that caches its BRDF table: off
            cmd.append("sim.brdf_cache=false")
    load0 = os.getloadavg()[0]
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    log = out / f"round-{rnd}-{model}-{mode}-workers-{workers}.log"
    with open(log, "w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, cwd=out)
        peak, tree_cpu, stop = [0.0], dict[int, float](), threading.Event()
        sampler = threading.Thread(target=_sample_tree, args=(proc.pid, 2.0, peak, tree_cpu, stop), daemon=True)
        sampler.start()
        proc.wait()
        stop.set()
        sampler.join()
    wall = time.monotonic() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    reaped = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)  # cab -m and what it reaped
    cpu_s = max(reaped, sum(tree_cpu.values()))  # the tree as sampled: forked attempt processes too
    if proc.returncode != 0:
        raise RuntimeError(f"sweep with {workers} worker(s) failed ({proc.returncode}):\n{log.read_text()[-3000:]}")
    results = [json.loads(p.read_text()) for p in completed_results(sweep_dir)]
    if len(results) != attempts:
        raise RuntimeError(f"{len(results)} of {attempts} attempts completed in {sweep_dir}")
    return {"round": rnd, "model": model, "mode": mode, "workers": workers, "attempts": attempts,
            "wall_s": round(wall, 1),
            "attempts_per_hour": round(3600 * attempts / wall, 1),
            "successes": sum(bool(r["verdict"]["success"]) for r in results),
            "mean_attempt_wall_s": round(sum(r["timing"]["wall_seconds"] for r in results) / attempts, 2),
            "cpu_s_per_attempt": round(cpu_s / attempts, 2),
            "cpu_utilisation": round(cpu_s / (wall * (os.cpu_count() or 1)), 3),
            "pss_mb_per_slot": round(peak[0] / min(workers, attempts), 1),
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
    ap.add_argument("--fake-model-latency", type=float, default=None, metavar="S",
                    help="the agent: a scripted OpenAI-compatible model answering each turn after S seconds "
                         "(model=qwen_local; 16 turns, 15 charged calls); worker counts are attempts in flight, "
                         "and the projected wall time of experiment=paper is printed")
    ap.add_argument("--override", action="append", default=[], metavar="KEY=VALUE",
                    help="a further override of every sweep (repeatable), e.g. sweep.cpu_slots=false")
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
    extra: tuple[str, ...] = ()
    server = None
    if a.fake_model_latency is not None:
        from cab_core.testing.fake_openai import MODEL_ID, FakeOpenAIServer

        if a.fake_model_latency < 0:
            print("cab-bench-sweep: --fake-model-latency must be >= 0 seconds", file=sys.stderr)
            sys.exit(2)
        server = FakeOpenAIServer(a.fake_model_latency).__enter__()
        models = ["qwen_local"]
        extra = (f"model.base_url={server.base_url}", f"model.model_id={MODEL_ID}")
    extra = (*extra, *a.override)
    server_cpu0 = time.process_time()
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
                                              a.sim, mode, extra))
                    except RuntimeError as e:
                        print(f"cab-bench-sweep: {e}", file=sys.stderr)
                        sys.exit(1)
    groups = [(m, mode) for m in models for mode in modes]
    rate = {(m, mode, w): 3600 * sum(r["attempts"] for r in rows if (r["model"], r["mode"], r["workers"]) == (m, mode, w))
            / sum(r["wall_s"] for r in rows if (r["model"], r["mode"], r["workers"]) == (m, mode, w))
            for m, mode in groups for w in counts}
    if server is not None:
        server.__exit__(None, None, None)
    print("| round | model | mode | workers | attempts | wall s | attempts/h | successes | mean attempt s | "
          "CPU s/attempt | CPU used | PSS MiB/slot | load avg (start, end) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['round']} | {r['model']} | {r['mode']} | {r['workers']} | {r['attempts']} | {r['wall_s']} | "
              f"{r['attempts_per_hour']} | {r['successes']}/{r['attempts']} | {r['mean_attempt_wall_s']} | "
              f"{r['cpu_s_per_attempt']} | {100 * r['cpu_utilisation']:.0f}% | {r['pss_mb_per_slot']} | "
              f"{r['load_avg_1min']} |")
    for m, mode in groups:
        base = rate[(m, mode, counts[0])]
        for w in counts:
            print(f"{m} ({mode}), {w} worker(s): {rate[(m, mode, w)]:.1f} attempts/h over all rounds, "
                  f"speed-up {rate[(m, mode, w)] / base:.2f}x")
    print(f"cpu cores: {os.cpu_count()}; task {a.task} on {a.sim}, video {'on' if a.video else 'off'}, "
          f"threads per attempt {a.threads}")
    projection = None
    if server is not None:
        print(f"fake model: {a.fake_model_latency} s per turn, {server.requests} requests, at most "
              f"{server.max_in_flight} waiting at once, {time.process_time() - server_cpu0:.1f} CPU s in this process")
        cpu_per_attempt = sum(r["cpu_s_per_attempt"] * r["attempts"] for r in rows) / sum(r["attempts"] for r in rows)
        default_n = paper_in_flight()
        projection = project(cpu_per_attempt, os.cpu_count() or 1, default_n)
        print(f"experiment=paper ({PAPER_ATTEMPTS} attempts), projected wall time, bounded by "
              f"{cpu_per_attempt:.1f} CPU s per attempt on {os.cpu_count()} cores:")
        print("| attempts in flight | at 23.3 min per attempt (paper's mean) | at 477 s (Astra's median) |")
        print("|---|---|---|")
        for p in projection:
            print(f"| {p['n']}{' (default here)' if p['default'] else ''} | {p['hours_paper_mean']:.1f} h | "
                  f"{p['hours_astra_median']:.1f} h |")
    if a.json:
        Path(a.json).write_text(json.dumps({"cpu_count": os.cpu_count(), "task": a.task, "sim": a.sim,
                                            "models": models, "modes": modes,
                                            "video": a.video, "threads_per_attempt": a.threads, "rows": rows,
                                            "attempts_per_hour": {f"{m}/{mode}/{w}": round(v, 1)
                                                                  for (m, mode, w), v in rate.items()},
                                            "fake_model_latency_s": a.fake_model_latency,
                                            "paper_projection": projection},
                                           indent=2))


def paper_in_flight() -> int:
    """The attempts ``experiment=paper`` keeps in flight on this machine by default (the launcher's n_jobs)."""
    from hydra import compose, initialize_config_module

    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=["experiment=paper"], return_hydra_config=True)
    return int(cfg.hydra.launcher.n_jobs)


def project(cpu_s_per_attempt: float, cores: int, default_n: int) -> list[dict]:
    """Hours for ``experiment=paper`` at N attempts in flight: the attempts' length over N, or the CPU
    they need over the cores, whichever is longer."""
    out = []
    for n in sorted({*PROJECTED_N, default_n}):
        hours = {key: PAPER_ATTEMPTS * max(length / n, cpu_s_per_attempt / cores) / 3600
                 for key, length in (("hours_paper_mean", PAPER_MEAN_S), ("hours_astra_median", ASTRA_MEDIAN_S))}
        out.append({"n": n, "default": n == default_n, **{k: round(v, 2) for k, v in hours.items()}})
    return out


if __name__ == "__main__":
    main()
