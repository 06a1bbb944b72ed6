"""cab's own plugin: the ``direct`` harness and the model-free agents (oracle, idle, scripted).
Registered through the same entry point group as third-party plugins."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .errors import AttemptEnded, ConfigError
from .hookspecs import hookimpl


class DirectHarness:
    """Runs a model-free agent in-process against the episode's tool session."""

    def __init__(self, cfg: dict):
        self.cfg = cfg

    def run(self, episode, model_cfg: dict) -> None:
        from .plugins import create

        agent = create("agents", model_cfg.get("agent", model_cfg.get("name")), model_cfg)
        try:
            agent.run(episode)
        except AttemptEnded:
            pass


class IdleAgent:
    """Calls done at once with a false claim: the floor every task must score 0 on."""

    def __init__(self, cfg: dict):
        self.cfg = cfg

    def run(self, episode) -> None:
        episode.call("done", {"report": "idle agent: no action taken", "success_claim": False})


class OracleAgent:
    """The task's reference solution: privileged state only to compute targets; acts only
    through the public tools."""

    def __init__(self, cfg: dict):
        self.cfg = cfg

    def run(self, episode) -> None:
        def call(tool: str, **kwargs: Any) -> dict:
            r = episode.call(tool, kwargs)
            if r.ended and tool != "done":
                raise AttemptEnded(f"attempt ended during {tool}: {episode.termination}")
            return r.payload

        call("capture_head")  # look before acting, as any agent would (and the record holds the view)
        episode.task.oracle(call, episode.world)


class ScriptedAgent:
    """Replays tool calls from a JSON or JSONL file of ``{"tool": name, "args": {...}}`` items."""

    def __init__(self, cfg: dict):
        path = cfg.get("script")
        if not path:
            raise ConfigError("the scripted agent needs model.script=<file of tool calls>")
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"script file not found: {path}")
        text = p.read_text()
        try:
            items = json.loads(text) if text.lstrip().startswith("[") else [json.loads(l) for l in text.splitlines() if l.strip()]
        except json.JSONDecodeError as e:
            raise ConfigError(f"script {path} is not valid JSON/JSONL: {e}") from e
        for i, it in enumerate(items):
            if not isinstance(it, dict) or "tool" not in it:
                raise ConfigError(f"script item {i} must be an object with a 'tool' key")
        self.items = items

    def run(self, episode) -> None:
        for it in self.items:
            r = episode.call(it["tool"], it.get("args") or {})
            if r.ended:
                return


@hookimpl
def cab_harnesses():
    return {"direct": DirectHarness}


@hookimpl
def cab_agents():
    return {"oracle": OracleAgent, "idle": IdleAgent, "scripted": ScriptedAgent}
