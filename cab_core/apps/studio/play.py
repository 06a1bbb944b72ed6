"""Attempts a person plays from cab-studio: each one composed as ``cab task=<t> sim=<s> seed=<n>
model=human`` would compose it, and run by the normal runner in a thread of the studio (the thread
that builds the world owns it), its calls handed over by a :class:`cab_core.attempt.human.PlayBridge`.

A played attempt is written where a sweep would write it, below the group the person chose (the
studio's ``played`` folder by default): ``<group>/<task>/human/<sim>/seed-<S>/attempt-<N>``, ``N``
the first attempt number not yet taken there, so a sweep's report counts it as the configuration
``human (direct, <sim>)``.
"""
from __future__ import annotations

import logging
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from cab_core.attempt.human import PlayBridge, SESSIONS, register
from cab_core.errors import ConfigError

log = logging.getLogger(__name__)

PLAYED = "played"  # the group played attempts go to unless the person chooses another
HANDLE = re.compile(r"^[\w .@+-]{1,64}$")
_COMPOSE = threading.Lock()  # Hydra's compose API is process-global


@dataclass
class Play:
    id: str
    handle: str
    task: str
    sim: str
    seed: int
    attempt: int
    folder: Path  # the attempt folder
    rel: str  # the folder, relative to the studio's root
    bridge: PlayBridge
    started: float = field(default_factory=time.time)
    state: str = "building"  # building | playing | finished | failed
    error: str | None = None
    thread: threading.Thread | None = None
    images: dict[str, bytes] = field(default_factory=dict)  # the images the person was shown, by obs_id

    def status(self) -> dict:
        """What the play page may know: never the verdict (the result page shows it once ended)."""
        b = self.bridge
        if self.state == "building" and b.ready.is_set():
            self.state = "playing"
        out = {"id": self.id, "state": self.state, "handle": self.handle, "task": self.task, "sim": self.sim,
               "seed": self.seed, "attempt": self.attempt, "ready": b.ready.is_set(), "calls": b.calls,
               "budget": b.budget, "ended": b.closed.is_set(), "error": self.error}
        if self.state == "finished":
            out["attempt_url"] = f"/attempt/{self.rel}/"
        return out


def installed() -> dict:
    """The tasks and simulators a person may choose from."""
    from cab_core.plugins import registry, task_names

    return {"tasks": sorted(task_names()), "sims": sorted(registry("simulators"))}


def next_attempt(folder: Path) -> int:
    """The first ``attempt-<N>`` not taken in ``folder``."""
    n = 1
    while (folder / f"attempt-{n}").exists():
        n += 1
    return n


class Plays:
    """The play sessions of one studio. ``run``: the runner (``run_attempt``), given by the app."""

    def __init__(self, root: Path, run: Callable[[object], dict]):
        self.root = Path(root)
        self.run = run
        self.plays: dict[str, Play] = {}
        self._lock = threading.Lock()

    def get(self, pid: str) -> Play | None:
        return self.plays.get(pid)

    def playing(self, folder: Path) -> bool:
        """Whether ``folder`` is the attempt of a play not yet finished (its records stay hidden)."""
        f = Path(folder).resolve()
        return any(p.folder.resolve() == f and p.state in ("building", "playing") for p in self.plays.values())

    def start(self, task: str, sim: str, seed: int | None, handle: str, into: str = PLAYED) -> Play:
        """Compose and start one attempt; ConfigError, in one line, for a choice that is not valid."""
        from cab_core.attempt.spec import attempt_spec
        from cab_core.config import composed
        from cab_core.plugins import task_info

        choices = installed()
        handle = (handle or "").strip()
        if not HANDLE.match(handle):
            raise ConfigError("give your name or handle: 1-64 letters, digits, spaces or . @ + - _")
        if task not in choices["tasks"]:
            raise ConfigError(f"unknown task {task!r}")
        if sim not in choices["sims"]:
            raise ConfigError(f"unknown simulator {sim!r}; installed: {', '.join(choices['sims'])}")
        if seed is not None and (not isinstance(seed, int) or seed < 0):
            raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
        into = (into or PLAYED).strip("/") or PLAYED
        base = (self.root / into).resolve()
        if not base.is_relative_to(self.root.resolve()) or any(p.startswith(".") for p in Path(into).parts):
            raise ConfigError(f"{into!r} is not a folder below the studio's root")
        seed = task_info(task).seed if seed is None else seed
        bridge = PlayBridge(handle)
        with self._lock:
            parent = base / task / "human" / sim / f"seed-{seed}"
            n = next_attempt(parent)
            folder = parent / f"attempt-{n}"
            folder.mkdir(parents=True)  # taken: a second play started meanwhile gets the next number
        overrides = [f"task={task}", f"sim={sim}", "model=human", f"seed={seed}", f"attempt={n}",
                     f"model.session={bridge.id}"]
        try:
            with _COMPOSE:
                cfg = composed(overrides)
            spec = attempt_spec(cfg, folder)
        except Exception:
            folder.rmdir()
            raise
        spec.model_cfg["handle"] = handle  # recorded with the model's configuration
        register(bridge)
        rel = folder.relative_to(self.root.resolve()).as_posix()
        play = Play(bridge.id, handle, task, sim, seed, n, folder, rel, bridge)
        play.thread = threading.Thread(target=self._run, args=(play, spec), name=f"cab-play-{play.id}", daemon=True)
        self.plays[play.id] = play
        play.thread.start()
        return play

    def _run(self, play: Play, spec) -> None:
        try:
            self.run(spec)
            play.state = "finished"
        except Exception as e:  # shown on the play page; the records say what they hold
            log.exception("played attempt %s failed", play.rel)
            play.error = f"{type(e).__name__}: {e}"
            play.state = "finished" if (play.folder / "result.json").exists() else "failed"
        finally:
            play.bridge.close()
            SESSIONS.pop(play.id, None)

    def stop(self, timeout: float = 10.0) -> None:
        """End every play still running (the studio is stopping): their records are written."""
        for p in list(self.plays.values()):
            p.bridge.abandon("interrupted", "cab-studio stopped while the attempt was played")
        for p in list(self.plays.values()):
            if p.thread is not None:
                p.thread.join(timeout)
