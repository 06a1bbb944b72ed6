"""What agents and MCP clients read of the tools stays byte-identical to the stored copy
``tests/data/tool_schemas.json``:

* ``schemas``: ``cab_core.tools.schemas()``, as ``cab-schemas`` prints it;
* ``specs``: every ``ToolDef.spec()``, what ``Episode.tool_specs`` gives a harness (and each
  provider adapter turns into its request format);
* ``mcp_tools_list``: the ``tools/list`` result the MCP server plugin serves
  (``cab_harness_mcp.server.tool_list``), dumped as the server puts it on the wire.

The copy was written from the registry before tools were declared next to their handlers. A change
to a description, a schema or a flag is a change to the benchmark: when one is intended, rewrite the
copy with ``python tests/test_tool_surface.py`` and say so in the commit.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from cab_core.tools import build_registry, schemas
from cab_harness_mcp.server import tool_list

STORED = Path(__file__).parent / "data" / "tool_schemas.json"


def surface() -> dict:
    import mcp_types as types

    listed = types.ListToolsResult(tools=tool_list())
    return {"schemas": schemas(),
            "specs": [t.spec() for t in build_registry().values()],
            "mcp_tools_list": listed.model_dump(by_alias=True, mode="json", exclude_none=True)}


def surface_text() -> str:
    return json.dumps(surface(), indent=2) + "\n"


def test_the_tool_surface_is_byte_identical_to_the_stored_copy():
    live, stored = surface(), json.loads(STORED.read_text())
    for part in ("schemas", "specs", "mcp_tools_list"):  # the first part that differs, named
        assert json.dumps(live[part], indent=2) == json.dumps(stored[part], indent=2), part
    assert surface_text() == STORED.read_text()


if __name__ == "__main__":  # rewrite the stored copy (on purpose only)
    STORED.parent.mkdir(exist_ok=True)
    STORED.write_text(surface_text())
    print(f"wrote {STORED}", file=sys.stderr)
