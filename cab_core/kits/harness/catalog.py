"""What a harness tells its model about the robot, as the engine has it:

* :func:`tool_catalog`: the tools an attempt serves, in the catalog's order, each a
  :class:`~cab_core.tools.ToolDef` (``spec()`` gives the name, description and JSON schema models
  see; ``read_only``, ``destructive``, ``advances_physics`` its nature), the same registry every
  episode is built from, so a harness can list them before its session exists (an MCP server
  announcing its tools);
* :func:`motion_rules`: the limits and rules of the motion tools (step sizes, legs, tolerances,
  the workspace) that the system prompt states (:func:`~cab_core.kits.harness.prompts.system_prompt`).
"""
from __future__ import annotations

import copy
from typing import Any

from cab_core.tools import ToolDef, build_registry
from cab_core.tools.motion import HARNESS_PARAMETERS


def tool_catalog() -> list[ToolDef]:
    """The attempt's tools in the catalog's order."""
    return list(build_registry().values())


def motion_rules() -> dict[str, Any]:
    """The motion tools' limits and rules, a copy the caller may change."""
    return copy.deepcopy(HARNESS_PARAMETERS)
