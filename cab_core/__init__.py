"""cab: a benchmark for agentic Code-as-Policy. The core contract; imports no simulator, provider
SDK or MCP."""
from .hookspecs import hookimpl, hookspec

__version__ = "0.1.0"
__all__ = ["hookimpl", "hookspec", "__version__"]
