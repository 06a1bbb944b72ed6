"""Hand-over between the MCP server's event loop and the thread that owns the attempt.

The simulator, planner and recorder belong to one thread (the one that built them; see
``cab_core.contracts.simulator.Simulator``). The server runs its event loop in another thread and never
touches them: each ``tools/call`` becomes a :class:`Job` on a FIFO queue, the owner thread executes
jobs one at a time in arrival order, and the server awaits the job's future. Concurrent calls from a
client (Claude Code issues read-only calls in parallel) are therefore serialised exactly as a
sequential agent's would be, and each is charged and recorded in the order it was executed.

The server also reports each client identity it sees (``clientInfo`` of the handshake, per MCP
session) with :meth:`CallBridge.saw`; the owner thread collects the new ones with
:meth:`CallBridge.new_clients` before it executes the next call, so a client is recorded before
its first call.
"""
from __future__ import annotations

import asyncio
import concurrent.futures as cf
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class SeenClient:
    """A client identity as the server saw it: ``clientInfo`` name and version, and the transport's
    session (the HTTP ``Mcp-Session-Id``; None on stdio, where the process serves one session)."""
    name: str
    version: str
    session: str | None = None


@dataclass
class Job:
    """One tool call waiting for the owner thread."""
    name: str
    arguments: dict[str, Any]
    client: SeenClient | None = None
    future: cf.Future = field(default_factory=cf.Future)
    queued_at: float = field(default_factory=time.monotonic)


class CallBridge:
    """FIFO of tool calls from the server thread to the attempt's owner thread."""

    def __init__(self) -> None:
        self._jobs: queue.Queue[Job] = queue.Queue()
        self._last_activity = time.monotonic()
        self._lock = threading.Lock()
        self._seen: set[SeenClient] = set()
        self._new: list[SeenClient] = []
        self._closed_answer: Any = None  # once the attempt is recorded: every later call's answer

    # -- server side (event loop thread) ------------------------------------------------------
    async def call(self, name: str, arguments: dict[str, Any], client: SeenClient | None = None) -> Any:
        """Queue a call and wait for its result without blocking the event loop; once the
        attempt is recorded (:meth:`close`), answered at once, the owner thread left alone."""
        job = Job(name, arguments, client)
        self.saw(client)
        self.touch()
        with self._lock:
            if self._closed_answer is not None:
                return self._closed_answer
            self._jobs.put(job)
        try:
            return await asyncio.wrap_future(job.future)
        finally:
            self.touch()

    def touch(self) -> None:
        """Record client activity (any request), for the idle time-out."""
        with self._lock:
            self._last_activity = time.monotonic()

    def saw(self, client: SeenClient | None) -> None:
        """Note a client identity (each distinct one is handed to the owner once)."""
        if client is None:
            return
        with self._lock:
            if client not in self._seen:
                self._seen.add(client)
                self._new.append(client)

    # -- owner side ---------------------------------------------------------------------------
    def close(self, answer: Any) -> list[Job]:
        """From now on every call is answered ``answer`` without the owner thread (which may
        render the video meanwhile); returns the calls queued before, for the owner to answer."""
        with self._lock:
            self._closed_answer = answer
        out = []
        while True:
            try:
                out.append(self._jobs.get_nowait())
            except queue.Empty:
                return out

    def next(self, timeout: float) -> Job | None:
        try:
            return self._jobs.get(timeout=timeout)
        except queue.Empty:
            return None

    def new_clients(self) -> list[SeenClient]:
        """The client identities seen since the last call, in the order first seen."""
        with self._lock:
            out, self._new = self._new, []
        return out

    def idle_seconds(self) -> float:
        with self._lock:
            return time.monotonic() - self._last_activity

    def pending(self) -> int:
        return self._jobs.qsize()
