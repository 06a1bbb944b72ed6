"""Memory of a sweep's slots, and of a warm worker over many attempts (issue 28).

``slots``: runs ``cab -m task=T sim=S model=qwen_local attempt=1..N hydra.launcher.n_jobs=N`` against a
local OpenAI-compatible stand-in that holds every model request open, so each of the N attempts sits
built and waiting on its model, as a model-bound sweep's attempts do; once all N have asked, prints the
PSS of every process of the sweep by role and per slot (all of it over N; with several N, also the
marginal cost of one more slot), then ends the sweep. ``growth``: one warm
worker runs K oracle attempts one after another (``AttemptSupervisor``, as a sweep does) and prints its
RSS and PSS after each. Not a test: figures depend on the machine and its load (printed beside them).

    python scripts/bench_memory.py slots --sim mujoco --slots 1,4,8 --out /tmp/mem
    python scripts/bench_memory.py growth --sim mujoco --attempts 50 --out /tmp/grow
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from cab_core.sweep.memory import descendants, memory_mb


class HoldingModel:
    """``POST /v1/chat/completions`` is held open until the server closes; ``GET /v1/models`` lists
    one model. Counts the chat requests."""

    def __init__(self, model_id: str = "held"):
        self.requests = 0
        self._stop = threading.Event()
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                body = json.dumps({"object": "list", "data": [{"id": model_id, "object": "model"}]}).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def do_POST(self):
                self.rfile.read(int(self.headers.get("Content-Length") or 0))
                outer.requests += 1
                outer._stop.wait()
                self.send_response(503)
                self.end_headers()

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/v1"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self._stop.set()
        self.server.shutdown()
        self.server.server_close()


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _role(pid: int) -> str:
    cmd = _cmdline(pid)
    if not cmd:
        return "gone"
    if "cab_core.sweep.worker" in cmd:
        return "attempt worker"
    if "cab_core.sweep.zygote" in cmd:  # the fork server, and the workers it forked (its children)
        try:
            parent = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            parent = 0
        return "attempt worker" if "cab_core.sweep.zygote" in _cmdline(parent) else "fork server"
    if "ffmpeg" in cmd:
        return "video encoder"
    if "resource_tracker" in cmd:
        return "resource tracker"
    if "loky" in cmd or "joblib" in cmd:
        return "launcher worker"
    return "other"


def slots(sim: str, n: int, out: Path, task: str, extra: list[str], wait_s: float) -> dict:
    fake = HoldingModel()
    cab = os.path.join(os.path.dirname(sys.executable), "cab")
    cmd = [cab, "-m", f"task={task}", f"sim={sim}", "model=qwen_local", f"model.base_url={fake.url}",
           "model.model_id=held", f"attempt={','.join(str(i) for i in range(1, n + 1))}",
           f"hydra.launcher.n_jobs={n}", f"hydra.sweep.dir={out / f'{sim}-{n}'}",
           "sweep.preflight_network=false", "model.probe=false", *extra]  # the stand-in holds requests: no probe
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    t0 = time.monotonic()
    try:
        while fake.requests < n:
            if proc.poll() is not None:
                raise RuntimeError(f"the sweep ended ({proc.returncode}): {proc.stderr.read().decode()[-2000:]}"
                                   if proc.stderr else "the sweep ended")
            if time.monotonic() - t0 > wait_s:
                raise RuntimeError(f"{fake.requests} of {n} attempts asked their model within {wait_s:g} s")
            time.sleep(0.5)
        ready_s = time.monotonic() - t0
        time.sleep(3.0)  # the last attempt's first request is out: its world is built
        roles: dict[str, list[dict]] = {}
        for p in descendants(proc.pid):
            role = "main" if p == proc.pid else _role(p)
            roles.setdefault(role, []).append(memory_mb(p))
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
        fake.close()
    total = sum(m["pss"] for ms in roles.values() for m in ms)
    per_role = {r: {"count": len(ms), "pss_mb": round(sum(m["pss"] for m in ms), 1),
                    "pss_anon_mb": round(sum(m["pss_anon"] for m in ms), 1),
                    "uss_mb": round(sum(m["uss"] for m in ms), 1), "rss_mb": round(sum(m["rss"] for m in ms), 1)}
                for r, ms in sorted(roles.items())}
    fixed = sum(v["pss_mb"] for r, v in per_role.items() if r in ("main", "resource tracker"))
    # per slot: everything the sweep holds (its main process, fork server and trackers included) over
    # N; "excluding main" is the measure of the first figures (issue 28), taken with a launcher
    # process per slot, when the main process held nothing per slot
    return {"sim": sim, "slots": n, "total_pss_mb": round(total, 1), "per_slot_pss_mb": round(total / n, 1),
            "per_slot_excl_main_mb": round((total - fixed) / n, 1),
            "start_s": round(ready_s, 1), "roles": per_role, "load_avg_1min": round(os.getloadavg()[0], 2)}


def growth(sim: str, attempts: int, out: Path, task: str, video: bool) -> list[dict]:
    from cab_core.plugins import task_info
    from cab_core.sweep.supervisor import _WORKERS, AttemptSupervisor, SupervisorConfig, attempt_configs, close_workers

    config = attempt_configs([(task, task_info(task).seed, "oracle", str(out), sim)], cold=False)[0]
    config["record"]["video"] = video
    identity = {"task": task, "seed": config["seed"], "attempt": 1, "sim": sim, "model": "oracle"}
    settings = SupervisorConfig(retry_backoff_s=0.0, worker_max_attempts=attempts + 1)
    rows = []
    try:
        for i in range(1, attempts + 1):
            AttemptSupervisor(config, out / f"attempt-{i}", identity, settings).run()
            (worker,) = _WORKERS.values()
            m = memory_mb(worker.proc.pid)
            rows.append({"attempt": i, "rss_mb": round(m["rss"], 1), "pss_mb": round(m["pss"], 1),
                         "uss_mb": round(m["uss"], 1)})
            print(json.dumps(rows[-1]), flush=True)
    finally:
        close_workers()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("slots", "growth"))
    ap.add_argument("--sim", default="mujoco")
    ap.add_argument("--task", default="click_bell")
    ap.add_argument("--slots", default="1,4,8", help="slots: comma-separated numbers of attempts in flight")
    ap.add_argument("--attempts", type=int, default=50, help="growth: attempts in one warm worker")
    ap.add_argument("--video", action="store_true", help="growth: record video (off by default)")
    ap.add_argument("--wait", type=float, default=600.0, help="slots: seconds to wait for every attempt to ask")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("extra", nargs="*", help="slots: more overrides for cab, e.g. sweep.warm_workers=false")
    a = ap.parse_intermixed_args()
    a.out.mkdir(parents=True, exist_ok=True)
    if a.what == "growth":
        rows = growth(a.sim, a.attempts, a.out, a.task, a.video)
        first, last = rows[min(1, len(rows) - 1)], rows[-1]
        print(f"{a.sim}: warm worker PSS {first['pss_mb']} MiB after attempt {first['attempt']}, {last['pss_mb']} MiB "
              f"after {last['attempt']} ({(last['pss_mb'] - first['pss_mb']) / max(1, last['attempt'] - first['attempt']):+.2f}"
              f" MiB per attempt); load {os.getloadavg()[0]:.2f}")
        return
    previous = None
    for n in (int(x) for x in a.slots.split(",")):
        r = slots(a.sim, n, a.out, a.task, a.extra, a.wait)
        if previous is not None and n != previous["slots"]:  # what one more attempt in flight costs
            r["marginal_pss_mb"] = round((r["total_pss_mb"] - previous["total_pss_mb"]) / (n - previous["slots"]), 1)
        previous = r
        print(json.dumps(r), flush=True)


if __name__ == "__main__":
    main()
