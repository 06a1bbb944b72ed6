"""cab: a benchmark for agentic Code-as-Policy. The core contract; imports no simulator, provider
SDK or MCP."""
from cab_core import numerics as _numerics

_numerics.pin()  # before anything of cab's imports numpy: the same numerics on every machine

from cab_core.contracts.hookspecs import hookimpl, hookspec  # noqa: E402

__version__ = "0.1.0"
__all__ = ["hookimpl", "hookspec", "__version__"]
