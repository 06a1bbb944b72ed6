"""What a tool is: its declaration (:class:`ToolDef`), made by :func:`tool` on the handler itself,
and what a handler returns (:class:`ToolOutput`).

A robot tool is declared once, on its handler, beside its models, in the module of its kind (``observe``,
``estimate``, ``motion``)::

    class RayArgs(Args):
        obs_id: ObsId = Field(description="Observation whose calibration snapshot (K, E) defines the ray.")
        px: Pixel = Field(description="Pixel [u, v] in that observation's image (u right, v down, zero-based).")


    @tool(group="geometry", kind="read", result=Estimate)
    def ray(ctx: RobotContext, args: RayArgs) -> ToolOutput:
        \"\"\"Back-projects a pixel of an observation into a world-frame viewing ray: ...\"\"\"

The tool's name is the function's; its argument model is the annotation of its ``args`` parameter
(read with :func:`typing.get_type_hints`, so the model is defined, or imported, above the handler);
its description (the text the agent reads) is the function's docstring with every run of whitespace
folded to one space, so the docstring may wrap freely but cannot carry a paragraph break.
``run_code`` and ``done`` are served by the episode host itself
(:class:`~cab_core.attempt.engine.serving.CallServer`): they are plain :class:`ToolDef` values without a
handler. :mod:`cab_core.tools` lists every declaration in catalog order and builds the registry.

A handler has the signature ``handler(ctx: RobotContext, args: <ArgsModel>) -> ToolOutput``.
This module imports nothing else of cab_core, so a handler module can import it.
"""
from __future__ import annotations

import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from pydantic import BaseModel

Group = Literal["observation", "geometry", "feedback", "motion", "composition", "control"]

# What a call does, from which its flags follow: "read" (read-only), "plan" (read-only planner
# query), "act" (moves the robot and advances physics: destructive), "code" (run_code: may move the
# robot, so destructive), "done" (free).
Kind = Literal["read", "plan", "act", "code", "done"]

Handler = Callable[..., "ToolOutput"]


@dataclass
class ToolOutput:
    """A handler's result: the JSON payload the agent sees, the images it carries (obs ids), and
    for actions the status and physics steps it consumed."""
    payload: dict[str, Any]
    obs_ids: list[str] = field(default_factory=list)
    status: str | None = None  # SUCCESS / FAILED / ABORTED for actions
    physics_steps: int = 0


def observation_output(obs: Any, **extra) -> ToolOutput:
    """The result of a tool that returns one observation: its summary (plus ``extra`` keys) and its image."""
    payload = obs.summary()
    payload.update(extra)
    return ToolOutput(payload=payload, obs_ids=[obs.obs_id])


@dataclass(frozen=True)
class ToolDef:
    name: str
    group: Group
    kind: Kind
    args: type[BaseModel]
    description: str
    handler: Handler | None = None  # None: served by the episode host (run_code, done)
    result: type[BaseModel] | None = None  # documented result model, when there is one
    renders: bool = False  # the call renders a fresh image from a camera (slow on a CPU renderer)

    @property
    def read_only(self) -> bool:  # MCP readOnlyHint
        return self.kind in ("read", "plan")

    @property
    def destructive(self) -> bool:  # MCP destructiveHint (motion, programs)
        return self.kind in ("act", "code")

    @property
    def advances_physics(self) -> bool:
        return self.kind == "act"

    @property
    def charged(self) -> bool:  # done is free
        return self.kind != "done"

    def json_schema(self) -> dict:
        s = self.args.model_json_schema()
        s.pop("title", None)
        return s

    def spec(self) -> dict:
        """Provider-neutral function-tool description: name, description, parameters."""
        return {"name": self.name, "description": self.description, "parameters": self.json_schema()}


def description_of(fn: Callable) -> str:
    """A handler's docstring as the one-paragraph description the agent reads."""
    text = " ".join((fn.__doc__ or "").split())
    if not text:
        raise TypeError(f"tool {fn.__name__}: its docstring is the description the agent reads, and it has none")
    return text


def argument_model(fn: Callable) -> type[BaseModel]:
    """The pydantic model a handler's ``args`` parameter is annotated with.

    Only that one annotation is resolved (with :func:`typing.get_type_hints`, in the handler's module):
    the handler modules import ``RobotContext`` for type checkers only, so ``ctx``'s would not resolve."""
    if "args" not in getattr(fn, "__annotations__", {}):
        raise TypeError(f"tool {fn.__name__}: annotate its args parameter with the tool's argument model "
                        f"(args: <pydantic model>)")
    only_args = types.SimpleNamespace(__annotations__={"args": fn.__annotations__["args"]})
    try:
        model = typing.get_type_hints(only_args, globalns=fn.__globals__)["args"]
    except NameError as e:
        raise TypeError(f"tool {fn.__name__}: its args annotation does not resolve ({e}); define or import its "
                        f"argument model before the handler") from None
    if not (isinstance(model, type) and issubclass(model, BaseModel)):
        raise TypeError(f"tool {fn.__name__}: annotate its args parameter with the tool's argument model "
                        f"(args: <pydantic model>), not {model!r}")
    return model


def tool(*, group: Group, kind: Kind, result: type[BaseModel] | None = None,
         renders: bool = False) -> Callable[[Handler], Handler]:
    """Declare the decorated handler a tool: name, description (its docstring), argument model (the
    annotation of its ``args`` parameter), group, kind, documented result model and whether it renders
    a fresh image. The function itself is returned unchanged, with its declaration as ``fn.tool_def``
    (the registry refuses undocumented arguments when it is built)."""

    def declare(fn: Handler) -> Handler:
        fn.tool_def = ToolDef(name=fn.__name__, group=group, kind=kind,  # type: ignore[attr-defined]
                              args=argument_model(fn), description=description_of(fn), handler=fn,
                              result=result, renders=renders)
        return fn

    return declare
