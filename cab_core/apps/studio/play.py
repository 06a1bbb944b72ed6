"""Attempts a person plays from cab-studio: each one composed as ``cab task=<t> sim=<s> seed=<n>
model=human`` would compose it, and run by the normal runner in a child process of its own
(:mod:`cab_core.apps.studio.child`, started as a sweep starts its children: the plain resolved config
on stdin, dying with the studio), its calls handed over by a :class:`cab_core.attempt.engine.human.PlayBridge`
over a connection only the two of them hold (a socket pair). A thread of the studio per play starts
that process, reads what it sends and waits for it.

A crash loses at most the attempt in flight: when a play's process dies before its attempt ended (a
segfault in a simulator's native code, ``os._exit``, the kernel's OOM killer, a kill), the studio and
its other plays go on; that play's waiting and later calls are answered that the simulator process
ended unexpectedly (:func:`cab_core.attempt.engine.human.crash_error`), and it is ``failed`` with that
error, or ``finished`` if its ``result.json`` was written. Stopping the studio abandons every play
(recorded as ``interrupted``) and waits for their processes, killing one that does not end in time.

A played attempt is written where a sweep would write it, below the group the person chose (the
studio's ``played`` folder by default): ``<group>/<task>/human/<sim>/seed-<S>/attempt-<N>``, ``N``
the first attempt number not yet taken there, so a sweep's report counts it as the configuration
``human (direct, <sim>)``.
"""
from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from multiprocessing import Pipe
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from cab_core.attempt.engine.human import PlayBridge, crash_error
from cab_core.attempt.spec import attempt_spec
from cab_core.config import composed
from cab_core.errors import ConfigError
from cab_core.plugins import registry, task_info, task_names
from cab_core.sweep.protocol import PARENT_ENV, kill_group

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
    thread: threading.Thread | None = None  # starts the play's process, reads from it, waits for it
    proc: subprocess.Popen | None = None  # the play's process
    pid: int | None = None
    exit_code: int | None = None  # the process's exit status once it ended (negative: the signal)
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
    return {"tasks": sorted(task_names()), "sims": sorted(registry("simulators"))}


def next_attempt(folder: Path) -> int:
    """The first ``attempt-<N>`` not taken in ``folder``."""
    n = 1
    while (folder / f"attempt-{n}").exists():
        n += 1
    return n


class Plays:
    """The play sessions of one studio, each attempt in a process of its own."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.plays: dict[str, Play] = {}
        self._lock = threading.Lock()

    def get(self, pid: str) -> Play | None:
        return self.plays.get(pid)

    def playing(self, folder: Path) -> bool:
        """Whether ``folder`` is the attempt of a play not yet finished (its records stay hidden)."""
        f = Path(folder).resolve()
        return any(p.folder.resolve() == f and p.state in ("building", "playing") for p in self.plays.values())

    def start(self, task: str, sim: str, seed: int | None, handle: str, into: str = PLAYED) -> Play:
        """Compose and start one attempt; ConfigError, in one line, for a choice that is not valid.
        Returns once its process is started (``play.pid``)."""
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
                config: Any = OmegaConf.to_container(composed(overrides), resolve=True)  # a dict: composed is one
            config["model"]["handle"] = handle  # recorded with the model's configuration
            attempt_spec(config, folder)  # a choice that is not valid is refused here, not in the process
        except Exception:
            folder.rmdir()
            raise
        rel = folder.relative_to(self.root.resolve()).as_posix()
        play = Play(bridge.id, handle, task, sim, seed, n, folder, rel, bridge)
        job = {"config": config, "output_dir": str(folder), "session": bridge.id, "handle": handle}
        started = threading.Event()
        # the process is started by the thread that waits for it: PR_SET_PDEATHSIG fires when the
        # thread that started a process ends, so not by the request's (pooled) thread
        play.thread = threading.Thread(target=self._run, args=(play, job, started), name=f"cab-play-{play.id}",
                                       daemon=True)
        self.plays[play.id] = play
        play.thread.start()
        started.wait()
        return play

    def _run(self, play: Play, job: dict, started: threading.Event) -> None:
        bridge = play.bridge
        ours = None
        try:
            try:
                ours, theirs = Pipe()  # a socket pair: the studio's end, the play's end
                try:
                    play.proc = subprocess.Popen(
                        [sys.executable, "-m", "cab_core.apps.studio.child", str(theirs.fileno())],
                        stdin=subprocess.PIPE, pass_fds=(theirs.fileno(),), start_new_session=True,
                        env={**os.environ, PARENT_ENV: str(os.getpid())})  # its output: the studio's
                finally:
                    theirs.close()  # only the play's process holds it now: it closes when that exits
                play.pid = play.proc.pid
                bridge.attach(ours)
            finally:
                started.set()
            try:
                stdin = play.proc.stdin
                assert stdin is not None, "started with stdin=PIPE"
                stdin.write(json.dumps(job).encode())
                stdin.close()
            except BrokenPipeError:  # it died at once; its exit status says so
                pass
            bridge.serve()  # until the process's end of the connection closes
            play.exit_code = play.proc.wait()
        except Exception as e:  # noqa: BLE001 (it could not be started, or the studio lost it: it is ended)
            log.exception("played attempt %s: the studio lost its process", play.rel)
            play.error = f"{type(e).__name__}: {e}"
            if play.proc is not None:
                kill_group(play.proc)
                play.exit_code = play.proc.returncode
        finally:
            if ours is not None:
                bridge.disconnect()
            self._ended(play)

    def _ended(self, play: Play) -> None:
        """The play's process is gone: what the play, its page and its calls say now."""
        bridge, code = play.bridge, play.exit_code
        if play.error is None and bridge.failure is not None:  # the attempt's run raised: the process said what
            play.error = bridge.failure
        elif play.error is None and code != 0:  # it died: a crash, a kill, the OOM killer
            play.error = crash_error(code)
            log.error("played attempt %s: %s", play.rel, play.error)
        if bridge.failure is None and play.error is not None:
            bridge.fail(play.error)  # the calls waiting, and later ones, are told (unless the attempt had ended)
        else:
            bridge.close()
        play.state = "finished" if (play.folder / "result.json").exists() else "failed"
        if play.state == "failed" and play.error is None:
            play.error = "the attempt's process ended without writing result.json"

    def stop(self, timeout: float = 30.0) -> None:
        """End every play still running (the studio is stopping): their records are written. A play's
        process that has not ended ``timeout`` s later is killed."""
        for p in list(self.plays.values()):
            p.bridge.abandon("interrupted", "cab-studio stopped while the attempt was played")
        deadline = time.monotonic() + timeout
        for p in list(self.plays.values()):
            if p.thread is None:
                continue
            p.thread.join(max(0.0, deadline - time.monotonic()))
            if p.thread.is_alive() and p.proc is not None:
                log.warning("played attempt %s did not end in %g s; killed", p.rel, timeout)
                kill_group(p.proc)
                p.thread.join(10)

