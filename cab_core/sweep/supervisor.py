"""Runs one attempt of a sweep in a child process, with a watchdog and bounded retries.

Infrastructure failures are not the model's failures: a simulator that crashes (the child dies on a
signal or an unexpected exception), a simulator or provider that hangs (no record grows for
``hang_timeout_s``), a provider outage that outlived the harness's own retries, or a host fault the
episode recorded (termination ``provider_failure`` or ``error``). Each is recorded in the attempt's
``infrastructure.jsonl``, the try's records are moved aside (kept), and the attempt runs again, at
most ``max_retries`` more times. If every try fails, ``result.json`` says so and carries no verdict;
reports exclude it and a resumed sweep runs it again. Configuration problems are not retried.

Warm workers (``sweep.warm_workers``, on by default): the attempt runs in a worker process that has
run earlier attempts of this launcher process and keeps its renderer and imports (a renderer's set-up
drops from seconds to a fraction of one); each attempt builds its world fresh. A worker is replaced
after any try that is not a clean attempt (crash, hang, host fault), after
``sweep.worker_max_attempts`` attempts, and when its resident memory exceeds
``sweep.worker_max_rss_mb`` (after an attempt; during one the worker is killed and the attempt
retried, kind ``memory``). Each launcher process (the ``cab -m`` process, whose threads run the jobs
under cab's own launcher; a joblib or Ray worker) holds at most one worker per thread and environment;
under SLURM each job is its own process, so each attempt gets a fresh one there.
With ``warm_workers: false`` every try is a fresh process, as before.
"""
from __future__ import annotations

import atexit
import concurrent.futures as cf
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from cab_core.attempt.engine import cpu_slots
from cab_core.attempt.fork import ForkPoint
from cab_core.attempt.records.recovery import recovery
from cab_core.config import default_selection, normalise_overrides
from cab_core.errors import ConfigError, RecordError
from cab_core.plugins import task_info
from cab_core.sweep import zygote
from cab_core.sweep.attempt_state import (
    INFRA_LOG,
    INFRA_TERMINATIONS,
    annotate_result,
    check_attempt,
    infrastructure_failures,
    infrastructure_record,
    is_infrastructure_failure,
    log_infrastructure_failure,
    record_entries,
    set_aside,
    write_infrastructure_result,
)
from cab_core.sweep.protocol import EXIT_CONFIG, EXIT_RENDERER, PARENT_ENV, ChildProcess, kill_group

CHILD_LOG = "attempt.log"
# Thread pools an attempt process may start: lavapipe's renderer (the largest), BLAS and OpenMP.
THREAD_ENV = ("LP_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


class ChildConfigError(ConfigError):
    """The attempt's process stopped on a configuration problem; retrying cannot help."""


@dataclass
class SupervisorConfig:
    """``sweep.*`` settings: how many retries, how long without progress is a hang, the pause
    between tries, how many threads each attempt's renderer and numeric libraries may use (None: as
    many as they like), and how often the watchdog looks."""
    max_retries: int = 2
    hang_timeout_s: float = 900.0
    retry_backoff_s: float = 10.0
    threads: int | None = 1
    poll_s: float = 0.5
    warm_workers: bool = True
    worker_max_attempts: int = 50
    worker_max_rss_mb: float = 6144.0
    fork_workers: bool = True  # warm workers forked from the sweep's fork server (cab_core.sweep.zygote)
    cpu_slots: bool = True  # attempts share this machine's CPU slot pool (cab_core.attempt.engine.cpu_slots)

    @classmethod
    def from_cfg(cls, cfg: dict | None) -> SupervisorConfig:
        c = dict(cfg or {})
        out = cls(max_retries=int(c.get("max_infra_retries", cls.max_retries)),
                  hang_timeout_s=float(c.get("hang_timeout_s", cls.hang_timeout_s)),
                  retry_backoff_s=float(c.get("retry_backoff_s", cls.retry_backoff_s)),
                  threads=c.get("threads_per_attempt", cls.threads),
                  warm_workers=c.get("warm_workers", cls.warm_workers),
                  worker_max_attempts=c.get("worker_max_attempts", cls.worker_max_attempts),
                  worker_max_rss_mb=c.get("worker_max_rss_mb", cls.worker_max_rss_mb),
                  fork_workers=c.get("fork_workers", cls.fork_workers),
                  cpu_slots=bool(c.get("cpu_slots", cls.cpu_slots)))
        if out.max_retries < 0 or out.hang_timeout_s <= 0 or out.retry_backoff_s < 0:
            raise ConfigError("sweep.max_infra_retries and sweep.retry_backoff_s must be >= 0, "
                              "sweep.hang_timeout_s > 0")
        for name in ("warm_workers", "fork_workers"):
            if not isinstance(getattr(out, name), bool):
                raise ConfigError(f"sweep.{name} must be true or false, got {getattr(out, name)!r}")
        if isinstance(out.worker_max_attempts, bool) or not isinstance(out.worker_max_attempts, int) \
                or out.worker_max_attempts < 1:
            raise ConfigError(f"sweep.worker_max_attempts must be a positive integer, got {out.worker_max_attempts!r}")
        if isinstance(out.worker_max_rss_mb, bool) or not isinstance(out.worker_max_rss_mb, (int, float)) \
                or not out.worker_max_rss_mb > 0:
            raise ConfigError(f"sweep.worker_max_rss_mb must be a positive number, got {out.worker_max_rss_mb!r}")
        if out.threads is not None and (not isinstance(out.threads, int) or out.threads < 1):
            raise ConfigError(f"sweep.threads_per_attempt must be a positive integer or null, got {out.threads!r}")
        return out


def _progress_mark(d: Path) -> tuple:
    """What grows while an attempt makes progress: its log, events and state snapshots."""
    mark: list[tuple[int, int] | None] = []
    for rel in (CHILD_LOG, "events.jsonl", "privileged/snapshots.jsonl"):
        try:
            st = os.stat(d / rel)
            mark.append((st.st_size, st.st_mtime_ns))
        except FileNotFoundError:
            mark.append(None)
    return tuple(mark)


def _rss_mb(pid: int) -> float:
    """Resident memory of a process now, in MiB (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def _pipe(stream: IO[bytes] | None) -> IO[bytes]:
    """A child's standard stream that was asked for as ``subprocess.PIPE`` (which Popen always opens)."""
    if stream is None:
        raise RuntimeError("the child process was started without this pipe")
    return stream


def _plugin_packages(config: dict) -> list[str]:
    """The plugin packages an attempt of ``config`` uses (its simulator, robot, planner, harness and
    the suite of its task), which a forked worker's server imports before it forks
    (``cab_core.sweep.zygote``): a package left out is imported by every worker, privately (a task
    suite's mesh and graph libraries: hundreds of modules)."""
    from cab_core.plugins import all_tasks, registry

    model = config.get("model") or {}
    picks = {"simulators": (config.get("sim") or {}).get("name"),
             "embodiments": (config.get("embodiment") or {}).get("name"),
             "planners": (config.get("planner") or {}).get("name"),
             "harnesses": model.get("harness") or (config.get("harness") or {}).get("name")}
    out: list[str] = []
    for kind, name in picks.items():
        try:
            factory = registry(kind).get(name) if isinstance(name, str) else None
        except Exception:  # noqa: BLE001 (a broken plugin: the attempt reports it)
            factory = None
        top = str(getattr(factory, "__module__", "") or "").split(".")[0]
        if top and top != "cab_core" and top not in out:
            out.append(top)
    task = (config.get("task") or {}).get("name")
    try:
        suite = type(all_tasks().get(task)).__module__.split(".")[0] if isinstance(task, str) else ""
    except Exception:  # noqa: BLE001 (a broken suite: the attempt reports it)
        suite = ""
    if suite and suite not in ("cab_core", "builtins") and suite not in out:
        out.append(suite)
    return out


class WarmWorker:
    """A ``cab_core.sweep.worker --worker`` process: attempts one after another (see there). Forked
    from this sweep's fork server when ``fork`` (``sweep.fork_workers``; ``preload``: the plugin
    packages it imports first), so that the workers share their libraries' pages; a fresh
    interpreter otherwise, or when no server can fork it."""

    def __init__(self, env: dict, first_log: Path, fork: bool = False, preload: Sequence[str] = ()):
        self.proc: subprocess.Popen | zygote.ForkedProcess
        with open(first_log, "ab") as log:  # what the worker says before its first job lands there
            forked = self._forked(env, log.fileno(), preload) if fork else None
            if forked is None:
                self.proc = subprocess.Popen([sys.executable, "-m", "cab_core.sweep.worker", "--worker"],
                                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, env=env,
                                             start_new_session=True)
                self._stdin, self._stdout = _pipe(self.proc.stdin), _pipe(self.proc.stdout)
            else:
                self.proc, self._stdin, self._stdout = forked
        self.attempts = 0
        self.rss_mb = 0.0
        self._buf = b""

    @staticmethod
    def _forked(env: dict, log: int, preload: Sequence[str]) -> tuple[zygote.ForkedProcess, IO[bytes], IO[bytes]] | None:
        in_r, in_w = os.pipe()
        out_r, out_w = os.pipe()
        try:
            proc = zygote.fork_worker(env, preload, in_r, out_w, log)
        finally:
            os.close(in_r)
            os.close(out_w)
        if proc is None:
            os.close(in_w)
            os.close(out_r)
            return None
        return proc, os.fdopen(in_w, "wb"), os.fdopen(out_r, "rb")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def submit(self, job: dict) -> bool:
        """Hand the worker a job; False when it is gone (its status then says why)."""
        try:
            self._stdin.write((json.dumps(job) + "\n").encode())
            self._stdin.flush()
        except (BrokenPipeError, OSError):
            return False
        self.attempts += 1
        return True

    def reply(self, timeout: float) -> dict | None:
        """The worker's answer to its job, None while it works; ``{"status": <exit status>}`` once it
        has died without one."""
        if b"\n" not in self._buf:
            ready, _, _ = select.select([self._stdout], [], [], timeout)
            if ready:
                chunk = os.read(self._stdout.fileno(), 65536)
                if not chunk:  # end of its output: the process is gone
                    return {"status": self.proc.wait()}
                self._buf += chunk
        if b"\n" in self._buf:
            line, self._buf = self._buf.split(b"\n", 1)
            out = json.loads(line)
            self.rss_mb = float(out.get("rss_mb") or 0.0)
            return out
        return None

    def close(self) -> None:
        """Let the worker leave (its input ends), or kill it if it does not within 5 s."""
        if self.alive():
            try:
                self._stdin.close()
                self.proc.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                kill_group(self.proc)
        for f in (self._stdin, self._stdout):
            try:
                f.close()
            except OSError:
                pass


_WORKERS: dict[tuple, WarmWorker] = {}  # this process's warm workers, by environment and thread


_ABANDONED = threading.Event()  # set by abandon(): the process is about to end, mid-sweep


@atexit.register
def close_workers() -> None:
    """Close every warm worker of this process (at exit; tests call it too)."""
    while _WORKERS:
        _WORKERS.popitem()[1].close()


def abandon() -> None:
    """Stop every supervisor of this process now (a sweep interrupted while its jobs run in threads
    of this process): each warm worker's process group is killed at once, without waiting on the
    connections that supervising threads are reading, and no supervisor starts another try or
    writes a failure afterwards (its thread ends in ``KeyboardInterrupt``). The attempts in flight
    leave no ``result.json``: a resumed sweep sets their records aside."""
    _ABANDONED.set()
    while _WORKERS:
        try:
            os.killpg(_WORKERS.popitem()[1].proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError, KeyError):
            pass


def _log_tail(d: Path, n: int = 1200) -> str:
    try:
        return (d / CHILD_LOG).read_text(errors="replace")[-n:]
    except FileNotFoundError:
        return ""


class _Watchdog:
    """Watches one try: a hang (no record grows for ``hang_timeout_s``) or, in a warm worker, a
    process over ``worker_max_rss_mb``."""

    def __init__(self, attempt_dir: Path, settings: SupervisorConfig, pid: int):
        self.dir, self.settings, self.pid = attempt_dir, settings, pid
        self.mark, self.last_change = _progress_mark(attempt_dir), time.monotonic()

    def verdict(self) -> str | None:
        """None while the try may go on, else why it must be killed."""
        mark = _progress_mark(self.dir)
        if mark != self.mark:
            self.mark, self.last_change = mark, time.monotonic()
        elif time.monotonic() - self.last_change > self.settings.hang_timeout_s:
            return "hang"
        if self.settings.warm_workers and _rss_mb(self.pid) > self.settings.worker_max_rss_mb:
            return "memory"
        return None


class AttemptSupervisor:
    """Runs the attempt of one attempt directory until it completes or its retries are spent."""

    def __init__(self, config: dict, attempt_dir: Path, identity: dict, settings: SupervisorConfig,
                 job_log: str | None = None, on_child: Callable[[ChildProcess, int], None] | None = None):
        self.config = config
        self.dir = Path(attempt_dir)
        self.identity = identity
        self.settings = settings
        self.job_log = job_log
        self.on_child = on_child  # observes each child process started (pid, try number)
        self.child_error: str | None = None  # the exception that ended the last try, as a warm worker tells it
        self.unwritten: list[str] = []  # what run() could not write (a full disk)
        self.write_error: str | None = None  # the first file-system error that stopped a write

    def _env(self) -> dict:
        env = {**os.environ, PARENT_ENV: str(os.getpid())}
        if self.settings.threads is not None:  # N workers on N cores: no attempt oversubscribes them
            env.update({k: str(self.settings.threads) for k in THREAD_ENV})
        # many attempts in flight compute one per core at a time (physics, rendering, video); none while it waits on its model
        env[cpu_slots.ENV] = str(os.cpu_count() or 1) if self.settings.cpu_slots else "0"
        return env

    def _run_child(self, try_no: int) -> tuple[int | None, str | None]:
        """One try; returns (exit status, or None when it was killed, and why it was killed: None,
        "hang" or "memory")."""
        self.child_error = None
        self.dir.mkdir(parents=True, exist_ok=True)
        if self.settings.warm_workers:
            return self._run_in_worker(try_no)
        env = self._env()
        with open(self.dir / CHILD_LOG, "ab") as log:
            proc = subprocess.Popen([sys.executable, "-m", "cab_core.sweep.worker"], stdin=subprocess.PIPE,
                                    stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        if self.on_child is not None:
            self.on_child(proc, try_no)
        try:
            stdin = _pipe(proc.stdin)
            stdin.write(json.dumps({"config": self.config, "output_dir": str(self.dir)}).encode())
            stdin.close()
        except BrokenPipeError:  # the child died at once; its exit status tells why
            pass
        watch = _Watchdog(self.dir, self.settings, proc.pid)
        while proc.poll() is None:
            time.sleep(self.settings.poll_s)
            killed = watch.verdict()
            if killed:
                kill_group(proc)
                return None, killed
        return proc.returncode, None

    def _run_in_worker(self, try_no: int) -> tuple[int | None, str | None]:
        env = self._env()
        # one worker per thread (cab-suite-check supervises from a pool of threads) and environment
        key = tuple(sorted((k, env.get(k)) for k in (*THREAD_ENV, PARENT_ENV, cpu_slots.ENV))) + (sys.executable,
                                                                                 threading.get_ident())
        worker = _WORKERS.get(key)
        if worker is not None and not worker.alive():
            worker.close()
            worker = None
        if worker is None:
            worker = _WORKERS[key] = WarmWorker(env, self.dir / CHILD_LOG, self.settings.fork_workers,
                                                _plugin_packages(self.config) if self.settings.fork_workers else ())
        if self.on_child is not None:
            self.on_child(worker.proc, try_no)
        job = {"config": self.config, "output_dir": str(self.dir), "log": str(self.dir / CHILD_LOG)}
        reply: dict | None = None if worker.submit(job) else {"status": worker.proc.wait()}
        watch = _Watchdog(self.dir, self.settings, worker.proc.pid)
        while reply is None:
            reply = worker.reply(self.settings.poll_s)
            killed = None if reply is not None else watch.verdict()
            if killed:
                kill_group(worker.proc)
                worker.close()
                _WORKERS.pop(key, None)
                return None, killed
        code = int(reply["status"])
        self.child_error = reply.get("error")
        s = self.settings
        if code != 0 or not worker.alive() or worker.attempts >= s.worker_max_attempts \
                or worker.rss_mb > s.worker_max_rss_mb:
            worker.close()
            _WORKERS.pop(key, None)
        return code, None

    def _failure(self, code: int | None, killed: str | None) -> dict | None:
        """Classify a finished try: None when it is a valid attempt, else the failure record."""
        if killed == "hang":
            return {"kind": "hang", "detail": f"no progress for {self.settings.hang_timeout_s:g} s; killed"}
        if killed == "memory":
            return {"kind": "memory", "detail": f"the attempt's process held more than "
                                                f"{self.settings.worker_max_rss_mb:g} MiB; killed"}
        assert code is not None  # a try without an exit status was killed for a hang or memory: above
        if code == EXIT_CONFIG or code == EXIT_RENDERER:
            raise ChildConfigError(f"attempt {self.dir}: {_log_tail(self.dir, 600).strip()}")
        if code != 0:
            how = f"killed by signal {-code}" if code < 0 else f"exit status {code}"
            why = f" ({self.child_error})" if self.child_error else ""
            return {"kind": "crash", "detail": f"attempt process {how}{why}", "log_tail": _log_tail(self.dir)}
        check = check_attempt(self.dir, self.identity, self.job_log)
        reason = check.record.termination.reason if check.record is not None else None
        if check.state != "complete" and reason not in INFRA_TERMINATIONS:  # an infrastructure termination is not scored: partial
            return {"kind": "incomplete_record", "detail": "; ".join(check.problems)}
        assert check.result is not None  # a complete record's result.json holds a dict
        if reason in INFRA_TERMINATIONS:
            return {"kind": reason, "detail": f"{INFRA_TERMINATIONS[reason]}: {check.result['termination'].get('detail')}"}
        return None

    def _keep(self, what: str, write: Callable, *args):
        """``write(*args)``; on a file-system error (a full disk, above all) note ``what`` could not be
        written and return None: the supervisor's own bookkeeping never ends the sweep."""
        try:
            return write(*args)
        except OSError as e:
            self.unwritten.append(what)
            self.write_error = self.write_error or (e.strerror or type(e).__name__)
            _drop_temporary(self.dir)
            return None

    def run(self) -> dict:
        """Run tries until one is a valid attempt; returns its result (or the infrastructure result).
        What could not be written (a full disk) is listed in :attr:`unwritten`, the error in
        :attr:`write_error`; then no further try runs (retrying cannot help until there is space,
        and records that could not be set aside stand in its way) and the result returned is the
        one that should have been written."""
        s = self.settings
        self.unwritten = []
        self.write_error = None
        session: list[dict] = []  # this session's failures, whether or not infrastructure.jsonl took them
        for try_no in range(1, s.max_retries + 2):
            t0 = time.monotonic()
            if _ABANDONED.is_set():
                raise KeyboardInterrupt("the sweep was stopped")
            try:
                code, killed = self._run_child(try_no)
            except OSError as e:  # the try's folder or log could not be made
                self.unwritten.append(f"the folder or log of try {try_no}")
                self.write_error = self.write_error or (e.strerror or type(e).__name__)
                break
            if _ABANDONED.is_set():  # its worker was killed by abandon(): not a failure of the attempt
                raise KeyboardInterrupt("the sweep was stopped")
            failure = self._failure(code, killed)
            if failure is None:
                failures = infrastructure_failures(self.dir, session)
                done = self._keep("the infrastructure failures in result.json", annotate_result, self.dir, failures)
                if done is None:
                    done = json.loads((self.dir / "result.json").read_text())
                    done["infrastructure"] = {"failed": False, "failures": failures}
                return done
            failure.update(try_no=try_no, wall_seconds=round(time.monotonic() - t0, 3), at=time.time())
            failure["records"] = self._keep(f"set_aside/ for try {try_no}'s records ({failure['kind']})",
                                            set_aside, self.dir, failure["kind"], self.job_log)
            session.append(failure)
            self._keep(f"{INFRA_LOG} (try {try_no}: {failure['kind']})", log_infrastructure_failure, self.dir, failure)
            if self.unwritten:
                break
            if try_no <= s.max_retries and s.retry_backoff_s:
                time.sleep(s.retry_backoff_s)
        failures = infrastructure_failures(self.dir, session)
        out = None
        if self.unwritten and record_entries(self.dir, self.job_log):
            self.unwritten.append("result.json")  # not among a try's records: a resumed sweep sets them aside
        else:
            out = self._keep("result.json", write_infrastructure_result, self.dir, self.identity, failures)
        return out if out is not None else infrastructure_record(self.identity, failures).dump()


def _drop_temporary(d: Path) -> None:
    """Remove what an atomic write of this process left half-written in ``d`` (a full disk)."""
    for p in d.glob(f".*.tmp-{os.getpid()}"):
        try:
            p.unlink()
        except OSError:
            pass


# -- batches: many one-off attempts (an oracle or the idle agent per task, seed and simulator) -----


def _as_dict(plain: object) -> dict:
    """A composed config made plain (``OmegaConf.to_container``), which is a dict: the root of a config is a mapping."""
    if not isinstance(plain, dict):
        raise ConfigError(f"a composed config is not a mapping: {plain!r}")
    return plain


def attempt_configs(jobs: list[tuple], cold: bool, randomize: str | None = None,
                    planner: str | None = None) -> list[dict]:
    """The composed configuration of each ``(task, seed, agent, out, sim)``, as ``cab task=T
    seed=S model=A sim=X`` composes it (in this thread: Hydra's composition is not thread-safe).
    ``cold``: a renderer generates its tables in each process (no cache folder), as before the cache."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    out = []
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        for task, seed, agent, _, sim, *perturb in jobs:
            overrides = [f"task={task}", f"seed={seed}", f"model={agent}", f"sim={sim}", "attempt=1"]
            if perturb and perturb[0] is not None:
                overrides.append(f"perturb.seed={perturb[0]}")
            if randomize is not None:
                overrides.append(f"randomize={randomize}")
            if planner is not None:
                overrides.append(f"planner={planner}")
            cfg = compose(config_name="config", overrides=normalise_overrides(overrides))
            plain = _as_dict(OmegaConf.to_container(cfg, resolve=True))
            if cold and "brdf_cache" in plain["sim"]:
                plain["sim"]["brdf_cache"] = False
            out.append(plain)
    return out


def run_one(config: dict, out: str, settings) -> dict:
    """One attempt, supervised (crashes, hangs and runaway memory are retried as infrastructure
    failures); returns a compact summary."""
    task, seed, agent, sim = config["task"]["name"], config["seed"], config["model"]["name"], config["sim"]["name"]
    perturb = (config.get("perturb") or {}).get("seed")
    info = task_info(task)
    identity = {"task": task, "seed": seed, "attempt": 1, "sim": sim, "model": agent}
    t0 = time.monotonic()
    row = {"task": task, "seed": seed, "agent": agent, "sim": sim, "perturb": perturb,
           "randomize": (config.get("randomize") or {}).get("name", "none")}
    fork = config.get("fork") or {}
    if fork.get("from") is not None:
        row.update(parent=str(fork["from"]), fork_at=fork.get("at"))
    try:
        r = AttemptSupervisor(config, Path(out), identity, settings).run()
    except Exception as e:  # report, never stop the whole check
        return {**row, "error": repr(e), "wall_s": time.monotonic() - t0}
    if is_infrastructure_failure(r):
        return {**row, "wall_s": time.monotonic() - t0,
                "error": f"infrastructure failure: {r['termination'].get('detail')}"}
    ck = r.get("checkpoints") or {}
    if "fork_at" in row:
        row.update(recovery(Path(out)))
    return {
        **row, "dir": out,
        "success": bool(r["verdict"].get("success")), "termination": r["termination"]["reason"],
        "margin": (r["verdict"].get("margin") or {}).get("fraction"),
        "margin_predicate": (r["verdict"].get("margin") or {}).get("predicate"),
        "calls": r["budget"]["tool_calls_used"], "calls_limit": r["budget"]["tool_calls_limit"],
        "sim_s": r["budget"]["sim_seconds_used"], "sim_s_limit": r["budget"]["sim_seconds_limit"],
        "ref_calls": info.reference_solution_api_calls, "ref_sim_s": info.reference_solution_sim_s,
        "subgoals": [s["attained"] for s in ck.get("subgoals", [])],
        "spatial": [s["attained"] for s in ck.get("spatial", [])],
        "subgoals_at_start": ck.get("subgoals_at_start", []),
        "checkpoint_error": ck.get("error"),
        "wall_s": round(time.monotonic() - t0, 1),
        "setup_s": (r.get("timing") or {}).get("setup_seconds"),
    }


def run_batch(tasks: list[str], seeds: list[int] | dict[str, tuple[int, ...]] | None, jobs: int, out: Path,
          agents=("oracle", "idle"), sims: tuple[str, ...] | None = None, cold: bool = False,
          perturb: int = 0, randomize: str | None = None, planner: str | None = None) -> list[dict]:
    """Every attempt, ``jobs`` at a time. Warm (the default): each of the ``jobs`` threads keeps one
    worker process that runs its attempts one after another (``sweep.warm_workers``), renderer
    tables read from the cache folder. ``cold``: a fresh process per attempt and no cache folder, as a
    ``cab -m`` sweep ran attempts before warm workers, for comparison. ``randomize``: the appearance
    randomisation option of every attempt (``cab_core.attempt.variation.randomize``). ``perturb``: each attempt
    ``perturb`` times instead, with ``perturb.seed`` 1..N (``cab_core.attempt.variation.perturb``). ``seeds``: one
    list for every task, or each task's own (a seed set), or None: each task's catalog seed. ``planner``:
    the motion planner option of every attempt (None: the default configuration's)."""
    if sims is None:
        sims = (default_selection(("sim",))["sim"],)

    by_task: Mapping[str, Sequence[int]] = seeds if isinstance(seeds, dict) else \
        {t: seeds if seeds is not None else [task_info(t).seed] for t in tasks}
    jobs_list = []
    for t in tasks:
        for s in by_task.get(t, ()):
            for sim in sims:
                for a in agents:
                    for k in (range(1, perturb + 1) if perturb else [None]):
                        where = out / sim / t / f"seed-{s}" / a / (f"perturb-{k}" if k else "")
                        jobs_list.append((t, s, a, str(where), sim, k))
    configs = attempt_configs(jobs_list, cold, randomize, planner)
    return run_configs(configs, [j[3] for j in jobs_list], jobs, cold)


def run_configs(configs: list[dict], outs: list[str], jobs: int, cold: bool = False) -> list[dict]:
    """Composed configurations, each into its folder, ``jobs`` at a time (supervised, warm workers
    unless ``cold``); the rows of :func:`run_one`, in the order given."""
    settings = SupervisorConfig(warm_workers=not cold, retry_backoff_s=1.0)
    rows: list[dict | None] = [None] * len(configs)
    try:
        with cf.ThreadPoolExecutor(max_workers=jobs) as ex:
            futs = {ex.submit(run_one, c, o, settings): i for i, (c, o) in enumerate(zip(configs, outs))}
            for f in cf.as_completed(futs):
                row = f.result()
                rows[futs[f]] = row
                fork = f" fork at {row['fork_at']}" if row.get("fork_at") is not None else ""
                print(f"  done {row['task']} seed={row['seed']} {row['agent']} on {row['sim']}{fork}"
                      + (f" perturb={row['perturb']}" if row.get("perturb") else "") + ": "
                      f"{'error ' + row['error'] if 'error' in row else ('success' if row['success'] else 'fail')}",
                      file=sys.stderr, flush=True)
    finally:
        close_workers()
    return [r for r in rows if r is not None]


def fork_configs(points: list[tuple[str, int]], agent: str | None = "oracle", video: bool = False,
                 planner: str | None = None) -> list[dict]:
    """The composed configuration of a fork of each ``(parent folder, K)`` played by ``agent``, as
    ``cab fork.from=<parent> fork.at=K model=<agent>`` composes it (the parent's task and simulator
    named too, so the supervisor's identity of the attempt is the fork's). ``agent=None``: each fork
    is played by its parent's own model, as the parent's records hold it (``attempt_start.config``:
    ``model_cfg`` and ``harness_cfg``, e.g. a scripted agent with its script, a reference-harness
    model with its settings), not by a model config of that name composed afresh. ``planner``: every
    prefix made again with that planner (``fork.planner=own``) instead of each parent's."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    out = []
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        for parent, at in points:
            cfg = ForkPoint.load(parent, at).config
            if agent is None and not (isinstance(cfg.get("model_cfg"), dict) and isinstance(cfg.get("harness_cfg"), dict)):
                raise RecordError(f"fork of {parent}: its records hold no model or harness configuration "
                                  "(attempt_start.config.model_cfg, harness_cfg) to play the fork with")
            overrides = [f"fork.from='{Path(parent).resolve()}'", f"fork.at={int(at)}", f"model={agent or 'oracle'}",
                         f"task={cfg['task']}", f"sim={cfg['sim']}", f"seed={cfg['seed']}",
                         f"record.video={'true' if video else 'false'}"]
            if planner is not None:
                overrides += [f"planner={planner}", "fork.planner=own"]
            c = _as_dict(OmegaConf.to_container(compose(config_name="config", overrides=overrides), resolve=True))
            if agent is None:  # the parent's model and harness as recorded (a composed placeholder replaced)
                c["model"], c["harness"] = dict(cfg["model_cfg"]), dict(cfg["harness_cfg"])
            out.append(c)
    return out
