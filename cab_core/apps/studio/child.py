"""The process that runs one attempt a person plays from cab-studio (:mod:`.play` starts it).

It follows a sweep's child (:mod:`cab_core.sweep.child`, :mod:`cab_core.sweep.protocol`): it reads
its job as JSON on stdin, ``{"config": <plain resolved config>, "output_dir": <attempt dir>,
"session": <id>, "handle": <the person's>}``, and dies with the studio (``PR_SET_PDEATHSIG``). Its
one argument is the file descriptor of its end of a :class:`multiprocessing.connection.Connection`
(a socket pair the studio made for this play alone: nothing else can connect to it). It registers
the :class:`cab_core.attempt.engine.human.ChildBridge` over that connection as the session's, which only
this entry point does (so ``cab model=human`` is refused before any simulator starts), then runs the
attempt with the normal runner; the person's calls come over the connection.

It exits as a sweep's child does: 0 once the attempt finished, 2 for a configuration problem, 3 when
no renderer could start, 1 otherwise; an exception is sent to the studio first (``failed``), so the
play page shows it. The studio outlives this process: a crash here ends only this play.
"""
from __future__ import annotations

import json
import logging
import os
import sys
from multiprocessing.connection import Connection
from pathlib import Path

from cab_core.attempt.engine.human import SESSIONS, ChildBridge
from cab_core.attempt.runner import attempt_spec, run_attempt
from cab_core.errors import ConfigError, MissingDependency, PluginError, RendererUnavailable
from cab_core.sweep.protocol import EXIT_CONFIG, EXIT_FAULT, EXIT_RENDERER, die_with_parent


def run(job: dict, conn: Connection) -> int:
    bridge = SESSIONS[job["session"]] = ChildBridge(conn, job["session"], job["handle"])
    try:
        run_attempt(attempt_spec(job["config"], Path(job["output_dir"])))
        return 0
    except Exception as e:  # noqa: BLE001 (the studio shows it; the records say what they hold)
        logging.getLogger(__name__).exception("played attempt %s failed", job["output_dir"])
        bridge.failed(f"{type(e).__name__}: {e}")
        if isinstance(e, RendererUnavailable):
            return EXIT_RENDERER
        return EXIT_CONFIG if isinstance(e, (ConfigError, MissingDependency, PluginError)) else EXIT_FAULT
    finally:
        SESSIONS.pop(job["session"], None)


def main() -> int:
    die_with_parent()
    job = json.loads(sys.stdin.read())
    logging.basicConfig(level=logging.INFO, format="%(message)s")  # as the studio logs (its stderr is ours)
    fd = int(sys.argv[1])
    os.set_inheritable(fd, False)  # no process this one starts holds the studio's connection open
    conn = Connection(fd)
    try:
        return run(job, conn)
    finally:
        conn.close()


if __name__ == "__main__":
    sys.exit(main())
