"""The tool contract: the robot tools (the paper's 29) plus ``run_code`` and ``done``, and the list of them all.

Each robot tool is declared once, in its handler's module (``observe``, ``estimate``, ``motion``):
its argument and result models beside the handler, the handler declared with
:func:`~cab_core.tools.registry.tool` (group, kind, result model; its name, docstring and ``args``
annotation give the rest). :data:`CATALOG` below is the tool list, one line per tool in the order of
the catalog: the robot tools by their handlers, then the two tools the episode host serves, declared
here. ``TOOLS`` (built on first access by :func:`build_registry`, then cached) maps each name to its
:class:`~cab_core.tools.registry.ToolDef`, whose ``handler`` is the function a call reaches; building
the registry refuses an argument without a description. :func:`validate_args` turns raw JSON
arguments into the model or raises :class:`~cab_core.errors.ToolArgumentError` with a short message a
model can act on.
"""
from __future__ import annotations

import functools
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from typing import Annotated, Any

from pydantic import BaseModel, Field, Strict, ValidationError

from cab_core.errors import PluginError, ToolArgumentError
from cab_core.tools import estimate, motion, observe
from cab_core.tools.models import Args, Result
from cab_core.tools.registry import ToolDef, ToolOutput

__all__ = ["CATALOG", "TOOLS", "ToolDef", "ToolOutput", "build_registry", "schemas", "validate_args", "tool_names"]


# -- the two tools the episode host serves itself (cab_core.attempt.engine.serving.CallServer): no handler --
class RunCodeArgs(Args):
    code: Annotated[str, Strict()] = Field(
        min_length=1, max_length=200_000,
        description="Python source run in the persistent sandbox (numpy as np, math, load_image and every "
                    "robot tool as a keyword-only function); assign `result` to return a value.")


class TraceEntry(Result):
    index: int = Field(description="Order of the internal call.")
    tool: str = Field(description="Tool name.")
    ok: bool = Field(description="The call returned without error.")
    status: str | None = Field(default=None, description="Action status if an action.")
    action_id: str | None = Field(default=None, description="Action id if an action.")
    tick: int | None = Field(default=None, description="Tick after the call.")
    abort_reason: str | None = Field(default=None, description="Abort reason if ABORTED.")
    obs_ids: list[str] = Field(default_factory=list, description="Observations produced.")
    error: str | None = Field(default=None, description="Error text if the call failed.")


class CodeResult(Result):
    ok: bool = Field(description="The program ran to completion without an exception.")
    error: str | None = Field(default=None, description="Exception text, if any.")
    stdout: str = Field(default="", description="Captured print output (capped at 8000 characters).")
    value: Any = Field(default=None, description="The value assigned to `result`, JSON-encoded.")
    result_assigned: bool = Field(default=False, description="Whether the program assigned `result`.")
    tool_calls: int = Field(default=0, description="Internal tool calls made (not charged individually).")
    obs_ids: list[str] = Field(default_factory=list, description="Observations produced by the program.")
    internal_trace: list[TraceEntry] = Field(default_factory=list, description="One entry per internal tool call.")
    filesystem_policy: str = Field(default="structurally_denied", description="Programs cannot reach a filesystem.")
    namespace_reset: bool = Field(
        default=False, description="True when a timeout or an aborted action reset the program state.")


RUN_CODE = ToolDef(
    name="run_code", group="composition", kind="code", args=RunCodeArgs, result=CodeResult,
    description="Runs a Python program in a confined, persistent sandbox: numpy as np, math, load_image(obs_id) and "
                "every robot tool as a keyword-only function returning plain dicts. Variables persist across calls; a "
                "timeout or an ABORTED action resets them. Returns stdout, the value of `result`, a trace of internal "
                "tool calls and up to 6 images. Costs one call; robot actions inside still consume simulated time.")


class DoneArgs(Args):
    report: Annotated[str, Strict()] = Field(
        max_length=20_000, description="Your account of what you did and the final state.")
    success_claim: Annotated[bool, Strict()] | None = Field(
        default=None, description="Whether you judge the task accomplished (true/false).")


class DoneResult(Result):
    ok: bool = Field(description="Always true.")
    note: str = Field(description="'episode ended; attempt recorded.' No verdict is returned.")


# The catalog's group "termination" is the registry's "control".
DONE = ToolDef(
    name="done", group="control", kind="done", args=DoneArgs, result=DoneResult,
    description="Ends the attempt with your report and your judgement of success. The verifier's outcome is never "
                "returned. Free, usable once.")


# -- the tool list ------------------------------------------------------------------------------
# Every tool, one line each, in catalog order: a robot tool by its handler (declared with @tool),
# a host tool by its ToolDef. A new tool is its handler and models in its module, and a line here.
CATALOG: tuple[Callable | ToolDef, ...] = (
    observe.get_world_frame,
    observe.get_embodiment,
    observe.get_camera_info,
    observe.get_arm_pose,
    observe.get_gripper_state,
    observe.get_robot_state,
    observe.get_grasp_contact,
    observe.capture_head,
    observe.capture_wrist,
    observe.capture_evidence_views,
    estimate.draw_marks,
    estimate.ray,
    estimate.project,
    estimate.plane_intersect,
    motion.capture_motion_pair,
    estimate.triangulate_correspondence,
    estimate.scale_from_object_size,
    estimate.scale_from_gripper,
    estimate.grasp_quat_candidates,
    estimate.camera_aim_pose,
    estimate.preview_tcp_pose,
    estimate.compare_tcp_poses,
    motion.check_tcp_pose_reachability,
    motion.reach_tcp,
    motion.reach_both_tcp,
    motion.move_delta,
    motion.move_both_delta,
    motion.probe_contact_along,
    motion.set_gripper,
    RUN_CODE,
    DONE,
)


def _model_types(annotation: Any) -> list[type[BaseModel]]:
    """Pydantic models nested anywhere in a type annotation."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    out: list[type[BaseModel]] = []
    for a in typing.get_args(annotation):
        out += _model_types(a)
    return out


def check_documented(model: type[BaseModel], _seen: set | None = None) -> None:
    """Raise PluginError if any field of ``model`` (or of a model nested in it) lacks a description."""
    seen = _seen if _seen is not None else set()
    if model in seen:
        return
    seen.add(model)
    for name, f in model.model_fields.items():
        if not (f.description or "").strip():
            raise PluginError(f"tool argument {model.__name__}.{name} has no description")
        for sub in _model_types(f.annotation):
            check_documented(sub, seen)


def declaration(entry: Callable | ToolDef) -> ToolDef:
    """A catalog entry's ToolDef: the host tool itself, or the declaration a handler carries."""
    if isinstance(entry, ToolDef):
        return entry
    td = getattr(entry, "tool_def", None)
    if not isinstance(td, ToolDef):
        raise PluginError(f"{getattr(entry, '__qualname__', entry)!r} is not declared as a tool (@tool)")
    return td


def check_tool(td: ToolDef) -> ToolDef:
    """Refuse a tool with an undocumented argument or an argument model that accepts extra fields."""
    check_documented(td.args)
    if td.args.model_config.get("extra") != "forbid":
        raise PluginError(f"tool {td.name}: argument model {td.args.__name__} must forbid extra fields")
    return td


def build_registry(entries: Iterable[Callable | ToolDef] = CATALOG) -> dict[str, ToolDef]:
    """Build the registry from the catalog (in its order); refuse duplicates and undocumented arguments."""
    tools: dict[str, ToolDef] = {}
    for entry in entries:
        td = check_tool(declaration(entry))
        if td.name in tools:
            raise PluginError(f"duplicate tool {td.name!r}")
        tools[td.name] = td
    return tools


@functools.cache
def _tools() -> types.MappingProxyType:
    return types.MappingProxyType(build_registry())


def __getattr__(name: str):  # lazily built module attribute TOOLS
    if name == "TOOLS":
        return _tools()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def tool_names() -> list[str]:
    return list(_tools())


def _fmt_loc(loc: tuple) -> str:
    return ".".join(str(p) for p in loc) or "arguments"


def _short(v: Any, n: int = 60) -> str:
    r = repr(v)
    return r if len(r) <= n else r[: n - 3] + "..."


def _fmt_error(e: Mapping[str, Any]) -> str:
    loc = _fmt_loc(e.get("loc", ()))
    typ = e.get("type", "")
    if typ == "missing":
        return f"missing required argument '{loc}'"
    if typ == "extra_forbidden":
        return f"unknown argument '{loc}'"
    msg = e.get("msg", "invalid")
    msg = msg.removeprefix("Value error, ")
    if typ == "literal_error" or typ.endswith("_type") or typ.endswith("_parsing"):
        return f"{loc}: {msg} (got {_short(e.get('input'))})"
    if loc == "arguments" or not e.get("loc"):
        return msg
    return f"{loc}: {msg}"


def format_validation_error(err: ValidationError, limit: int = 4) -> str:
    errs = err.errors(include_url=False)
    parts = [_fmt_error(e) for e in errs[:limit]]
    if len(errs) > limit:
        parts.append(f"and {len(errs) - limit} more")
    return "; ".join(parts)


def validate_args(name: str, raw: Any) -> BaseModel:
    """Validate raw JSON arguments for tool ``name``; raise ToolArgumentError with a short message."""
    tools = _tools()
    if name not in tools:
        raise ToolArgumentError(f"unknown tool: {name}")
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ToolArgumentError(f"bad arguments: arguments must be a JSON object, got {type(raw).__name__}")
    try:
        return tools[name].args.model_validate(raw)
    except ValidationError as e:
        raise ToolArgumentError(f"bad arguments: {format_validation_error(e)}") from None


def schemas() -> list[dict]:
    """Every tool's provider-neutral description, in registry order (printed by ``cab-schemas``)."""
    return [{"name": t.name, "description": t.description, "group": t.group, "read_only": t.read_only,
             "destructive": t.destructive, "advances_physics": t.advances_physics, "charged": t.charged,
             "parameters": t.json_schema()} for t in _tools().values()]
