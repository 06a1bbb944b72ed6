"""Rate and concurrency limits shared by every process that uses one credential on this machine.

A sweep's workers are separate processes (any launcher of one machine); a provider's limits are per
credential. :class:`Limiter` keeps the state of one credential in a small file under
``fcntl.flock``, in a directory every process of the user sees (:func:`state_dir`):

* requests per minute and tokens per minute (input + output tokens, cache reads and writes
  included): a sliding log of the requests of the last window, each with its tokens. A request
  reserves its place (and an estimate of its tokens) before it is sent and settles the real usage
  after; its place is the earliest time at which no window holds more than the limits. The log is
  stricter than a provider's token bucket (which refills continuously), so it never exceeds one.
* ``Retry-After``: a 429's pause is written to the state (:meth:`Limiter.pause`), and every process
  sharing the credential waits for it before its next request, not only the one that got it.
* concurrency per provider endpoint: ``max_concurrent`` slot files; a request in flight holds one
  slot's ``flock``; a process that finds none free blocks in ``flock`` on one of them.

Waiting never spins: a process sleeps until the moment its reservation falls due, or blocks in the
kernel on a slot's lock. The time waited is measured (:attr:`Limiter.waited_s`). The key of a
credential is the provider, the endpoint and a hash of the key's value (:func:`credential_key`);
the key itself is never written.
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from cab_core.errors import ConfigError

T = TypeVar("T")

#: the environment variable that moves the state directory (default: the temporary directory)
DIR_ENV = "CAB_LIMITS_DIR"
KEYS = ("requests_per_minute", "tokens_per_minute", "max_concurrent")


def state_dir(directory: str | os.PathLike | None = None) -> Path:
    """Where the limits' state lives: ``directory``, else ``$CAB_LIMITS_DIR``, else
    ``<tempdir>/cab-limits-<uid>`` (one per user and machine; created mode 0700)."""
    d = Path(directory or os.environ.get(DIR_ENV) or Path(tempfile.gettempdir()) / f"cab-limits-{os.getuid()}")
    d.mkdir(mode=0o700, parents=True, exist_ok=True)
    return d


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)[:40] or "provider"


def credential_key(provider: str, endpoint: str | None, key_value: str | None) -> str:
    """``<provider>-<hash>``: the hash of the provider, the endpoint and a hash of the key's value
    (``None`` for a server without a key). Two workers with the same key share one state."""
    secret = hashlib.sha256((key_value or "").encode()).hexdigest()
    digest = hashlib.sha256(f"{provider}\0{endpoint or ''}\0{secret}".encode()).hexdigest()[:20]
    return f"{_safe(provider)}-{digest}"


def endpoint_key(provider: str, endpoint: str | None) -> str:
    """``<provider>-<hash of the endpoint>``: the key of a provider endpoint's concurrency slots."""
    return f"{_safe(provider)}-{hashlib.sha256((endpoint or '').encode()).hexdigest()[:20]}"


@dataclass(frozen=True)
class LimitSettings:
    """A model's ``limits`` block: each a positive integer or null (no limit). ``window_s`` is the
    length of the window the per-minute limits count over (60; tests scale it down); ``margin_s``
    widens it, for the delay between a request's release here and its arrival at the server."""
    requests_per_minute: int | None = None
    tokens_per_minute: int | None = None
    max_concurrent: int | None = None
    window_s: float = 60.0
    margin_s: float = 1.0

    @classmethod
    def from_cfg(cls, cfg: dict | None, where: str = "model.limits") -> LimitSettings:
        cfg = dict(cfg or {})
        unknown = sorted(set(cfg) - set(KEYS) - {"window_s", "margin_s"})
        if unknown:
            raise ConfigError(f"{where}: unknown key {unknown[0]!r} (valid: {', '.join(KEYS)})")
        vals: dict[str, Any] = {}
        for k in KEYS:
            v = cfg.get(k)
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise ConfigError(f"{where}.{k}={v!r}: must be a positive integer or null (no limit)")
            vals[k] = v
        for k in ("window_s", "margin_s"):
            if cfg.get(k) is not None:
                v = cfg[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0 or (k == "window_s" and v == 0):
                    raise ConfigError(f"{where}.{k}={v!r}: must be a positive number of seconds")
                vals[k] = float(v)
        return cls(**vals)

    @property
    def active(self) -> bool:
        return any(getattr(self, k) is not None for k in KEYS)


@contextmanager
def _locked(path: Path) -> Iterator[int]:
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # blocks in the kernel; held for a read-modify-write only
        yield fd
    finally:
        os.close(fd)  # closing releases the lock


def _read(fd: int) -> dict:
    os.lseek(fd, 0, os.SEEK_SET)
    raw = b""
    while chunk := os.read(fd, 1 << 16):
        raw += chunk
    try:
        state = json.loads(raw) if raw.strip() else {}
    except ValueError:  # a state file cut short (a crash mid-write): start afresh
        state = {}
    return state if isinstance(state, dict) else {}


def _write(fd: int, state: dict) -> None:
    data = json.dumps(state, separators=(",", ":")).encode()
    os.lseek(fd, 0, os.SEEK_SET)
    os.ftruncate(fd, 0)
    os.write(fd, data)


class Grant:
    """A request's place in the log: :meth:`settle` replaces its estimated tokens with the real ones."""

    def __init__(self, limiter: Limiter, entry_id: str | None, estimated_tokens: int):
        self.limiter = limiter
        self.entry_id = entry_id
        self.estimated_tokens = estimated_tokens
        self.settled: int | None = None

    def settle(self, tokens: int) -> None:
        if self.entry_id is not None and self.settled is None:
            self.limiter._settle(self.entry_id, int(tokens))
        self.settled = int(tokens)


class Limiter:
    """The limits of one credential (``key``, :func:`credential_key`) and of one provider endpoint
    (``slots_key``, :func:`endpoint_key`), shared through files under ``directory``.

    ``with limiter.request(estimated_tokens) as grant: ...; grant.settle(used)`` waits for a
    concurrency slot and for the request's place under the per-minute limits and any pause, and
    holds the slot until the block ends. :meth:`call` does that around a function."""

    def __init__(self, key: str, settings: LimitSettings, directory: str | os.PathLike | None = None,
                 slots_key: str | None = None, *, clock: Callable[[], float] = time.time,
                 sleep: Callable[[float], None] = time.sleep):
        self.key = key
        self.settings = settings
        self.dir = state_dir(directory)
        self.slots_key = slots_key or key
        self.clock = clock
        self.sleep = sleep
        self.waited_s = 0.0  # time this process spent waiting on limits (slots, log, pauses)
        self._n = 0
        #: for a caller whose requests are sent deeper down (a provider's retry loop): the tokens the
        #: next request reserves, and the grant of the last one admitted, to settle
        self.estimate = 0
        self.last_grant: Grant | None = None

    @property
    def state_path(self) -> Path:
        return self.dir / f"{self.key}.json"

    # -- the sliding log -----------------------------------------------------------------------
    def _due(self, state: dict, now: float, tokens: int) -> float:
        """The earliest time at or after ``now`` at which a request of ``tokens`` keeps every window
        within the limits, given the log (which may hold reservations in the future)."""
        s = self.settings
        w = s.window_s + s.margin_s
        log = state.get("log", [])
        t = max(now, float(state.get("paused_until", 0.0)))
        if log:
            t = max(t, float(log[-1][0]))  # places are handed out in order: the log stays sorted
        rpm = s.requests_per_minute
        if rpm is not None and len(log) >= rpm:
            t = max(t, float(log[-rpm][0]) + w)
        tpm = s.tokens_per_minute
        if tpm is not None:
            need = min(tokens, tpm)  # a request larger than the whole limit goes alone in its window
            total = sum(int(e[1]) for e in log if float(e[0]) > t - w)
            for e in log:  # oldest first: how long until enough of the window has expired
                if total + need <= tpm:
                    break
                if float(e[0]) > t - w:
                    t = max(t, float(e[0]) + w)
                    total -= int(e[1])
        return t

    def _reserve(self, tokens: int) -> tuple[str | None, float]:
        """Reserve a place in the log; returns its id and the time it falls due."""
        s = self.settings
        if s.requests_per_minute is None and s.tokens_per_minute is None:
            with _locked(self.state_path) as fd:  # only a Retry-After pause can apply
                return None, float(_read(fd).get("paused_until", 0.0))
        with _locked(self.state_path) as fd:
            state = _read(fd)
            now = self.clock()
            w = s.window_s + s.margin_s
            state["log"] = [e for e in state.get("log", []) if float(e[0]) > now - w]
            due = self._due(state, now, tokens)
            self._n += 1
            entry_id = f"{os.getpid()}.{id(self)}.{self._n}"
            state["log"].append([due, int(tokens), entry_id])
            _write(fd, state)
        return entry_id, due

    def _settle(self, entry_id: str, tokens: int) -> None:
        with _locked(self.state_path) as fd:
            state = _read(fd)
            for e in state.get("log", []):
                if e[2] == entry_id:
                    e[1] = int(tokens)
                    break
            _write(fd, state)

    def pause(self, seconds: float) -> None:
        """A server's ``Retry-After``: no process sharing this credential sends a request for
        ``seconds`` from now (a later pause wins over an earlier one)."""
        with _locked(self.state_path) as fd:
            state = _read(fd)
            state["paused_until"] = max(float(state.get("paused_until", 0.0)), self.clock() + max(0.0, seconds))
            _write(fd, state)

    def wait_for_pause(self) -> float:
        """Sleep until a pause written by any process has passed; returns the seconds waited."""
        waited = 0.0
        while True:
            with _locked(self.state_path) as fd:
                until = float(_read(fd).get("paused_until", 0.0))
            delay = until - self.clock()
            if delay <= 0:
                break
            self.sleep(delay)
            waited += delay
        self.waited_s += waited
        return waited

    # -- concurrency slots ---------------------------------------------------------------------
    @contextmanager
    def _slot(self) -> Iterator[None]:
        n = self.settings.max_concurrent
        if n is None:
            yield
            return
        d = self.dir / f"{self.slots_key}.slots"
        d.mkdir(mode=0o700, exist_ok=True)
        fds = []
        held = None
        try:
            for i in range(n):  # a free slot, without waiting
                fd = os.open(d / str(i), os.O_RDWR | os.O_CREAT, 0o600)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as e:
                    os.close(fd)
                    if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                        raise
                    continue
                held = fd
                break
            if held is None:  # all taken: block in the kernel on one, chosen in turn among the waiters
                with _locked(d / "turn") as tfd:
                    turn = _read(tfd).get("next", 0)
                    _write(tfd, {"next": (int(turn) + 1) % n})
                held = os.open(d / str(int(turn) % n), os.O_RDWR | os.O_CREAT, 0o600)
                t0 = time.monotonic()
                fcntl.flock(held, fcntl.LOCK_EX)
                self.waited_s += time.monotonic() - t0
            fds.append(held)
            yield
        finally:
            for fd in fds:
                os.close(fd)

    # -- one request ---------------------------------------------------------------------------
    def admit(self, estimated_tokens: int = 0) -> Grant:
        """Wait for a place under the per-minute limits and any pause (no slot); the returned
        grant settles the request's real tokens. A retry of a request is admitted again."""
        while True:
            entry_id, due = self._reserve(max(0, int(estimated_tokens)))
            delay = due - self.clock()
            if delay > 0:
                self.sleep(delay)
                self.waited_s += delay
            if entry_id is None:  # no per-minute limit: only a pause can hold the request
                self.wait_for_pause()
                break
            # a pause written while this process slept (another worker's 429) applies to it too
            with _locked(self.state_path) as fd:
                state = _read(fd)
                if float(state.get("paused_until", 0.0)) <= self.clock():
                    break
                state["log"] = [e for e in state.get("log", []) if e[2] != entry_id]  # give the place back
                _write(fd, state)
        return Grant(self, entry_id, int(estimated_tokens))

    @contextmanager
    def request(self, estimated_tokens: int = 0) -> Iterator[Grant]:
        """Hold a concurrency slot and a place under the limits for one request (see the class)."""
        with self._slot():
            yield self.admit(estimated_tokens)

    def call(self, fn: Callable[[], T], estimated_tokens: int = 0,
             used_tokens: Callable[[T], int] | None = None) -> T:
        """``fn()`` inside :meth:`request`; the grant is settled with ``used_tokens(result)``."""
        with self.request(estimated_tokens) as grant:
            result = fn()
            if used_tokens is not None:
                grant.settle(used_tokens(result))
            return result
