"""The fault rule: whose fault an exception is, and which attempts a sweep and a report set aside.

An exception raised while the host serves an agent's call (a direct call, or a tool called from a
``run_code`` program) is the **agent's tool error** unless the host itself is broken. The agent gets
a typed error (``code: tool_error``, the exception's type and a short message, never a traceback or
a host path), the call stays charged as the catalog says (one call per direct call or program,
success or not), the fault is recorded with its traceback in ``events.jsonl`` (kind ``tool_error``)
and counted in ``result.json`` (``counts.tool_errors``), and the attempt goes on.

Only faults outside the agent's reach are **infrastructure failures**: the simulator or renderer
process died or hung, the provider was out beyond its retries, the host ran out of memory or disk,
the sandbox could not be (re)started. An attempt that ends on one carries a termination reason in
:data:`INFRASTRUCTURE_TERMINATIONS`; a sweep retries it and a report excludes it. Nothing an agent
sends can produce one: arguments are validated before any handler runs, and any other exception
from a handler is classified here by its type, not by where it came from.

A plugin that detects its own breakage (a simulator server that stopped answering, a renderer that
lost its device) raises :class:`~cab_core.errors.InfrastructureFault` (or one of the other types in
:func:`is_infrastructure_fault`).
"""
from __future__ import annotations

import errno
import re

from cab_core.attempt.records.result_format import (  # noqa: F401  (the fault rule's terminations, named here too)
    INFRASTRUCTURE_TERMINATIONS,
    INTERRUPTED,
    UNSCORED_TERMINATIONS,
)
from cab_core.errors import InfrastructureFault, RendererUnavailable, SandboxUnavailable

# The terminations that are never scored (:data:`INFRASTRUCTURE_TERMINATIONS`, which a sweep retries,
# and :data:`INTERRUPTED`) are defined with the record format, which marks them (``verdict.excluded``):
# that module stays low in the import map.

# OS errors that mean the machine, not the call, is broken: out of disk or quota, I/O failure,
# out of file handles, a read-only file system.
_HOST_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EMFILE, errno.ENFILE, errno.EROFS, errno.ENOMEM}

_PATH = re.compile(r"(?:[A-Za-z]:)?(?:/[\w.+@-]+){2,}/?")
MESSAGE_CHARS = 300


def is_infrastructure_fault(exc: BaseException) -> bool:
    """Whether ``exc`` means the host is broken (never the agent's doing)."""
    if isinstance(exc, (InfrastructureFault, RendererUnavailable, SandboxUnavailable, MemoryError)):
        return True
    if isinstance(exc, OSError) and exc.errno in _HOST_ERRNOS:
        return True
    return False


def is_infrastructure_termination(reason: str | None) -> bool:
    return reason in INFRASTRUCTURE_TERMINATIONS


def is_unscored_termination(reason: str | None) -> bool:
    """Whether an attempt that ended for ``reason`` counts neither for nor against the model."""
    return reason in UNSCORED_TERMINATIONS


def agent_message(exc: BaseException) -> str:
    """The exception as the agent may see it: its type and a short message, host paths removed."""
    text = " ".join(str(exc).split()) or "(no message)"
    text = _PATH.sub("<path>", text)
    if len(text) > MESSAGE_CHARS:
        text = text[: MESSAGE_CHARS - 3] + "..."
    return f"{type(exc).__name__}: {text}"


def tool_error_payload(tool: str, exc: BaseException) -> dict:
    """The typed error an agent gets for an exception raised while serving its call."""
    return {"error": f"tool error: {tool} could not complete this call ({agent_message(exc)})",
            "code": "tool_error"}
