"""``-T agent=reference``: the paper's reference harness plays the sample's attempt, on the eval's
Inspect model.

The attempt is ``cab model=inspect model.model_id=<the eval's model string>`` in a child process:
cab's own loop (prompt, context policy, image rule, run_code limits, the no-tool-call rule, its
records) with the ``inspect`` provider of ``cab-harness-reference``, which makes each request
through Inspect's model API (Inspect's providers, retries and credentials). The requests are
therefore those cab's harness makes, by construction: the same code makes them. They are made in
the child (each attempt its own Inspect ``Model``), so they appear in the attempt's records
(``events.jsonl``, ``cab-studio``), not in the Inspect transcript, and ``--max-connections`` does
not bound them (cab's ``model.limits`` do, through ``-T cab_args``).
"""
from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import anyio
from inspect_ai.model import ChatMessageAssistant, ModelOutput, get_model
from inspect_ai.solver import TaskState

from .attempt import read_result

TERM_GRACE_S = 30.0  # after SIGTERM (a cancelled sample): cab records the attempt as interrupted


def reference_command(task: str, sim: str, seed: int, model_name: str, folder: Path, overrides: list[str],
                      attempt: int, base_url: str | None = None) -> list[str]:
    quoted = model_name.replace("\\", "\\\\").replace("'", "\\'")
    cmd = ["cab", f"task={task}", f"sim={sim}", "model=inspect", f"model.model_id='{quoted}'", f"seed={seed}",
           f"attempt={attempt}", f"hydra.run.dir={folder}"]
    if base_url:
        cmd.append(f"model.base_url='{base_url}'")
    return cmd + list(overrides)


async def run_reference(state: TaskState, task: str, sim: str, seed: int, folder: Path, overrides: list[str],
                        exit_grace_s: float) -> None:
    """Run the attempt to its end; the sample's output is the agent's completion claim."""
    model = get_model()
    command = reference_command(task, sim, seed, str(state.model), folder, overrides, state.epoch,
                                getattr(model.api, "base_url", None))
    folder.mkdir(parents=True, exist_ok=True)
    log = folder.parent / f"{folder.name}.cab.log"
    with log.open("ab") as errf:
        process = await anyio.open_process(command, stdin=subprocess.DEVNULL, stdout=errf, stderr=errf,
                                           cwd=str(folder.parent), start_new_session=True)
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
    record = read_result(folder)
    claim = record.get("claim") or {}
    text = claim.get("report") or ""
    state.messages.append(ChatMessageAssistant(content=text or "(no completion claim)", model=str(state.model)))
    state.output = ModelOutput.from_content(str(state.model), text)
