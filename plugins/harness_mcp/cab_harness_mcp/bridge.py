"""Hand-over between the MCP server's event loop and the thread that owns the attempt.

The simulator, planner and recorder belong to one thread (the one that built them; see
``cab_core.simulator.Simulator``). The server runs its event loop in another thread and never
touches them: each ``tools/call`` becomes a :class:`Job` on a FIFO queue, the owner thread executes
jobs one at a time in arrival order, and the server awaits the job's future. Concurrent calls from a
client (Claude Code issues read-only calls in parallel) are therefore serialised exactly as a
sequential agent's would be, and each is charged and recorded in the order it was executed.
"""
from __future__ import annotations

import asyncio
import concurrent.futures as cf
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Job:
    """One tool call waiting for the owner thread."""
    name: str
    arguments: dict[str, Any]
    client: str | None = None
    future: cf.Future = field(default_factory=cf.Future)
    queued_at: float = field(default_factory=time.monotonic)


class CallBridge:
    """FIFO of tool calls from the server thread to the attempt's owner thread."""

    def __init__(self) -> None:
        self._jobs: queue.Queue[Job] = queue.Queue()
        self._last_activity = time.monotonic()
        self._lock = threading.Lock()

    # -- server side (event loop thread) ------------------------------------------------------
    async def call(self, name: str, arguments: dict[str, Any], client: str | None = None) -> Any:
        """Queue a call and wait for its result without blocking the event loop."""
        job = Job(name, arguments, client)
        self.touch()
        self._jobs.put(job)
        try:
            return await asyncio.wrap_future(job.future)
        finally:
            self.touch()

    def touch(self) -> None:
        """Record client activity (any request), for the idle time-out."""
        with self._lock:
            self._last_activity = time.monotonic()

    # -- owner side ---------------------------------------------------------------------------
    def next(self, timeout: float) -> Job | None:
        try:
            return self._jobs.get(timeout=timeout)
        except queue.Empty:
            return None

    def idle_seconds(self) -> float:
        with self._lock:
            return time.monotonic() - self._last_activity

    def pending(self) -> int:
        return self._jobs.qsize()
