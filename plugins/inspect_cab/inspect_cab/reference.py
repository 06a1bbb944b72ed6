"""``-T agent=reference``: the paper's reference harness plays the sample's attempt, on the eval's
own Inspect model.

The attempt is cab's reference harness in a child process, through its ``openai_compatible``
provider (``cab model=openai_compatible model.model_id=inspect model.base_url=<bridge>``): cab's own
loop (prompt, context policy, image rule, run_code limits, the no-tool-call rule, its records). Its
endpoint is Inspect's agent bridge (:func:`inspect_ai.agent.sandbox_agent_bridge`), an
OpenAI-compatible server that Inspect runs in the sample's sandbox (``local``: this host, on
127.0.0.1) and whose requests for the model ``inspect`` it serves with the eval's model. Each of
the harness's requests is therefore a model event of the sample's transcript, counted in the log's
model usage, bounded by ``--max-connections``, generated with the eval's ``-M`` arguments and
generation settings (the bridge drops the harness's own ``max_tokens``: ``--max-tokens`` governs).
The record names the configuration by the Inspect model string (``model.label``), its folders by
that string made one folder name (``model.name``).
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
from pathlib import Path

import anyio
from inspect_ai.agent import AgentState, sandbox_agent_bridge
from inspect_ai.model import ChatMessageAssistant, ModelOutput
from inspect_ai.solver import TaskState

from cab_core.sweep.layout import folder_safe

from .attempt import AttemptFailed, read_result

TERM_GRACE_S = 30.0      # after SIGTERM (a cancelled sample): cab records the attempt as interrupted
BRIDGE_START_S = 60.0    # the bridge's server must listen within this
BRIDGE_MODEL = "inspect"  # the model name the bridge serves with the eval's model


def _quoted(value: str) -> str:
    return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"


def reference_command(task: str, sim: str, seed: int, model_name: str, folder: Path, overrides: list[str],
                      attempt: int) -> list[str]:
    """The attempt's command line: the reference harness on an OpenAI-compatible endpoint, the
    configuration named by the Inspect model string. The endpoint (the sample's bridge) is given by
    ``OPENAI_BASE_URL`` (:func:`bridge_env`), not ``model.base_url``: its port differs from sample to
    sample, and a setting of the model configuration would name each sample's configuration apart
    in ``cab-report``. The endpoint is not probed (``model.probe=false``): tool results go back as
    text, their images in one user message after them, as for any OpenAI-compatible server."""
    cmd = ["cab", f"task={task}", f"sim={sim}", "model=openai_compatible", f"model.model_id={BRIDGE_MODEL}",
           "model.base_url=null", f"model.name={_quoted(folder_safe(model_name))}",
           f"+model.label={_quoted(model_name)}", "+model.probe=false", f"seed={seed}",
           f"attempt={attempt}", f"hydra.run.dir={folder}"]
    return cmd + list(overrides)


def free_port() -> int:
    """A port of 127.0.0.1 free now (each sample in flight has its own bridge)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def wait_listening(port: int, timeout_s: float = BRIDGE_START_S) -> None:
    """The bridge's server is started by a process Inspect launches without saying when it
    listens: wait until it accepts a connection."""
    with anyio.move_on_after(timeout_s):
        while True:
            try:
                stream = await anyio.connect_tcp("127.0.0.1", port)
            except OSError:
                await anyio.sleep(0.1)
                continue
            await stream.aclose()
            return
    raise AttemptFailed(f"Inspect's model bridge did not listen on 127.0.0.1:{port} within {timeout_s:g}s")


def bridge_env(port: int) -> dict[str, str]:
    """The attempt's environment: the bridge as its endpoint, no API key sent to it."""
    env = dict(os.environ)
    env["OPENAI_BASE_URL"] = f"http://127.0.0.1:{port}/v1"
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.setdefault("CAB_CPU_SLOTS", str(os.cpu_count() or 1))  # as attempt.serve_attempt: a sweep's CPU slots
    return env


async def _run(command: list[str], env: dict[str, str], folder: Path) -> None:
    log = folder.parent / f"{folder.name}.cab.log"
    with log.open("ab") as errf:
        process = await anyio.open_process(command, stdin=subprocess.DEVNULL, stdout=errf, stderr=errf,
                                           env=env, cwd=str(folder.parent), start_new_session=True)
        try:
            await process.wait()
        finally:
            if process.returncode is None:  # the sample was cancelled (a time limit, Ctrl-C)
                with anyio.CancelScope(shield=True):
                    os.killpg(process.pid, signal.SIGTERM)
                    with anyio.move_on_after(TERM_GRACE_S):
                        await process.wait()
                    if process.returncode is None:
                        os.killpg(process.pid, signal.SIGKILL)
                        await process.wait()


async def run_reference(state: TaskState, task: str, sim: str, seed: int, folder: Path, overrides: list[str],
                        exit_grace_s: float) -> None:
    """Run the attempt to its end behind the bridge. The sample's messages are the conversation
    as the bridge last saw it; its output is the agent's completion claim."""
    model = str(state.model)
    folder.mkdir(parents=True, exist_ok=True)
    port = free_port()
    async with sandbox_agent_bridge(AgentState(messages=list(state.messages)), port=port) as bridge:
        await wait_listening(port)
        await _run(reference_command(task, sim, seed, model, folder, overrides, state.epoch),
                   bridge_env(port), folder)
    record = read_result(folder)
    text = (record.get("claim") or {}).get("report") or ""
    if bridge.state.messages:  # the last request and its reply (the harness's context policy applied)
        state.messages = list(bridge.state.messages)
    else:
        state.messages.append(ChatMessageAssistant(content=text or "(no completion claim)", model=model))
    state.output = ModelOutput.from_content(model, text)
