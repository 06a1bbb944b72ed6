"""What the tests of the reference harness's OpenAI providers share: the two tools they offer the
model, and the first turn of the conversation they drive (import it after the harness plugin is
importable: the provider tests put its source tree on sys.path where it is not installed)."""
from __future__ import annotations

from cab_harness_reference.types import Message, Text, ToolSpec

SYSTEM = "You control a robot."
TOOLS = [ToolSpec("run_code", "Run a program", {"type": "object", "properties": {
    "code": {"type": "string"}}, "required": ["code"]}),
         ToolSpec("done", "Finish", {"type": "object", "properties": {
             "report": {"type": "string"}}, "required": ["report"]})]


def first_turn(provider):
    """The user's request (put the cube in the bin) sent to ``provider`` with :data:`SYSTEM` and
    :data:`TOOLS`; the reply must stop for tool calls. Returns the conversation so far (to extend with
    the reply and the tool results) and the reply."""
    msgs = [Message("user", [Text("Put the cube in the bin.")])]
    r1 = provider.complete(SYSTEM, msgs, TOOLS)
    assert r1.stop_reason == "tool_calls"
    return msgs, r1
