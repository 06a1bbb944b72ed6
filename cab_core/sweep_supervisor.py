"""Runs one attempt of a sweep in a child process, with a watchdog and bounded retries.

Infrastructure failures are not the model's failures: a simulator that crashes (the child dies on a
signal or an unexpected exception), a simulator or provider that hangs (no record grows for
``hang_timeout_s``), a provider outage that outlived the harness's own retries, or a host fault the
episode recorded (termination ``provider_failure`` or ``error``). Each is recorded in the attempt's
``infrastructure.jsonl``, the try's records are moved aside (kept), and the attempt runs again, at
most ``max_retries`` more times. If every try fails, ``result.json`` says so and carries no verdict;
reports exclude it and a resumed sweep runs it again. Configuration problems are not retried.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .errors import ConfigError
from .sweep_child import EXIT_CONFIG, EXIT_RENDERER, PARENT_ENV
from .sweep_records import (INFRA_TERMINATIONS, annotate_result, check_attempt, infrastructure_failures,
                            log_infrastructure_failure, set_aside, write_infrastructure_result)

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

    @classmethod
    def from_cfg(cls, cfg: dict | None) -> "SupervisorConfig":
        c = dict(cfg or {})
        out = cls(max_retries=int(c.get("max_infra_retries", cls.max_retries)),
                  hang_timeout_s=float(c.get("hang_timeout_s", cls.hang_timeout_s)),
                  retry_backoff_s=float(c.get("retry_backoff_s", cls.retry_backoff_s)),
                  threads=c.get("threads_per_attempt", cls.threads))
        if out.max_retries < 0 or out.hang_timeout_s <= 0 or out.retry_backoff_s < 0:
            raise ConfigError("sweep.max_infra_retries and sweep.retry_backoff_s must be >= 0, "
                              "sweep.hang_timeout_s > 0")
        if out.threads is not None and (not isinstance(out.threads, int) or out.threads < 1):
            raise ConfigError(f"sweep.threads_per_attempt must be a positive integer or null, got {out.threads!r}")
        return out


def _progress_mark(d: Path) -> tuple:
    """What grows while an attempt makes progress: its log, events and state snapshots."""
    mark = []
    for rel in (CHILD_LOG, "events.jsonl", "privileged/snapshots.jsonl"):
        try:
            st = os.stat(d / rel)
            mark.append((st.st_size, st.st_mtime_ns))
        except FileNotFoundError:
            mark.append(None)
    return tuple(mark)


def _kill(proc: subprocess.Popen) -> None:
    """SIGKILL the child and anything in its process group (it leads its own)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def _log_tail(d: Path, n: int = 1200) -> str:
    try:
        return (d / CHILD_LOG).read_text(errors="replace")[-n:]
    except FileNotFoundError:
        return ""


class AttemptSupervisor:
    """Runs the attempt of one attempt directory until it completes or its retries are spent."""

    def __init__(self, config: dict, attempt_dir: Path, identity: dict, settings: SupervisorConfig,
                 job_log: str | None = None, on_child: Callable[[subprocess.Popen, int], None] | None = None):
        self.config = config
        self.dir = Path(attempt_dir)
        self.identity = identity
        self.settings = settings
        self.job_log = job_log
        self.on_child = on_child  # observes each child process started (pid, try number)

    def _run_child(self, try_no: int) -> tuple[int | None, bool]:
        """One try; returns (exit status or None when killed as hung, whether it hung)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, PARENT_ENV: str(os.getpid())}
        if self.settings.threads is not None:  # N workers on N cores: no attempt oversubscribes them
            env.update({k: str(self.settings.threads) for k in THREAD_ENV})
        with open(self.dir / CHILD_LOG, "ab") as log:
            proc = subprocess.Popen([sys.executable, "-m", "cab_core.sweep_child"], stdin=subprocess.PIPE,
                                    stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        if self.on_child is not None:
            self.on_child(proc, try_no)
        try:
            proc.stdin.write(json.dumps({"config": self.config, "output_dir": str(self.dir)}).encode())
            proc.stdin.close()
        except BrokenPipeError:  # the child died at once; its exit status tells why
            pass
        mark, last_change = _progress_mark(self.dir), time.monotonic()
        while proc.poll() is None:
            time.sleep(self.settings.poll_s)
            now_mark = _progress_mark(self.dir)
            if now_mark != mark:
                mark, last_change = now_mark, time.monotonic()
            elif time.monotonic() - last_change > self.settings.hang_timeout_s:
                _kill(proc)
                return None, True
        return proc.returncode, False

    def _failure(self, code: int | None, hung: bool) -> dict | None:
        """Classify a finished try: None when it is a valid attempt, else the failure record."""
        if hung:
            return {"kind": "hang", "detail": f"no progress for {self.settings.hang_timeout_s:g} s; killed"}
        if code == EXIT_CONFIG or code == EXIT_RENDERER:
            raise ChildConfigError(f"attempt {self.dir}: {_log_tail(self.dir, 600).strip()}")
        if code != 0:
            how = f"killed by signal {-code}" if code < 0 else f"exit status {code}"
            return {"kind": "crash", "detail": f"attempt process {how}", "log_tail": _log_tail(self.dir)}
        check = check_attempt(self.dir, self.identity, self.job_log)
        if check.state != "complete":
            return {"kind": "incomplete_record", "detail": "; ".join(check.problems)}
        reason = check.result["termination"]["reason"]
        if reason in INFRA_TERMINATIONS:
            return {"kind": reason, "detail": f"{INFRA_TERMINATIONS[reason]}: {check.result['termination'].get('detail')}"}
        return None

    def run(self) -> dict:
        """Run tries until one is a valid attempt; returns its result (or the infrastructure result)."""
        s = self.settings
        for try_no in range(1, s.max_retries + 2):
            t0 = time.monotonic()
            code, hung = self._run_child(try_no)
            failure = self._failure(code, hung)
            if failure is None:
                return annotate_result(self.dir, infrastructure_failures(self.dir))
            failure.update(try_no=try_no, wall_seconds=round(time.monotonic() - t0, 3), at=time.time())
            failure["records"] = set_aside(self.dir, failure["kind"], self.job_log)
            log_infrastructure_failure(self.dir, failure)
            if try_no <= s.max_retries and s.retry_backoff_s:
                time.sleep(s.retry_backoff_s)
        return write_infrastructure_result(self.dir, self.identity, infrastructure_failures(self.dir))

