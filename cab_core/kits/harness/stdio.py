"""Reserving stdin/stdout for a protocol (the MCP harness over stdio).

A protocol on stdout must own it: simulators, renderers, Hydra and loggers print there, some from
C. :func:`claim` keeps private duplicates of fd 0 and fd 1 for the protocol and points fd 1 at
stderr and fd 0 at the null device, so anything else written to "stdout" lands on stderr and nothing
else reads the client's frames. The CLI claims as soon as it knows the protocol is wanted (before
Hydra starts); a harness calls :func:`claim` again and gets the same channel. The descriptors are a
process-wide resource, so the claim is too.
"""
from __future__ import annotations

import fcntl
import os
import sys
import threading
from dataclasses import dataclass


@dataclass(frozen=True)
class StdioChannel:
    """The protocol's private descriptors (close-on-exec, above the standard range)."""
    in_fd: int
    out_fd: int


_lock = threading.Lock()
_channel: StdioChannel | None = None


def _dup_private(fd: int) -> int:
    return fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 3)


def claim() -> StdioChannel:
    """Take fd 0/1 for the protocol (once per process; later calls return the same channel)."""
    global _channel
    with _lock:
        if _channel is None:
            sys.stdout.flush()
            channel = StdioChannel(_dup_private(0), _dup_private(1))
            devnull = os.open(os.devnull, os.O_RDONLY)
            try:
                os.dup2(devnull, 0)
            finally:
                os.close(devnull)
            os.dup2(2, 1)
            _channel = channel
        return _channel


def claimed() -> StdioChannel | None:
    return _channel
