"""The task ``cab/codeaction``: its samples (one per task instance and seed), the solver that runs
one cab attempt per sample and epoch, and the agents that play it.

A sample's attempt is a ``cab +harness=mcp`` child process (:mod:`.attempt`), its folder
``<records>/<task>/<model>/<sim>/seed-<S>/attempt-<epoch>`` (the layout of a cab sweep, so
``cab-report`` and ``cab-studio`` read an Inspect run as they read a sweep), its configuration
named by the Inspect model string.
"""
from __future__ import annotations

import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from inspect_ai.agent import AgentSubmit, as_solver, react
from inspect_ai.dataset import Sample
from inspect_ai.model import ChatMessageSystem, ChatMessageUser
from inspect_ai.solver import Generate, Solver, TaskState, solver
from inspect_ai.util import LimitExceededError

from cab_core.errors import ConfigError
from cab_core.sweep.layout import folder_safe

from .attempt import cab_command, read_result, serve_attempt, set_unscored
from .tools import attempt_tools

AGENTS = ("react", "reference")
ATTEMPT_DIR = "cab_attempt_dir"   # the sample metadata key naming the attempt folder
MAX_NO_TOOL_TURNS = 3             # as cab's reference harness: this many replies in a row without a tool call end the agent


def _names(value: str | Iterable[str] | None) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    return [str(v).strip() for v in value if str(v).strip()]


def resolve_tasks(tasks: str | Iterable[str] | None) -> list[str]:
    """Task names from task and suite names (a suite stands for its tasks, in its order)."""
    from cab_core.plugins import load_suites

    loaded = load_suites()
    wanted = _names(tasks)
    if not wanted:
        raise ConfigError("-T tasks= names no task (give task or suite names, comma-separated)")
    out: list[str] = []
    for name in wanted:
        if name in loaded.suites:
            out += [t for t in loaded.suites[name] if t in loaded.tasks]
        elif name in loaded.tasks:
            out.append(name)
        else:
            raise ConfigError(f"-T tasks: unknown task or suite {name!r}; suites: {', '.join(sorted(loaded.suites))}")
    return list(dict.fromkeys(out))


def default_sim() -> str:
    """The simulator plain ``cab`` composes."""
    from cab_core.config import default_selection

    return default_selection(("sim",))["sim"]


def resolve_seeds(task: str, seeds: str | int | Iterable[int] | None, seed_set: str | None) -> list[int]:
    """The seeds of ``task``: the given ones, its named seed set, or its catalog seed."""
    from cab_core.plugins import all_tasks

    if seeds is not None and seed_set is not None:
        raise ConfigError("give -T seeds=... or -T seed_set=NAME, not both")
    if seed_set is not None:
        return list(all_tasks()[task].seeds(seed_set))
    if seeds is None:
        return list(all_tasks()[task].seeds("catalog"))
    items = [seeds] if isinstance(seeds, int) else _names(seeds) if isinstance(seeds, str) else list(seeds)
    try:
        return [int(s) for s in items]
    except (TypeError, ValueError):
        raise ConfigError(f"-T seeds must be integers, got {seeds!r}") from None


def samples(tasks: list[str], sim: str, seeds: Any, seed_set: str | None) -> list[Sample]:
    from cab_core.plugins import task_info

    out = []
    for task in tasks:
        info = task_info(task)
        for seed in resolve_seeds(task, seeds, seed_set):
            out.append(Sample(id=f"{task}/seed-{seed}", input=info.instruction, target="success",
                              metadata={"task": task, "seed": seed, "sim": sim}))
    return out


def cab_overrides(randomize: str | None, tool_calls: int | None, sim_seconds: float | None,
                  video: bool, extra: str | Iterable[str] | None) -> list[str]:
    """The cab settings every sample's attempt gets (the seed and task are per sample)."""
    out = []
    if randomize:
        out.append(f"randomize={randomize}")
    if tool_calls is not None:
        out.append(f"budget.tool_calls={int(tool_calls)}")
    if sim_seconds is not None:
        out.append(f"budget.sim_seconds={float(sim_seconds)}")
    if not video:
        out.append("record.video=false")
    if isinstance(extra, str):
        extra = extra.split()
    return out + list(extra or [])


def records_root(records: str | None) -> Path:
    """Where the attempt folders go: ``records`` when given, else beside the eval's log
    (``<log>.cab/`` for ``<log>.eval``)."""
    if records:
        return Path(records).resolve()
    from inspect_ai.log._samples import sample_active

    active = sample_active()
    location = getattr(active, "log_location", None) if active is not None else None
    if not location or "://" in str(location):
        return Path("logs", "cab").resolve()
    log = Path(location)
    return log.with_name(log.stem + ".cab").resolve()


def attempt_folder(root: Path, task: str, model: str, sim: str, seed: int, epoch: int) -> Path:
    """The sweep layout's folder (``cab_core.sweep.layout``), the Inspect epoch as the attempt."""
    return root / folder_safe(task) / folder_safe(model) / folder_safe(sim) / f"seed-{seed}" / f"attempt-{epoch}"


def _set_aside(folder: Path) -> None:
    """An earlier try of the sample (an infrastructure failure, or a run before in the same records
    folder) keeps its files, beside the new one."""
    if folder.exists() and any(folder.iterdir()):
        k = 1
        while folder.with_name(f"{folder.name}.previous-{k}").exists():
            k += 1
        shutil.move(str(folder), str(folder.with_name(f"{folder.name}.previous-{k}")))


def _continue_unless_ended(served) -> Any:
    turns = {"without_tools": 0}

    async def on_continue(state) -> bool:
        if served.ended:
            return False
        if state.output.message.tool_calls:
            turns["without_tools"] = 0
            return True
        turns["without_tools"] += 1
        return turns["without_tools"] < MAX_NO_TOOL_TURNS

    return on_continue


async def run_react(state: TaskState, served, generate: Generate) -> TaskState:
    """Inspect's standard tool-calling loop on cab's tools, cab's ``done`` as its submit tool (the
    loop ends when ``done`` is accepted, when the attempt has ended, or after
    ``MAX_NO_TOOL_TURNS`` replies in a row without a tool call)."""
    tools = attempt_tools(served)
    done = next(t for t in tools if t.name == "done")
    others = [t for t in tools if t.name != "done"]
    agent = react(prompt=None, tools=others, on_continue=_continue_unless_ended(served),
                  submit=AgentSubmit(name="done", description=done.description, tool=done, keep_in_messages=True))
    return await as_solver(agent)(state, generate)


@solver
def cab_attempt(sim: str, overrides: list[str], agent: str = "react", records: str | None = None,
                exit_grace_s: float = 300.0, call_timeout_s: float = 900.0) -> Solver:
    """Runs one cab attempt for the sample (its task and seed) and epoch, played by ``agent``."""
    if agent not in AGENTS:
        raise ConfigError(f"-T agent must be one of {', '.join(AGENTS)}, got {agent!r}")

    async def solve(state: TaskState, generate: Generate) -> TaskState:
        md = state.metadata
        model = str(state.model)
        folder = attempt_folder(records_root(records), md["task"], model, sim, int(md["seed"]), state.epoch)
        _set_aside(folder)
        state.metadata[ATTEMPT_DIR] = str(folder)
        command = cab_command(md["task"], sim, int(md["seed"]), model, folder, overrides, attempt=state.epoch)
        try:
            if agent == "reference":
                from .reference import run_reference

                await run_reference(state, md["task"], sim, int(md["seed"]), folder, overrides, exit_grace_s)
            else:
                async with serve_attempt(command, folder, exit_grace_s=exit_grace_s,
                                         call_timeout_s=call_timeout_s) as served:
                    state.messages = [ChatMessageSystem(content=served.system),
                                      ChatMessageUser(content=served.first_user)]
                    state = await run_react(state, served, generate)
        except LimitExceededError:
            raise                    # a limit of the sample (time, tokens, messages): Inspect scores it, as cab recorded it
        except Exception as e:
            if folder.is_dir():      # cab was started
                read_result(folder)  # it died or hung up (the connection lost): AttemptFailed, with cab's last words
                set_unscored(folder, "inspect_sample_error", f"{type(e).__name__}: {e}")
            raise                    # the provider, the agent loop: a sample error, and the record says so
        read_result(folder)  # no record, or an excluded one: a sample error, never a score
        return state

    return solve
