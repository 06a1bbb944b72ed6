"""What cab-studio shows of a tree of records: the groups of attempts below a directory and the
progress of each, read from the files alone (never a simulator, never a running process).

A *group* is a sweep (a folder holding ``sweep.json``: its planned jobs and where each writes) or a
folder of loose attempts (every attempt folder not inside a sweep, grouped by the first folder below
the root that holds it; attempts directly in the root form the group ``.``). Attempt folders are
found as :func:`cab_core.analysis.attempts.attempt_dirs` finds them (hidden folders, set-aside
records and recoverability forks skipped). Each attempt is

* ``done``: ``result.json`` holds a verdict (``success`` says which);
* ``infra``: ``result.json`` of an attempt that is not scored (``why`` says why): the sweep gave up on
  it for infrastructure failures, it ended on one (a provider outage), or it was interrupted;
* ``running``: ``events.jsonl`` without ``result.json`` (``stale`` when the log has not grown for
  :data:`STALE_S`: an attempt killed mid-way looks the same);

and a planned job of a sweep without any records yet is ``not started``. The ETA of a sweep that is
running comes from the completion times of its current session (as ``cab -m`` prints it): the
attempts finished since the session started, over the time since then, for those left.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from cab_core.analysis.attempts import FORKS_FOLDER, attempt_dirs
from cab_core.analysis.configurations import configuration_labels
from cab_core.sweep.attempt_state import SET_ASIDE, is_infrastructure_failure
from cab_core.sweep.manifest import MANIFEST

STALE_S = 600.0  # a running attempt whose event log has not grown for this long is marked stale
SKIP = (SET_ASIDE, FORKS_FOLDER)


@dataclass
class AttemptState:
    rel: str  # relative to the group's folder
    state: str  # done | infra | running
    success: bool | None = None
    config: str = ""
    task: str = ""
    updated: float = 0.0  # mtime of result.json (done, infra) or events.jsonl (running)
    stale: bool = False
    why: str = ""  # infra: why the attempt is not scored (its termination reason and detail)
    #: model, harness, sim and model_cfg, which name the configuration among the group's attempts as
    #: cab-report names it (cab_core.analysis.configurations); not shown
    identity: dict = field(default_factory=dict, repr=False)


@dataclass
class Group:
    rel: str  # relative to the studio's root ("." for the root itself)
    kind: str  # sweep | folder
    planned: int | None = None  # the sweep's jobs; None for a folder
    done: int = 0
    success: int = 0
    running: int = 0
    infra: int = 0
    not_started: int = 0
    extra: int = 0  # attempts of a sweep's folder that its manifest does not plan (played ones, forks...)
    eta_s: float | None = None
    updated: float = 0.0
    attempts: list[AttemptState] = field(default_factory=list)

    def as_dict(self, attempts: bool = True) -> dict:
        d = asdict(self)
        if not attempts:
            d.pop("attempts")
        for a in d.get("attempts", []):
            a.pop("identity", None)
        return d


def _walk(root: Path):
    """(sweep folders, loose attempt folders) below root, both sorted."""
    sweeps, loose = [], []
    for d, dirs, files in os.walk(root):
        dirs[:] = sorted(x for x in dirs if not x.startswith(".") and x not in SKIP)
        if MANIFEST in files:
            sweeps.append(Path(d))
            dirs[:] = []
        elif "result.json" in files or "events.jsonl" in files:
            loose.append(Path(d))
            dirs[:] = []
    return sweeps, loose


def _rel(path: Path, root: Path) -> str:
    return os.path.relpath(path, root).replace(os.sep, "/")


def _start(d: Path) -> dict:
    """The attempt's ``attempt_start`` event (the first line of its log), ``{}`` where unreadable."""
    try:
        with open(d / "events.jsonl") as f:
            start = json.loads(f.readline() or "{}")
    except (OSError, ValueError):
        return {}
    return start if isinstance(start, dict) else {}


def attempt_state(d: Path, rel: str, now: float) -> AttemptState:
    res = d / "result.json"
    if res.is_file():
        try:
            r = json.loads(res.read_text())
        except (OSError, ValueError):
            r = None
        mtime = res.stat().st_mtime
        if not isinstance(r, dict):
            return AttemptState(rel, "done", None, "(unreadable result.json)", "", mtime)
        config = f"{r.get('model')} ({r.get('harness')}, {r.get('sim')})"
        if is_infrastructure_failure(r):
            t = r.get("termination") or {}
            why = f"{(r.get('verdict') or {}).get('excluded') or t.get('reason')}: {t.get('detail') or ''}".strip(": ")
            return AttemptState(rel, "infra", None, config, str(r.get("task", "")), mtime, why=why)
        success = (r.get("verdict") or {}).get("success")
        c = _start(d).get("config")
        identity = {"model": r.get("model"), "harness": r.get("harness"), "sim": r.get("sim"), "task": r.get("task"),
                    "model_cfg": c.get("model_cfg") if isinstance(c, dict) else None}
        return AttemptState(rel, "done", bool(success), config, str(r.get("task", "")), mtime, identity=identity)
    ev = d / "events.jsonl"
    try:
        mtime = ev.stat().st_mtime
    except OSError:
        mtime = 0.0
    config, task, identity = "", "", {}
    start = _start(d)
    c = start.get("config")
    if isinstance(c, dict):
        config, task = f"{c.get('model', '?')} ({c.get('harness', '?')}, {c.get('sim', '?')})", str(start.get("task", ""))
        identity = {k: c.get(k) for k in ("model", "harness", "sim", "task", "model_cfg")}
    return AttemptState(rel, "running", None, config, task, mtime, stale=now - mtime > STALE_S, identity=identity)


def _count(g: Group, states: list[AttemptState]) -> None:
    named = [a for a in states if a.identity]  # scored and running attempts, named as cab-report names them
    for a, label in zip(named, configuration_labels([a.identity for a in named])):
        a.config = label
    g.attempts = states
    for a in states:
        if a.state == "done":
            g.done += 1
            g.success += bool(a.success)
        elif a.state == "infra":
            g.infra += 1
        else:
            g.running += 1
        g.updated = max(g.updated, a.updated)


def sweep_group(sweep: Path, root: Path, now: float | None = None) -> Group:
    """A sweep's progress against its manifest (planned jobs, each job's folder)."""
    now = time.time() if now is None else now
    try:
        m = json.loads((sweep / MANIFEST).read_text())
    except (OSError, ValueError):
        m = {}
    folders = [str(f).strip("/") for f in (m.get("folders") or [])]
    planned = m.get("n_jobs") if isinstance(m.get("n_jobs"), int) else len(folders)
    g = Group(_rel(sweep, root), "sweep", planned)
    g.updated = (sweep / MANIFEST).stat().st_mtime if (sweep / MANIFEST).exists() else 0.0
    states = [attempt_state(d, rel, now) for d, rel, _ in attempt_dirs(sweep) if rel != "."]
    _count(g, states)
    seen = {a.rel for a in states}
    g.extra = len(seen - set(folders)) if folders else 0
    in_plan = len(seen & set(folders)) if folders else len(seen)
    g.not_started = max(0, (planned or 0) - in_plan)
    sessions = m.get("sessions") or []
    started = sessions[-1].get("started") if sessions and isinstance(sessions[-1], dict) else None
    planned_running = sum(1 for a in states if a.state == "running" and (not folders or a.rel in folders))
    if planned_running and isinstance(started, (int, float)):  # only the planned jobs: a played attempt is no job
        fresh = sum(1 for a in states if a.state in ("done", "infra") and a.updated >= started
                    and (not folders or a.rel in folders))
        left = g.not_started + planned_running
        if fresh:
            g.eta_s = left * max(now - started, 1e-6) / fresh
    return g


def folder_group(rel: str, dirs: list[Path], root: Path, now: float | None = None) -> Group:
    now = time.time() if now is None else now
    base = root if rel == "." else root / rel
    g = Group(rel, "folder")
    _count(g, [attempt_state(d, _rel(d, base), now) for d in dirs])
    return g


def groups(root: Path, now: float | None = None) -> list[Group]:
    """Every group below ``root``: the sweeps, then the folders of loose attempts, by path."""
    root = Path(root)
    now = time.time() if now is None else now
    sweeps, loose = _walk(root)
    out = [sweep_group(s, root, now) for s in sweeps]
    by: dict[str, list[Path]] = {}
    for d in loose:
        rel = _rel(d, root)
        parts = rel.split("/")
        by.setdefault("." if rel == "." or len(parts) == 1 else parts[0], []).append(d)
    out += [folder_group(rel, ds, root, now) for rel, ds in by.items()]
    return sorted(out, key=lambda g: g.rel)


def group(root: Path, rel: str, now: float | None = None) -> Group | None:
    """The group at ``rel`` (a sweep folder, or a folder of loose attempts), None if there is none."""
    for g in groups(root, now):
        if g.rel == rel:
            return g
    return None


def signature(folder: Path) -> list:
    """What changes when an attempt below ``folder`` starts, grows or finishes (for caches)."""
    out = []
    for d, rel, finished in attempt_dirs(folder):
        p = d / ("result.json" if finished else "events.jsonl")
        try:
            st = p.stat()
            out.append((rel, finished, st.st_mtime_ns, st.st_size))
        except OSError:
            pass
    return out
