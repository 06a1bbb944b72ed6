"""The tool registry: one ToolDef per tool; schemas come from the pydantic argument models.

Handlers are referenced by dotted path (``"cab_core.tools.motion:move_delta"``) and resolved on
first use, so the registry can be listed and its schemas printed without a simulator.
A handler has the signature ``handler(ctx: RobotContext, args: <ArgsModel>) -> ToolOutput``.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable, Literal

from pydantic import BaseModel

Group = Literal["observation", "geometry", "feedback", "motion", "composition", "control"]


@dataclass
class ToolOutput:
    """A handler's result: the JSON payload the agent sees, the images it carries (obs ids), and
    for actions the status and physics steps it consumed."""
    payload: dict[str, Any]
    obs_ids: list[str] = field(default_factory=list)
    status: str | None = None  # SUCCESS / FAILED / ABORTED for actions
    physics_steps: int = 0


@dataclass(frozen=True)
class ToolDef:
    name: str
    group: Group
    args: type[BaseModel]
    handler: str  # "module:function"
    description: str
    read_only: bool = True  # MCP readOnlyHint
    destructive: bool = False  # MCP destructiveHint (motion)
    advances_physics: bool = False
    charged: bool = True  # done is free
    result: type[BaseModel] | None = None  # documented result model, when there is one

    def resolve(self) -> Callable[..., ToolOutput]:
        mod, fn = self.handler.split(":")
        return getattr(importlib.import_module(mod), fn)

    def json_schema(self) -> dict:
        s = self.args.model_json_schema()
        s.pop("title", None)
        return s

    def spec(self) -> dict:
        """Provider-neutral function-tool description: name, description, parameters."""
        return {"name": self.name, "description": self.description, "parameters": self.json_schema()}
