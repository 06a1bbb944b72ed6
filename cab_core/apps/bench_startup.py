"""``cab-bench --startup``: how long an attempt takes to start, per simulator, three ways.

- **cold process**: a fresh process and an empty cache folder (``CAB_CACHE_DIR``: generated assets,
  a renderer's tables, Mesa's shader cache), as on a new machine or after a cache wipe;
- **warm cache**: a fresh process (as ``cab`` runs one attempt) with the cache folder filled;
- **warm worker**: the next attempt in a sweep's warm worker (``sweep.warm_workers``), which keeps its
  renderer and imports from earlier attempts.

Each figure is the idle agent's attempt on one task: ``setup_seconds`` (building the world, the
robot, the renderer, up to the first call: ``result.json`` ``timing``) and, for the fresh
processes, the process's whole wall time (interpreter, imports and writing the records included).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cab_core.sweep.supervisor import AttemptSupervisor, SupervisorConfig, attempt_configs, close_workers


def _fresh_process(config: dict, out: Path, cache: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "MESA_SHADER_CACHE_DIR"}
    env["CAB_CACHE_DIR"] = str(cache)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "cab_core.sweep.worker"], input=json.dumps(
        {"config": config, "output_dir": str(out)}), text=True, capture_output=True, env=env)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"attempt process failed ({r.returncode}): {r.stderr[-2000:]}")
    res = json.loads((out / "result.json").read_text())
    sim = res["versions"]["simulator"]
    return {"setup_s": res["timing"]["setup_seconds"], "process_s": round(wall, 2),
            **({"brdf_lut": sim["brdf_lut"]} if "brdf_lut" in sim else {})}


def _warm_worker(config: dict, root: Path, cache: Path, n: int) -> dict:
    identity = {"task": config["task"]["name"], "seed": config["seed"], "attempt": 1, "sim": config["sim"]["name"],
                "model": config["model"]["name"]}
    old = os.environ.get("CAB_CACHE_DIR")
    os.environ["CAB_CACHE_DIR"] = str(cache)
    setups = []
    try:
        for i in range(n + 1):  # the first attempt starts the worker
            res = AttemptSupervisor(config, root / f"attempt-{i}", identity, SupervisorConfig(retry_backoff_s=0.0)).run()
            setups.append(res["timing"]["setup_seconds"])
    finally:
        close_workers()
        if old is None:
            os.environ.pop("CAB_CACHE_DIR", None)
        else:
            os.environ["CAB_CACHE_DIR"] = old
    return {"setup_s": round(statistics.median(setups[1:]), 3), "first_setup_s": setups[0], "n": n}


def startup(sims: list[str], task: str, n: int = 3) -> dict:
    """``{sim: {"cold_process": ..., "warm_cache": ..., "warm_worker": ...}}``."""
    out: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="cab-bench-startup-") as td:
        root = Path(td)
        for sim in sims:
            [config] = attempt_configs([(task, 0, "idle", "", sim)], cold=False)
            config["seed"] = 0
            cache = root / sim / "cache"
            print(f"cab-bench: start-up on {sim}...", file=sys.stderr, flush=True)
            out[sim] = {"cold_process": _fresh_process(config, root / sim / "cold", cache),
                        "warm_cache": _fresh_process(config, root / sim / "warm", cache),
                        "warm_worker": _warm_worker(config, root / sim / "worker", cache, n)}
    return out


def print_startup(res: dict, task: str) -> None:
    print(f"start-up of an idle attempt ({task}): setup_seconds, and the whole process for fresh ones")
    print(f"{'simulator':<12}{'cold process':>24}{'warm cache':>24}{'warm worker':>14}")
    for sim, r in res.items():
        c, w, k = r["cold_process"], r["warm_cache"], r["warm_worker"]
        print(f"{sim:<12}{c['setup_s']:>10.2f} s ({c['process_s']:>5.1f} s){w['setup_s']:>10.2f} s "
              f"({w['process_s']:>5.1f} s){k['setup_s']:>12.2f} s")
