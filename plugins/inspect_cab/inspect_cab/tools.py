"""cab's tools as Inspect tools: one :class:`~inspect_ai.tool.ToolDef` per tool the attempt's MCP
server lists, with its name, description and input schema as cab serves them.

Inspect's own MCP tools (``mcp_tools``) are not used: they turn a result marked ``isError`` into
a :class:`~inspect_ai.tool.ToolError` holding the text only, so the images of an error result (a
failed grasp with its camera view) would never reach the model. Here an error result without
images is a ``ToolError`` (the model sees cab's JSON error payload, and Inspect marks the call
failed); an error result with images is returned as content, text and images, like any result.

Images are :class:`~inspect_ai._util.content.ContentImage` parts of the tool message. For a
provider that cannot carry images in a tool message, Inspect moves them into a user message
right after the tool messages (``ModelAPI.tool_result_images``), as cab's reference harness does.

Inspect's tool schema model (``ToolParams``/``JSONSchema``) has no ``$ref``: the references of
cab's schemas to their ``$defs`` are inlined here (the same schema, written out). The keywords the
model has no field for (``minItems``, ``maxItems``, ``exclusiveMinimum``, ``title``) are not sent
to the model; cab still validates every call against the full schema (a bad call is charged and
answered with a typed error, as under any harness).
"""
from __future__ import annotations

import copy
import json
from typing import Any

from inspect_ai._util.content import Content, ContentImage, ContentText
from inspect_ai.tool import ToolDef, ToolError, ToolParams

from .attempt import Outcome, ServedAttempt


def inline_refs(schema: dict[str, Any]) -> dict[str, Any]:
    """``schema`` with every ``{"$ref": "#/$defs/X"}`` replaced by a copy of ``$defs.X`` (the
    reference's sibling keys, e.g. a ``description``, kept over it) and ``$defs`` dropped."""
    defs = schema.get("$defs", {})

    def walk(node: Any, seen: tuple[str, ...]) -> Any:
        if isinstance(node, list):
            return [walk(v, seen) for v in node]
        if not isinstance(node, dict):
            return node
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            name = ref.split("/", 2)[2]
            if name in seen:
                raise ValueError(f"recursive schema reference {ref!r}")
            target = walk(copy.deepcopy(defs[name]), (*seen, name))
            return {**target, **{k: walk(v, seen) for k, v in node.items() if k != "$ref"}}
        return {k: walk(v, seen) for k, v in node.items() if k != "$defs"}

    return walk(schema, ())


def result_content(out: Outcome) -> list[Content]:
    """The tool message's content: cab's JSON payload, then each image labelled as cab labels it."""
    parts: list[Content] = [ContentText(text=json.dumps(out.payload))]
    labels = iter(out.labels)
    for mime, data in out.images:
        label = next(labels, None)
        if label:
            parts.append(ContentText(text=label))
        parts.append(ContentImage(image=f"data:{mime};base64,{data}"))
    return parts


def tool_def(served: ServedAttempt, name: str, description: str, schema: dict[str, Any]) -> ToolDef:
    async def execute(**kwargs: Any) -> list[Content]:
        out = await served.call(name, kwargs)
        if out.is_error and not out.images:
            raise ToolError(json.dumps(out.payload))
        return result_content(out)

    params = ToolParams.model_validate(inline_refs(schema))
    return ToolDef(execute, name=name, description=description, parameters=params)


def attempt_tools(served: ServedAttempt) -> list[ToolDef]:
    """The attempt's tools, in the order its server lists them (cab's catalog order)."""
    return [tool_def(served, t.name, t.description or "", dict(t.input_schema)) for t in served.tools]
