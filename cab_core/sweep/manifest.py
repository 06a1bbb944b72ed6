"""Sweeps (``cab -m ...``): the manifest that pins a sweep's configuration, resume, and progress.

A sweep directory holds ``sweep.json``: the resolved configuration (without Hydra's own settings
and the ``sweep.*`` infrastructure settings, which may legitimately differ between sessions: the
launcher, its worker count, output directories, retries), the list of jobs the sweep expands to,
and a fingerprint of both, the keys the attempt folders name besides task, model, simulator, seed
and attempt (``path_keys``, read back by each job: ``cab_core.sweep.layout``) and each job's folder, and the comparison contract of each configuration (``contracts``, by the label
cab-report gives it: :func:`cab_core.apps.sweep_contracts.sweep_contracts`).
A sweep two of whose jobs would write to the same folder is refused before anything runs. Running a
sweep into a directory that already has a manifest resumes it, provided the fingerprint is the same;
otherwise it is refused, naming what changed. A directory written with the first layout
(``cab-sweep/1``: no simulator folder) is refused too: its attempts would all run again elsewhere.

Each job (one attempt) skips an attempt directory whose ``result.json`` validates, moves a partial
one aside, and runs the attempt under ``AttemptSupervisor`` (child process, watchdog, retries).
"""
from __future__ import annotations

import atexit
import fcntl
import hashlib
import itertools
import json
import os
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cab_core.attempt.records.result_format import write_json_atomic
from cab_core.attempt.spec import attempt_spec
from cab_core.errors import ConfigError
from cab_core.sweep.attempt_state import (
    GIVEN_UP,
    INTERRUPTED,
    SET_ASIDE,
    annotate_result,
    check_attempt,
    infrastructure_failures,
    is_infrastructure_failure,
    set_aside,
    unlisted_set_aside,
)
from cab_core.sweep.layout import attempt_folders, check_distinct, varying_keys
from cab_core.sweep.spend import sweep_spend
from cab_core.sweep.supervisor import AttemptSupervisor, SupervisorConfig

MANIFEST = "sweep.json"
LOCK = "sweep.lock"  # held (flock) by the process that runs a sweep in this directory
MANIFEST_VERSION = "cab-sweep/2"  # 2: attempt folders <task>/<model>/<sim>/[<swept>/]seed-<S>/attempt-<A>
OLD_LAYOUTS = {"cab-sweep/1": "<task>/<model>/seed-<S>/attempt-<A>"}
VOLATILE = ("hydra", "sweep")  # top-level config keys that may differ between sessions of one sweep


class SweepConfigChanged(ConfigError):
    """A sweep directory was started with another configuration; mixing results is refused."""


class SweepBusy(SweepConfigChanged):
    """A sweep is running in this sweep directory now: a second one is refused like a changed
    configuration (exit status 2), before it writes or sets aside anything."""


_LOCKS: dict[str, int] = {}  # sweep directories this process holds, and the descriptor holding each


def lock_sweep(sweep_dir: Path) -> None:
    """Hold ``<sweep_dir>/sweep.lock`` (``flock``, exclusive) until :func:`unlock_sweep` or the end
    of this process, or raise SweepBusy naming the process that holds it (pid, host, start time,
    command). The kernel releases the lock when the process ends, however it ends (SIGKILL
    included): a resumed sweep never finds a stale lock. The descriptor is not inherited by the
    processes the sweep starts. The file is removed when the lock is released by this process (a
    lock taken on a file that was removed meanwhile is taken again on the new one)."""
    d = Path(sweep_dir)
    key = str(d.resolve())
    if key in _LOCKS:
        return
    d.mkdir(parents=True, exist_ok=True)
    path = d / LOCK
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise SweepBusy(f"{d} is in use by a sweep running now ({holder}); nothing was run or set aside. "
                            "Wait for it to end (then run this command to resume), or choose another "
                            "hydra.sweep.dir") from None
        if _same_file(fd, path):
            break
        os.close(fd)  # its holder removed it after we opened it: lock the file there now
    _LOCKS[key] = fd
    me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(), "argv": sys.argv}
    try:  # who holds it, for the refusal above (the lock itself holds without it: a full disk)
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(me).encode(), 0)
    except OSError:
        pass


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except FileNotFoundError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def unlock_sweep(sweep_dir: Path) -> None:
    """Release :func:`lock_sweep`'s lock and remove its file (while still holding it)."""
    fd = _LOCKS.pop(str(Path(sweep_dir).resolve()), None)
    if fd is None:
        return
    path = Path(sweep_dir) / LOCK
    try:
        if _same_file(fd, path):
            path.unlink()
    except OSError:
        pass
    os.close(fd)


@atexit.register
def _unlock_all() -> None:
    for key in list(_LOCKS):
        unlock_sweep(Path(key))


def _holder(fd: int) -> str:
    try:
        h = json.loads(os.pread(fd, 65536, 0))
        started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(float(h["started"])))
        cmd = " ".join(str(a) for a in h.get("argv") or [])
        return f"pid {int(h['pid'])} on {h['host']}, started {started}" + (f": {cmd}" if cmd else "")
    except (OSError, ValueError, KeyError, TypeError):
        return "a process that has not yet written its name"


def _plain(cfg: Any) -> Any:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(cfg, resolve=True) if OmegaConf.is_config(cfg) else cfg


def _is_volatile(override: str) -> bool:
    key = override.split("=", 1)[0].lstrip("+~")
    return key.split(".", 1)[0] in VOLATILE or key.startswith("hydra/")


def expand_jobs(cfg: Any) -> list[list[str]]:
    """The jobs a multirun config expands to (as Hydra's basic sweeper does), each a sorted list of
    overrides without the volatile ones. Globs over config groups are resolved by Hydra's loader."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = [f"{k}={v}" for k, v in (_plain(cfg.hydra.sweeper).get("params") or {}).items()]
    args = params + list(_plain(cfg.hydra.overrides.task))
    parser = OverridesParser.create(config_loader=GlobalHydra.instance().config_loader())
    parsed = parser.parse_overrides(args)
    swept = {o.get_key_element() for o in parsed if o.is_sweep_override()}  # the rest is in the config
    # each key's values (a sweep's several, any other its one; the last override of a key wins, so the
    # command line's over the sweeper's params), then every combination of them: Hydra's basic sweeper
    values: dict[str, list[str]] = {}
    for o in parsed:
        key = o.get_key_element()
        if o.is_sweep_override() and not o.is_discrete_sweep():
            raise ConfigError(f"{key}: a sweep over an interval cannot be listed as jobs; give its values")
        values[key] = ([f"{key}={v}" for v in o.sweep_string_iterator()] if o.is_sweep_override()
                       else [f"{key}={o.get_value_element_as_str()}"])
    return sorted(sorted(o for o in job if o.split("=", 1)[0] in swept and not _is_volatile(o))
                  for job in itertools.product(*values.values()))


def _stable_config(cfg: Any) -> dict:
    """The resolved config without its volatile parts (resolved key by key: Hydra's own node only
    resolves inside a job)."""
    out = {k: _plain(cfg[k]) for k in cfg if k not in VOLATILE}
    if isinstance(out.get("perturb"), dict) and out["perturb"].get("seed") is None:
        del out["perturb"]  # off: a sweep from before perturbations existed keeps its fingerprint
    if isinstance(out.get("fork"), dict) and out["fork"].get("planner") == "parent":  # the default: likewise
        out["fork"] = {k: v for k, v in out["fork"].items() if k != "planner"}  # for sweeps before fork.planner
    if isinstance(out.get("sim"), dict) and "slot_memory_mb" in out["sim"]:  # a measured figure for the
        out["sim"] = {k: v for k, v in out["sim"].items() if k != "slot_memory_mb"}  # launcher, not the attempt's
    return out


def fingerprint(config: dict, jobs: list[list[str]]) -> str:
    blob = json.dumps({"config": config, "jobs": jobs}, sort_keys=True, separators=(",", ":"))
    return "sha256:" + hashlib.sha256(blob.encode()).hexdigest()


def config_diff(old: Any, new: Any, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two plain configs, with both values."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new), key=str):
            p = f"{prefix}.{k}" if prefix else str(k)
            if k not in old:
                out.append(f"{p} added ({new[k]!r})")
            elif k not in new:
                out.append(f"{p} removed (was {old[k]!r})")
            else:
                out += config_diff(old[k], new[k], p)
        return out
    return [] if old == new else [f"{prefix or '(root)'}: {old!r} -> {new!r}"]


def _jobs_diff(old: list[list[str]], new: list[list[str]]) -> list[str]:
    a, b = {" ".join(j) for j in old}, {" ".join(j) for j in new}
    out = []
    if b - a:
        out.append(f"{len(b - a)} job(s) added, e.g. [{sorted(b - a)[0]}]")
    if a - b:
        out.append(f"{len(a - b)} job(s) removed, e.g. [{sorted(a - b)[0]}]")
    return out


@dataclass
class SweepManifest:
    """The pinned configuration of one sweep directory, and where each of its jobs writes."""
    config: dict
    jobs: list[list[str]]
    path_keys: list[str]
    folders: list[str]
    #: each configuration's comparison contract (:func:`cab_core.apps.sweep_contracts.sweep_contracts`, which
    #: ``cab`` computes before opening the sweep); not part of the fingerprint
    contracts: dict | None = field(default=None, compare=False)

    @classmethod
    def from_hydra(cls, cfg: Any) -> SweepManifest:
        """The manifest of the sweep Hydra is about to launch. Raises SweepJobsCollide when two of
        its jobs would write to the same attempt folder."""
        jobs = expand_jobs(cfg)
        keys = varying_keys(jobs)
        folders = attempt_folders(cfg, jobs, keys)
        check_distinct(folders, jobs)
        return cls(_stable_config(cfg), jobs, keys, folders)

    @property
    def fingerprint(self) -> str:
        return fingerprint(self.config, self.jobs)

    def open(self, sweep_dir: Path, launcher: str) -> dict:
        """Start a session in ``sweep_dir``: lock the directory for this process (:func:`lock_sweep`),
        then write the manifest, or check it and append the session. Raises SweepBusy when another
        sweep runs there now, SweepConfigChanged, naming what changed, when the directory holds
        another sweep."""
        lock_sweep(Path(sweep_dir))
        try:
            return self._open(Path(sweep_dir), launcher)
        except BaseException:  # refused (or the manifest could not be written): nothing of this session stays
            unlock_sweep(Path(sweep_dir))
            raise

    def _open(self, sweep_dir: Path, launcher: str) -> dict:
        path = Path(sweep_dir) / MANIFEST
        now = time.time()
        if path.is_file():
            old = json.loads(path.read_text())
            if old.get("manifest_version") in OLD_LAYOUTS:
                raise SweepConfigChanged(
                    f"{sweep_dir} was written with the attempt layout {OLD_LAYOUTS[old['manifest_version']]} "
                    f"({old['manifest_version']}); this cab writes <task>/<model>/<sim>/[<swept>/]seed-<S>/"
                    "attempt-<A> and would run every attempt again. Finish it with the cab version that "
                    "started it, or start a new hydra.sweep.dir (cab-report reads both layouts).")
            if old.get("fingerprint") != self.fingerprint:
                changes = config_diff(old.get("config"), self.config) + _jobs_diff(old.get("jobs", []), self.jobs)
                raise SweepConfigChanged(
                    f"{sweep_dir} holds a sweep with another configuration ({old.get('fingerprint')}, now "
                    f"{self.fingerprint}); changed: {'; '.join(changes) or '(config resolves differently)'}. "
                    "Resume it with the same overrides, or choose a new hydra.sweep.dir.")
            manifest = old
        else:
            Path(sweep_dir).mkdir(parents=True, exist_ok=True)
            manifest = {"manifest_version": MANIFEST_VERSION, "fingerprint": self.fingerprint, "created": now,
                        "n_jobs": len(self.jobs), "jobs": self.jobs, "path_keys": self.path_keys,
                        "folders": self.folders, "config": self.config, "sessions": []}
        if "contracts" not in manifest and self.contracts is not None:  # a new sweep, or one begun before cab kept them
            manifest["contracts"] = self.contracts
        manifest["sessions"].append({"started": now, "launcher": launcher,
                                     "complete_at_start": len(completed_results(Path(sweep_dir)))})
        write_json_atomic(path, manifest)
        return manifest


def completed_results(sweep_dir: Path) -> list[Path]:
    """``result.json`` files of the sweep that count (set-aside records and infrastructure failures
    excluded). Cheap: reads each result once, no record validation."""
    out = []
    for p in Path(sweep_dir).rglob("result.json"):
        if SET_ASIDE in p.relative_to(sweep_dir).parts:
            continue
        try:
            res = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if isinstance(res, dict) and not is_infrastructure_failure(res):
            out.append(p)
    return out


def progress_line(sweep_dir: Path, job: str, what: str, result: Path | None = None) -> str:
    """One line for a finished job: counts over the whole sweep, the rate of this session, the ETA.
    The count is the rank of this job's ``result`` among the complete attempts (in the order their
    results were written, then by path): jobs that finish together each get their own number, not
    the count both see once both have finished."""
    try:
        m = json.loads((Path(sweep_dir) / MANIFEST).read_text())
    except (OSError, json.JSONDecodeError):
        return f"cab sweep: {job}: {what}"
    done = _by_completion(completed_results(Path(sweep_dir)))
    order = _finish_order(Path(sweep_dir), done)
    own = _place(Path(result), Path(sweep_dir)) if result is not None else None
    rank = order.index(own) + 1 if own in order else len(done)
    session = m["sessions"][-1]
    fresh = sum(1 for t, _ in done if t >= session["started"])
    elapsed = max(time.time() - session["started"], 1e-6)
    left = max(m["n_jobs"] - len(done), 0)
    eta = f"ETA {_hms(left * elapsed / fresh)}" if fresh and left else ("sweep complete" if not left else "ETA ?")
    rate = f"{3600 * fresh / elapsed:.0f} attempts/h, " if fresh else ""
    spend = sweep_spend(Path(sweep_dir))
    spent = f"{spend.words()} | " if spend.attempts else ""
    return f"cab sweep [{rank}/{m['n_jobs']}] {job}: {what} | {spent}{rate}{eta}"


ORDER = "progress.order"  # complete attempts, one folder a line, in the order a job first saw them


def _finish_order(sweep_dir: Path, done: list[tuple[float, Path]]) -> list[str]:
    """The complete attempts in the order they were first seen complete, under ``flock`` on
    ``progress.order``: each one keeps its place once it has one, so two jobs that finish together
    get two numbers. (A result's modification time cannot order them: ``result.json`` is written
    again when the video is closed, after the other job may have counted.) Without the file (a full
    disk, a read-only folder) the order is that of the results' modification times."""
    seen = [_place(p, sweep_dir) for _, p in done]
    try:
        with open(sweep_dir / ORDER, "a+", encoding="utf-8") as f:
            fcntl.flock(f, fcntl.LOCK_EX)
            f.seek(0)
            listed = f.read().splitlines()
            new = [s for s in seen if s not in set(listed)]
            if new:
                f.write("".join(s + "\n" for s in new))
                f.flush()
            order = listed + new
    except OSError:
        order = seen
    current = set(seen)  # an attempt set aside since it was listed no longer counts
    return [s for s in order if s in current]


def _place(result: Path, sweep_dir: Path) -> str:
    """How ``progress.order`` names a result: its path in the sweep folder (absolute if outside)."""
    here, root = result.resolve(), sweep_dir.resolve()
    return str(here.relative_to(root)) if here.is_relative_to(root) else str(here)


def _by_completion(results: list[Path]) -> list[tuple[float, Path]]:
    """(modification time in seconds, path) of each result, oldest first, ties by path."""
    out = []
    for p in results:
        try:
            out.append((p.stat().st_mtime_ns, str(p), p))
        except OSError:
            continue
    return [(ns / 1e9, p) for ns, _, p in sorted(out)]


def summary_line(sweep_dir: Path, command: str | None = None) -> str:
    """The state of a whole sweep after a session: complete, infrastructure failures, missing."""
    return sweep_summary(sweep_dir, command)[0]


def sweep_summary(sweep_dir: Path, command: str | None = None) -> tuple[str, bool]:
    """The sweep's summary line and whether every attempt is complete. An incomplete sweep's line
    ends with the command that resumes it (``command``: the one this session ran, as typed)."""
    m = json.loads((Path(sweep_dir) / MANIFEST).read_text())
    complete = len(completed_results(Path(sweep_dir)))
    infra = 0
    for p in Path(sweep_dir).rglob("result.json"):
        if SET_ASIDE not in p.relative_to(sweep_dir).parts:
            try:
                infra += is_infrastructure_failure(json.loads(p.read_text()))
            except (OSError, json.JSONDecodeError):
                pass
    missing = max(m["n_jobs"] - complete - infra, 0)
    if complete >= m["n_jobs"]:
        return f"cab sweep: {complete}/{m['n_jobs']} attempts complete; {sweep_dir}", True
    resume = f"run the same command to resume: {command}" if command else "run the same command again to resume"
    return (f"cab sweep: {complete}/{m['n_jobs']} attempts complete, {infra} given up on for infrastructure "
            f"failures (not scored), {missing} missing; {sweep_dir}; {resume}"), False


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def run_job(cfg: Any, attempt_dir: Path, sweep_dir: Path, job_log: str | None = None) -> tuple[dict | None, str]:
    """One job of a sweep: skip a complete attempt, set a partial one aside, run it supervised.
    Returns the result (None when skipped) and the progress line, which also says what could not be
    written (a full disk: the job ends with its line, the sweep with its resume line)."""
    spec = attempt_spec(cfg, attempt_dir)  # a bad config fails here, before any process starts
    identity = {"task": spec.task, "seed": spec.seed, "attempt": spec.attempt, "sim": spec.sim, "model": spec.model}
    here, root = Path(attempt_dir).resolve(), Path(sweep_dir).resolve()
    job = str(here.relative_to(root)) if here.is_relative_to(root) else str(attempt_dir)
    result_path = Path(attempt_dir) / "result.json"
    check = check_attempt(attempt_dir, identity, job_log)
    if check.state == "complete":
        if check.result is not None and unlisted_set_aside(Path(attempt_dir), check.result):  # its failures' note could not be written then
            try:
                annotate_result(attempt_dir, infrastructure_failures(Path(attempt_dir)))
            except OSError:
                pass
        return None, progress_line(sweep_dir, job, "complete already, skipped", result_path)
    try:
        if check.state == "partial":  # killed mid-attempt, or every try of an earlier session failed
            infra = check.result is not None and is_infrastructure_failure(check.result) \
                and (check.result.get("termination") or {}).get("reason") != INTERRUPTED
            set_aside(attempt_dir, GIVEN_UP if infra else INTERRUPTED, job_log)
    except OSError as e:
        return None, progress_line(sweep_dir, job, f"NOT RUN: its earlier records could not be set aside "
                                                   f"({e.strerror or e}); {RESUME_HINT}")
    plain = _plain(cfg)
    cap = (plain.get("sweep") or {}).get("max_cost_usd")
    if cap is not None:  # no new attempt once the sweep's spend (finished and in flight) has reached its cap
        spent = sweep_spend(Path(sweep_dir)).usd
        if spent >= float(cap):
            return None, progress_line(sweep_dir, job, f"NOT STARTED: the sweep has spent ${spent:.2f}, its cap "
                                                       f"sweep.max_cost_usd={cap:g} (raise it to resume)")
    sup = AttemptSupervisor(plain, attempt_dir, identity, SupervisorConfig.from_cfg(plain.get("sweep")), job_log)
    result = sup.run()
    what = describe(result)
    if sup.unwritten:
        what += f"; NOT WRITTEN ({sup.write_error}): {', '.join(sup.unwritten)}; {RESUME_HINT}"
    return result, progress_line(sweep_dir, job, what, result_path)


RESUME_HINT = "free space (or fix the folder), then run the same command again to resume"


def describe(result: dict) -> str:
    """A few words on one attempt's outcome for the progress line."""
    if is_infrastructure_failure(result):
        return f"INFRASTRUCTURE FAILURE ({result['termination']['detail']})"
    b, t = result.get("budget") or {}, result.get("timing") or {}
    retries = len((result.get("infrastructure") or {}).get("failures") or [])
    return (f"success={result['verdict'].get('success')} ({result['termination']['reason']}, "
            f"{b.get('tool_calls_used')} calls, {t.get('wall_seconds', 0):.1f} s"
            + (f", after {retries} infrastructure failure(s)" if retries else "") + ")")
