"""How the supervisor and a child process that runs attempts speak: the child's exit statuses and
the environment variable naming its supervisor (a child whose supervisor is gone exits). cab-studio's
play processes (``cab_core.apps.studio.child``) follow it too."""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
from typing import Protocol

EXIT_FAULT = 1  # the attempt's process failed (crash, unexpected exception): retried as infrastructure
EXIT_CONFIG = 2  # the configuration is wrong: never retried
EXIT_RENDERER = 3  # no renderer on this machine: never retried
PARENT_ENV = "CAB_SUPERVISOR_PID"
_PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent dies (when the thread of the parent that
    started it ends); exit at once if the parent named by :data:`PARENT_ENV` is already gone."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: the supervisor's kill on hang still applies
        pass
    expected = os.environ.get(PARENT_ENV)
    if expected and os.getppid() != int(expected):
        os._exit(EXIT_FAULT)


class ChildProcess(Protocol):
    """What the supervisor uses of a child: a ``subprocess.Popen`` or a worker forked by
    ``cab_core.sweep.zygote`` (``ForkedProcess``)."""
    pid: int
    returncode: int | None

    def poll(self) -> int | None: ...

    def wait(self, timeout: float | None = None) -> int | None: ...


def kill_group(proc: ChildProcess | subprocess.Popen) -> None:
    """SIGKILL a child and anything in its process group (it leads its own), and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):  # gone already
        pass
    proc.wait()
