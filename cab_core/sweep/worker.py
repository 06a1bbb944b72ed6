"""The process that runs attempts of a sweep, under ``cab_core.sweep.supervisor``.

One attempt: reads ``{"config": <plain resolved config>, "output_dir": <attempt dir>}`` as JSON on
stdin, runs the attempt and exits. A warm worker (``--worker``): reads such jobs one JSON line at a
time, each with ``"log"``, the file its output goes to, and answers each on its standard output with
one JSON line ``{"status": S, "rss_mb": M}`` (with ``"error"``, one line, when an exception ended
the attempt); the renderer (its device, its precomputed tables,
compiled pipelines) and the imported plugins live on from one attempt to the next, each attempt
builds its world fresh. The status, or the one-attempt process's exit status:

    0  the attempt finished and wrote result.json
    2  a configuration problem (bad config, missing plugin or dependency): retrying cannot help
    3  no renderer could start (a diagnosis, not a transient fault)
    1  anything else: a fault of the host, retried as an infrastructure failure

A worker leaves after any status but 0 (the next attempt gets a fresh process) and when its input
ends.

The child dies with its supervisor (``PR_SET_PDEATHSIG``), so a killed worker leaves no orphan
writing into an attempt directory that a resumed sweep is about to reuse.
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from cab_core.errors import ConfigError, MissingDependency, PluginError, RendererUnavailable
from cab_core.sweep.protocol import EXIT_CONFIG, EXIT_FAULT, EXIT_RENDERER, die_with_parent


def run(job: dict) -> int:
    """Run one job's attempt; the status above (exceptions other than configuration and renderer
    problems propagate)."""
    # after main() has set PR_SET_PDEATHSIG: a supervisor killed while the engine, Hydra and the plugins
    # import (about 1 s) leaves no orphan behind
    from cab_core.attempt.runner import attempt_spec, run_attempt

    try:
        run_attempt(attempt_spec(job["config"], Path(job["output_dir"])))
    except RendererUnavailable as e:
        print(f"cab: renderer unavailable: {e}", file=sys.stderr)
        return EXIT_RENDERER
    except (ConfigError, MissingDependency, PluginError) as e:
        print(f"cab: {type(e).__name__}: {e}", file=sys.stderr)
        return EXIT_CONFIG
    return 0


def release() -> None:
    """Free what the attempt just run left behind. Its world (episode, simulator and its native model
    and data, renderer buffers, video writer) is held in reference cycles that only the cyclic
    collector frees, and a full collection comes rarely: without one after each attempt a warm worker
    kept several attempts' worlds alive and grew by about 5 MiB per attempt. Then the C heap's free
    pages go back to the system (glibc's ``malloc_trim``; nothing elsewhere)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


def _rss_mb() -> float:
    """This process's resident memory now (not its peak), in MiB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _output_to(fd: int) -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(fd, 1)
    os.dup2(fd, 2)


def serve() -> int:
    """The warm worker's loop (see the module's docstring)."""
    import traceback

    replies = os.fdopen(os.dup(1), "w", buffering=1)
    quiet = os.open(os.devnull, os.O_WRONLY)
    _output_to(quiet)  # between attempts nothing is anyone's log
    for line in sys.stdin:
        if not line.strip():
            continue
        job = json.loads(line)
        log = os.open(job["log"], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        _output_to(log)
        os.close(log)
        error = None
        try:
            status = run(job)
        except Exception as e:  # noqa: BLE001 (a host fault: reported, and this process leaves)
            # in the reply too: a full disk may refuse the log
            error = " ".join(f"{type(e).__name__}: {e}".split())[:500]
            try:
                traceback.print_exc()
            except OSError:
                pass
            status = EXIT_FAULT
        finally:
            release()
            try:
                _output_to(quiet)
            except OSError:  # (flushing into a full disk)
                os.dup2(quiet, 1)
                os.dup2(quiet, 2)
        reply: dict[str, object] = {"status": status, "rss_mb": round(_rss_mb(), 1)}
        if error is not None:
            reply["error"] = error
        replies.write(json.dumps(reply) + "\n")
        if status != 0:
            return status
    return 0


def main() -> int:
    die_with_parent()
    if sys.argv[1:] == ["--worker"]:
        return serve()
    return run(json.loads(sys.stdin.read()))


if __name__ == "__main__":
    sys.exit(main())
