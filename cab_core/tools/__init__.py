"""The tool contract: the 29 robot tools of the paper plus ``run_code`` and ``done``.

Each robot tool is declared once, next to its handler, with :func:`~cab_core.tools.registry.tool`
(name, description, argument and result models, group, kind); :data:`CATALOG` below lists the
handlers themselves in the order of the catalog, then the two tools the episode host serves.
``TOOLS`` (built on first access by :func:`build_registry`, then cached) maps each name to its
:class:`~cab_core.tools.registry.ToolDef`, whose ``handler`` is the function a call reaches. Schemas
come from the pydantic models in :mod:`cab_core.tools.models`; building the registry refuses an
argument without a description. :func:`validate_args` turns raw JSON arguments into the model or
raises :class:`~cab_core.errors.ToolArgumentError` with a short message a model can act on.
"""
from __future__ import annotations

import functools
import types
import typing
from typing import Any, Callable, Iterable, Union

from pydantic import BaseModel, ValidationError

from cab_core.errors import PluginError, ToolArgumentError
from cab_core.tools import estimate, motion, observe
from cab_core.tools import models as m
from cab_core.tools.registry import ToolDef, ToolOutput

__all__ = ["CATALOG", "TOOLS", "ToolDef", "ToolOutput", "build_registry", "schemas", "validate_args", "tool_names"]

# The two tools the episode host serves itself (cab_core.attempt.serving.CallServer): no handler.
# The catalog's group "termination" is the registry's "control".
RUN_CODE = ToolDef(
    name="run_code", group="composition", kind="code", args=m.RunCodeArgs, result=m.CodeResult,
    description="Runs a Python program in a confined, persistent sandbox: numpy as np, math, load_image(obs_id) and "
                "every robot tool as a keyword-only function returning plain dicts. Variables persist across calls; a "
                "timeout or an ABORTED action resets them. Returns stdout, the value of `result`, a trace of internal "
                "tool calls and up to 6 images. Costs one call; robot actions inside still consume simulated time.")
DONE = ToolDef(
    name="done", group="control", kind="done", args=m.DoneArgs, result=m.DoneResult,
    description="Ends the attempt with your report and your judgement of success. The verifier's outcome is never "
                "returned. Free, usable once.")

# Every tool, in catalog order: a robot tool by its handler (declared with @tool), a host tool by its ToolDef.
CATALOG: tuple[Union[Callable, ToolDef], ...] = (
    observe.get_world_frame, observe.get_embodiment, observe.get_camera_info, observe.get_arm_pose,
    observe.get_gripper_state, observe.get_robot_state, observe.get_grasp_contact, observe.capture_head,
    observe.capture_wrist, observe.capture_evidence_views, estimate.draw_marks,
    estimate.ray, estimate.project, estimate.plane_intersect, motion.capture_motion_pair,
    estimate.triangulate_correspondence, estimate.scale_from_object_size, estimate.scale_from_gripper,
    estimate.grasp_quat_candidates, estimate.camera_aim_pose, estimate.preview_tcp_pose, estimate.compare_tcp_poses,
    motion.check_tcp_pose_reachability,
    motion.reach_tcp, motion.reach_both_tcp, motion.move_delta, motion.move_both_delta, motion.probe_contact_along,
    motion.set_gripper,
    RUN_CODE, DONE,
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


def declaration(entry: Union[Callable, ToolDef]) -> ToolDef:
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


def build_registry(entries: Iterable[Union[Callable, ToolDef]] = CATALOG) -> dict[str, ToolDef]:
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


def _fmt_error(e: dict) -> str:
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
