"""cab's own plugin: the ``direct`` harness and the model-free agents (oracle, idle, scripted, and
``human``: a person playing from cab-studio, :mod:`cab_core.attempt.engine.human`).
Registered through the same entry point group as third-party plugins."""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from cab_core.attempt.engine.human import HumanAgent
from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.task import NotRecoverable
from cab_core.errors import AttemptEnded, ConfigError, closest
from cab_core.plugins import create

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.harness import AttemptSession, ModelFreeAgent


class DirectHarness:
    """Runs a model-free agent in-process against the episode's tool session."""

    config_keys: frozenset[str] = frozenset()  # of a model configuration: the agent's own (below) besides the basics

    def __init__(self, cfg: dict):
        self.cfg = cfg
        self._agent: ModelFreeAgent | None = None

    def preflight(self, model_cfg: dict) -> None:
        """Create the agent before any simulator starts: a bad agent config (a scripted agent's
        missing or malformed script) is a ConfigError in one line, not an attempt ended by an error."""
        name = model_cfg.get("agent", model_cfg.get("name"))
        # cast: create() refuses a name it does not know, None (no agent named) included, listing the agents
        self._agent = create("agents", cast(str, name), model_cfg)

    def run(self, episode: AttemptSession, model_cfg: dict) -> None:
        if self._agent is None:
            self.preflight(model_cfg)
        agent, self._agent = self._agent, None
        assert agent is not None  # preflight created it
        try:
            agent.run(episode)
        except AttemptEnded:
            pass


class IdleAgent:
    """Calls done at once with a false claim: the floor every task must score 0 on."""

    config_keys: frozenset[str] = frozenset()

    def __init__(self, cfg: dict):
        self.cfg = cfg

    def run(self, episode: AttemptSession) -> None:
        episode.call("done", {"report": "idle agent: no action taken", "success_claim": False})


class OracleAgent:
    """The task's reference solution: privileged state only to compute targets; acts only
    through the public tools."""

    config_keys: frozenset[str] = frozenset()

    def __init__(self, cfg: dict):
        self.cfg = cfg

    def run(self, episode: AttemptSession) -> None:
        def call(tool: str, **kwargs: Any) -> dict:
            r = episode.call(tool, kwargs)
            if r.ended and tool != "done":
                raise AttemptEnded(f"attempt ended during {tool}: {episode.termination}")
            return r.payload

        call("capture_head")  # look before acting, as any agent would (and the record holds the view)
        try:
            episode.task.oracle(call, episode.world)
        except NotRecoverable as e:  # the reason goes to the record; no success is claimed
            episode.recorder.event("oracle_not_recoverable", reason_kind=e.kind, reason=e.reason, stages=e.stages)
            if not episode.ended:
                call("done", report=f"not recoverable ({e.kind}): {e.reason}", success_claim=False)


class ScriptedAgent:
    """Replays tool calls from a JSON or JSONL file of ``{"tool": name, "args": {...}}`` items
    (``"arguments"`` is accepted for ``"args"``; any other key is refused, never ignored)."""

    ITEM_KEYS = ("tool", "args", "arguments")
    config_keys = frozenset({"script"})

    def __init__(self, cfg: dict):
        path = cfg.get("script")
        if not path:
            raise ConfigError("the scripted agent needs model.script=<file of tool calls>")
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"script file not found: {path}")
        text = p.read_text()
        try:
            items = json.loads(text) if text.lstrip().startswith("[") else [json.loads(line) for line in text.splitlines() if line.strip()]
        except json.JSONDecodeError as e:
            raise ConfigError(f"script {path} is not valid JSON/JSONL: {e}") from e
        if not isinstance(items, list):
            raise ConfigError(f"script {path} must hold a list of tool calls")
        valid = ", ".join(self.ITEM_KEYS)
        for i, it in enumerate(items):
            if not isinstance(it, dict) or "tool" not in it:
                raise ConfigError(f"script item {i} must be an object with a 'tool' key (valid keys: {valid})")
            unknown = [k for k in it if k not in self.ITEM_KEYS]
            if unknown:
                near = closest(unknown[0], self.ITEM_KEYS)
                hint = f"did you mean {' or '.join(near)}? " if near else ""
                raise ConfigError(f"script item {i} has unknown key {unknown[0]!r}; {hint}valid keys: {valid}")
            if "args" in it and "arguments" in it:
                raise ConfigError(f"script item {i} has both 'args' and 'arguments'; give one")
        self.items = items

    def run(self, episode: AttemptSession) -> None:
        for it in self.items:
            r = episode.call(it["tool"], (it["args"] if "args" in it else it.get("arguments")) or {})
            if r.ended:
                return


@hookimpl
def cab_harnesses():
    return {"direct": DirectHarness}


@hookimpl
def cab_agents():
    return {"oracle": OracleAgent, "idle": IdleAgent, "scripted": ScriptedAgent, "human": HumanAgent}
