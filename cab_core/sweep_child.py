"""The process that runs one attempt of a sweep, under ``cab_core.sweep_supervisor``.

Reads ``{"config": <plain resolved config>, "output_dir": <attempt dir>}`` as JSON on stdin, runs the
attempt and exits. The exit status tells the supervisor what happened:

    0  the attempt finished and wrote result.json
    2  a configuration problem (bad config, missing plugin or dependency): retrying cannot help
    3  no renderer could start (a diagnosis, not a transient fault)
    1  anything else: a fault of the host, retried as an infrastructure failure

The child dies with its supervisor (``PR_SET_PDEATHSIG``), so a killed worker leaves no orphan
writing into an attempt directory that a resumed sweep is about to reuse.
"""
from __future__ import annotations

import ctypes
import json
import os
import signal
import sys
from pathlib import Path

EXIT_CONFIG = 2
EXIT_RENDERER = 3
EXIT_FAULT = 1
PARENT_ENV = "CAB_SUPERVISOR_PID"
_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent dies; exit if it already has."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: the supervisor's kill on hang still applies
        pass
    expected = os.environ.get(PARENT_ENV)
    if expected and os.getppid() != int(expected):
        os._exit(EXIT_FAULT)


def main() -> int:
    _die_with_parent()
    from .errors import ConfigError, MissingDependency, PluginError, RendererUnavailable
    from .runner import attempt_spec, run_attempt

    job = json.loads(sys.stdin.read())
    try:
        run_attempt(attempt_spec(job["config"], Path(job["output_dir"])))
    except RendererUnavailable as e:
        print(f"cab: renderer unavailable: {e}", file=sys.stderr)
        return EXIT_RENDERER
    except (ConfigError, MissingDependency, PluginError) as e:
        print(f"cab: {type(e).__name__}: {e}", file=sys.stderr)
        return EXIT_CONFIG
    return 0


if __name__ == "__main__":
    sys.exit(main())
