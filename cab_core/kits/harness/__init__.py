"""The harness kit: what a model harness plugin builds on, outside the engine.

* :mod:`~cab_core.kits.harness.prompts`: the system prompt, the first user message, the note a
  fork's agent is given, and the image rules of tool results;
* :mod:`~cab_core.kits.harness.pricing`: token usage and its cost;
* :mod:`~cab_core.kits.harness.limits`: requests and tokens per minute and requests in flight,
  shared by every worker process of one machine that uses a credential;
* :mod:`~cab_core.kits.harness.agent_info`: who played (``result.json``'s ``agent`` block);
* :mod:`~cab_core.kits.harness.conversation`: a fork's conversation rebuilt from its parent's records;
* :mod:`~cab_core.kits.harness.stdio`: the process's stdin/stdout, claimed for a protocol;
* :mod:`~cab_core.kits.harness.catalog`: the tools an attempt serves and the motion rules the
  system prompt states, as the engine has them;
* :class:`ToolResponse`: what a call returns (the harness contract's own type,
  :mod:`cab_core.contracts.harness`, with the session a harness drives).

The engine imports these modules from here; a harness imports nothing of ``cab_core.attempt`` or
``cab_core.apps``."""
from cab_core.contracts.harness import ToolResponse

__all__ = ["ToolResponse"]
