"""PyBullet's C code prints to the process's own output streams: its build time on standard error
when the module is imported, ``argv[0]=`` on standard output when a client connects. Neither says
anything a user needs, and on a command whose standard output carries a protocol (an MCP server
over stdio) a stray line would corrupt it; so both moments run with file descriptors 1 and 2 on the
null device. (Python exceptions are raised, not printed: nothing that matters is hidden.)"""
from __future__ import annotations

import contextlib
import os
import sys


@contextlib.contextmanager
def c_output_silenced():
    """File descriptors 1 and 2 on /dev/null for the block (Python's ``sys.stdout`` and
    ``sys.stderr`` flushed first, so nothing already written is lost)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)
