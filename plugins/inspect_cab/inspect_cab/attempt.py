"""One cab attempt served to the Inspect process over MCP on stdio.

The attempt runs in a child process, ``cab +harness=mcp`` (the MCP harness of
``cab-harness-mcp``): the simulator, the budgets, the records and the verdict are cab's, and a crash
or a hang of the simulator kills that process, never the evaluation. The Inspect side is an MCP
client of the official SDK: the tools it lists are cab's own (names, descriptions, input schemas),
and each call the Inspect agent makes is one ``tools/call``, charged by cab exactly as under any
other harness.

The stdio transport is this module's own (not :func:`mcp.client.stdio.stdio_client`): when the
agent has finished, the client closes the server's stdin and then *waits* for cab to write
``result.json`` and its video and exit (``exit_grace_s``), where the SDK's transport kills a server
that has not exited two seconds after its stdin closed.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import mcp_types as types
from anyio.streams.text import TextReceiveStream
from mcp.shared.message import SessionMessage

from cab_core.analysis.attempts import read_record
from cab_core.attempt.records.result_format import RESULT_FILE, Infrastructure, write_record

log = logging.getLogger(__name__)

# What the MCP harness tells its client before the task (harness_mcp's server.instructions_text):
# the system prompt every harness gives, then "# Task" and the first user message.
TASK_HEADING = "\n\n# Task\n"


class AttemptFailed(RuntimeError):
    """The attempt could not be scored through no fault of the agent: cab exited without a record,
    or wrote one whose verdict is excluded (an infrastructure termination). Raised out of the
    sample, so Inspect records a sample error (retried by ``--retry-on-error`` and by
    ``inspect eval-set``), never a score."""


def cab_command(task: str, sim: str, seed: int | None, model_name: str, folder: Path,
                overrides: list[str], attempt: int = 1) -> list[str]:
    """The command line of one served attempt. The configuration is named by the Inspect model
    string (``model.name``), the attempt number is the Inspect epoch, the attempt folder is
    ``hydra.run.dir``."""
    quoted = model_name.replace("\\", "\\\\").replace("'", "\\'")
    cmd = ["cab", "+harness=mcp", f"task={task}", f"sim={sim}", f"model.name='{quoted}'",
           f"attempt={attempt}", f"hydra.run.dir={folder}"]
    if seed is not None:
        cmd.append(f"seed={seed}")
    return cmd + list(overrides)


@dataclass
class Outcome:
    """What one result of the attempt said, as the agent's tools see it."""
    payload: dict[str, Any]
    images: list[tuple[str, str]]  # (mime type, base64 data), in order
    labels: list[str]              # the text parts after the payload ("[image obs_3]")
    is_error: bool


def outcome_of(result: types.CallToolResult) -> Outcome:
    texts = [c.text for c in result.content if isinstance(c, types.TextContent)]
    try:
        payload = json.loads(texts[0]) if texts else {}
    except json.JSONDecodeError:
        payload = {"text": texts[0]}
    if not isinstance(payload, dict):
        payload = {"value": payload}
    images = [(c.mime_type, c.data) for c in result.content if isinstance(c, types.ImageContent)]
    return Outcome(payload, images, texts[1:], bool(result.is_error))


@dataclass
class ServedAttempt:
    """An initialised MCP session with one attempt, and what the client learnt of it."""
    session: Any                      # mcp.ClientSession
    folder: Path
    system: str = ""                  # cab's system prompt
    first_user: str = ""              # cab's first user message (the task)
    tools: list[types.Tool] = field(default_factory=list)
    ended: bool = False               # done accepted, a budget spent, or the attempt ended otherwise
    call_timeout_s: float = 900.0

    async def call(self, name: str, arguments: dict[str, Any]) -> Outcome:
        """One tool call. A lost connection or a call that never returns raises (a sample error):
        the attempt cannot go on and must not be scored as the agent's failure."""
        result = await self.session.call_tool(name, arguments,
                                              read_timeout_seconds=self.call_timeout_s)
        out = outcome_of(result)
        if out.payload.get("attempt_ended") or (name == "done" and not out.is_error):
            self.ended = True
        return out


async def _stderr_to(stream, path: Path) -> None:
    with path.open("ab") as f:
        async for chunk in stream:
            f.write(chunk)
            f.flush()


@asynccontextmanager
async def stdio_transport(command: list[str], env: dict[str, str], cwd: Path, stderr_log: Path,
                          exit_grace_s: float) -> AsyncIterator[tuple[Any, Any, Any]]:
    """``(read_stream, write_stream, process)`` of an MCP server started as ``command``. On exit:
    stdin is closed (cab ends an unfinished attempt as ``client_disconnected`` and writes its
    record), the server is given ``exit_grace_s`` to exit, then its process group is killed."""
    process = await anyio.open_process(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                       stderr=subprocess.PIPE, env=env, cwd=str(cwd), start_new_session=True)
    read_writer, read_stream = anyio.create_memory_object_stream[SessionMessage | Exception](0)
    write_stream, write_reader = anyio.create_memory_object_stream[SessionMessage](0)

    async def reader() -> None:
        buffer = ""
        async with read_writer:
            try:
                async for chunk in TextReceiveStream(process.stdout):
                    lines = (buffer + chunk).split("\n")
                    buffer = lines.pop()
                    for line in lines:
                        if not line.strip():
                            continue
                        try:
                            msg: SessionMessage | Exception = SessionMessage(
                                types.jsonrpc_message_adapter.validate_json(line, by_name=False))
                        except ValueError as e:
                            msg = e
                        await read_writer.send(msg)
            except (anyio.ClosedResourceError, anyio.BrokenResourceError, anyio.EndOfStream):
                pass

    async def writer() -> None:
        async with write_reader:
            try:
                async for message in write_reader:
                    data = message.message.model_dump_json(by_alias=True, exclude_unset=True) + "\n"
                    await process.stdin.send(data.encode())
            except (anyio.ClosedResourceError, anyio.BrokenResourceError, OSError):
                await read_writer.aclose()

    async with anyio.create_task_group() as tg:
        tg.start_soon(reader)
        tg.start_soon(writer)
        tg.start_soon(_stderr_to, process.stderr, stderr_log)
        try:
            yield read_stream, write_stream, process
        finally:
            with anyio.CancelScope(shield=True):
                write_stream.close()
                try:
                    await process.stdin.aclose()
                except (OSError, anyio.BrokenResourceError, anyio.ClosedResourceError):
                    pass
                with anyio.move_on_after(exit_grace_s):
                    while process.returncode is None:
                        await anyio.sleep(0.05)
                if process.returncode is None:
                    log.warning("cab attempt %s did not exit %gs after its client left: killed", cwd, exit_grace_s)
                    try:
                        os.killpg(process.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    await process.wait()
            tg.cancel_scope.cancel()


@asynccontextmanager
async def serve_attempt(command: list[str], folder: Path, *, exit_grace_s: float = 300.0,
                        startup_timeout_s: float = 600.0, call_timeout_s: float = 900.0,
                        client_name: str = "inspect_ai") -> AsyncIterator[ServedAttempt]:
    """Start the attempt, initialise the MCP session and list its tools; on exit the attempt is
    ended (if the agent has not ended it) and its record written."""
    from inspect_ai import __version__ as inspect_version
    from mcp import ClientSession
    from mcp_types import Implementation

    folder.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    # the samples in flight (--max-samples) share one CPU slot per core while they compute, as a cab
    # sweep's attempts do (cab_core.attempt.engine.cpu_slots: the pool is on where this names its size)
    env.setdefault("CAB_CPU_SLOTS", str(os.cpu_count() or 1))
    async with stdio_transport(command, env, folder.parent, folder.parent / f"{folder.name}.cab.log",
                               exit_grace_s) as (read, write, _process):
        info = Implementation(name=client_name, version=inspect_version)
        async with ClientSession(read, write, client_info=info,
                                 read_timeout_seconds=startup_timeout_s) as session:
            init = await session.initialize()
            served = ServedAttempt(session, folder, call_timeout_s=call_timeout_s)
            instructions = init.instructions or ""
            served.system, _, task = instructions.partition(TASK_HEADING)
            served.first_user = task.rstrip("\n")
            served.tools = list((await session.list_tools()).tools)
            yield served


def read_result(folder: Path) -> dict:
    """The attempt's ``result.json``, checked against cab's record format. A missing record, or
    one whose verdict is excluded (an infrastructure failure, an interruption), raises
    :class:`AttemptFailed`."""
    path = folder / RESULT_FILE
    if not path.is_file():
        tail = ""
        logf = folder.parent / f"{folder.name}.cab.log"
        if logf.is_file():
            tail = " | ".join(logf.read_text(errors="replace").strip().splitlines()[-3:])
        raise AttemptFailed(f"cab wrote no {RESULT_FILE} in {folder}" + (f": {tail}" if tail else ""))
    record = read_record(path)
    if record.excluded:
        raise AttemptFailed(f"attempt {folder} not scored ({record.excluded_reason}): "
                            f"{record.termination.reason}: {record.termination.detail}")
    return record.dump()


def set_unscored(folder: Path, kind: str, detail: str) -> None:
    """Mark the attempt's record as not the agent's to score: the sample failed on Inspect's side
    (the provider, the agent loop) after cab had recorded the attempt as ended by its client. As
    a sweep marks an attempt whose tries all failed: ``infrastructure.failed``, so that
    ``cab-report`` excludes it as the Inspect log does (a sample error, no score)."""
    path = folder / RESULT_FILE
    record = read_record(path)
    if record.excluded:
        return
    record.infrastructure = Infrastructure.model_validate(
        {"failed": True, "failures": [{"kind": kind, "detail": detail[:2000], "records": str(folder)}]})
    write_record(path, record)
